// Exact block sums of a channel: the only pass over every sample of a capture (impactcore.h).
#include <string.h>

#include "impactcore.h"

#if defined(__ARM_FEATURE_DSP)
#include <arm_acle.h>
#endif

namespace impactcore {
namespace {

// One sample into the sums: the portable definition of every statistic.
inline void add_sample(Sums* s, const int16_t* x, int i) {
  const int32_t v = x[i];
  s->s1 += v;
  s->s2 += static_cast<int64_t>(v * v);  // |v| <= 2^15: v * v fits int32
}

}  // namespace

// Full blocks of kBlock samples add straight into the running sums. On cores with the DSP extension
// (Cortex-M4/M7/M33) two samples at a time: SMLALD adds x0^2 + x1^2 to the 64-bit sum, SMLAD
// x0 * 1 + x1 * 1 to the 32-bit one. Integer arithmetic: the same numbers as the portable loop (which
// is add_sample), bit for bit.
int block_prefix_sums(const int16_t* x, int n, Sums* prefix) {
  Sums run = {0, 0};
  prefix[0] = run;
  int k = 0;
  int i = 0;
  for (; i + kBlock <= n; i += kBlock) {
    const int16_t* b = x + i;
#if defined(__ARM_FEATURE_DSP)
    static_assert(kBlock % 2 == 0, "the DSP kernel takes samples in pairs");
#pragma GCC unroll 8
    for (int j = 0; j < kBlock; j += 2) {
      int32_t w;
      memcpy(&w, b + j, sizeof(w));  // b[j] in the low half, b[j + 1] in the high half (little endian)
      run.s2 = __smlald(w, w, run.s2);
      run.s1 = __smlad(w, 0x00010001, run.s1);
    }
#else
    for (int j = 0; j < kBlock; ++j) add_sample(&run, b, j);
#endif
    prefix[++k] = run;
  }
  if (i < n) {
    for (; i < n; ++i) add_sample(&run, x, i);
    prefix[++k] = run;
  }
  return k;
}

Sums prefix_at(const int16_t* x, const Sums* prefix, int n, int i) {
  const int k = i / kBlock;
  const int next = (k + 1) * kBlock < n ? (k + 1) * kBlock : n;  // the boundary after i: prefix[k + 1]
  if (next - i < i - k * kBlock) {  // nearer the next boundary: take its sums back to i
    const Sums& p = prefix[k + 1];
    Sums t = {0, 0};
    for (int j = i; j < next; ++j) add_sample(&t, x, j);
    Sums s;
    s.s1 = p.s1 - t.s1;
    s.s2 = p.s2 - t.s2;
    return s;
  }
  Sums s = prefix[k];
  for (int j = k * kBlock; j < i; ++j) add_sample(&s, x, j);
  return s;
}

int64_t scaled_energy(const Sums& r, int m, int n_b, int32_t sum_b) {
  const int64_t nb = n_b;
  const int64_t b = sum_b;
  return nb * nb * r.s2 - 2 * nb * b * r.s1 + static_cast<int64_t>(m) * b * b;
}

}  // namespace impactcore
