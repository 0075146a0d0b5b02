// The stepper's pass (stepper.h), compiled for three x86-64 levels and picked at load time.
#include "stepper.h"

#include <algorithm>

#include "element.h"
#include "fused.h"

namespace impactsim {
namespace detail {

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(IMPACTSIM_NO_CLONES)
#define IMPACTSIM_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define IMPACTSIM_CLONES
#endif
#if defined(__GNUC__)
#define IMPACTSIM_LAMBDA_INLINE __attribute__((always_inline))
#else
#define IMPACTSIM_LAMBDA_INLINE
#endif

IMPACTSIM_CLONES void step_fast(const StepArgs& a) {
  const int64_t rs = a.rs;
  const size_t np = a.np;
  float* const u = a.u;
  const float alpha = a.alpha;
#ifdef IMPACTSIM_FUSED
  static_assert(kLanes == 16 && kBetaOffset == kDbBeta, "d/beta layout differs from fused.h");
  float* const set[2] = {a.edge, a.edge + 6 * rs};
  const int j_lo = std::max(a.j_lo, 0), j_hi = std::min(a.j_hi, a.ny);
  const int b_lo = std::max(a.b_lo, 0), b_hi = std::min(a.b_hi, a.nx / kLanes);
  if (j_lo > j_hi || b_lo > b_hi) return;
  std::fill(set[0], set[0] + 6 * rs, 0.0f);  // element row j_lo - 1 joins rows at rest: no forces
  int cur = 0;
  FusedRow fr;
  for (int j = j_lo; j <= j_hi; ++j) {
    for (int f = 0; f < 3; ++f) {
      fr.u0[f] = u + f * np + j * rs;
      fr.u1[f] = u + f * np + (j < a.ny ? j + 1 : j) * rs;
    }
    fr.db = a.db + j * 6 * rs;
    fr.in = set[cur];
    fr.out = set[1 - cur];
    if (j == a.ny) {
      last_row(a.nx, alpha, fr, b_lo, b_hi);
      break;
    }
    const int64_t sr = a.scaled_row[j];  // rows with disc elements: per-element stiffness on their blocks
    if (sr >= 0)
      fused_row(a.nx, *a.base, alpha, fr, a.scaled_block + sr * a.nblocks, a.scale + 2 * sr * rs,
                        a.scale + (2 * sr + 1) * rs, b_lo, b_hi);
    else
      fused_row(a.nx, *a.base, alpha, fr, nullptr, nullptr, nullptr, b_lo, b_hi);
    cur = 1 - cur;
  }
#else
  const int rl = a.nx + 1;
  sweep<float>(a.nx, a.ny, rs, *a.base, a.special, a.row_start, u, u + np, u + 2 * np, *a.acc,
               [&](int j, const RowAcc<float>& acc) IMPACTSIM_LAMBDA_INLINE {
                 const size_t o = static_cast<size_t>(j) * rs;
                 const float* const p[3] = {acc.pw, acc.px, acc.py};
                 const float* const q[3] = {acc.qw, acc.qx, acc.qy};
                 for (int fld = 0; fld < 3; ++fld) {
                   float* __restrict uu = u + fld * np + o;
                   float* const db = a.db + j * 6 * rs;
                   const float* __restrict pp = p[fld];
                   const float* __restrict qq = q[fld];
                   for (int i = 0; i < rl; ++i) {
                     float* const dd = db + db_index(i, fld);
                     const float dn = alpha * dd[0] - dd[kDbBeta] * node_force(pp, qq, i);
                     dd[0] = dn;
                     uu[i] += dn;
                   }
                 }
               });
#endif
}



// NaN and Inf survive a multiplication by zero; the sum's order is immaterial).
IMPACTSIM_CLONES bool all_finite(const float* x, size_t n) {
  float acc = 0;
#pragma omp simd reduction(+ : acc)
  for (size_t k = 0; k < n; ++k) acc += x[k] * 0.0f;
  return acc == 0;
}


}  // namespace detail
}  // namespace impactsim
