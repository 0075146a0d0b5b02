// Shared by the plate's operators (plate.cpp) and the stepper (run.cpp): input checks, the denormal guard,
// and the portable element sweep (element.h) over a plate's rows with its special elements.
#pragma once

#include <algorithm>
#include <stdexcept>
#include <string>
#include <vector>

#if defined(__SSE__) || defined(__x86_64__)
#include <xmmintrin.h>
#define IMPACTSIM_X86 1
#endif

#include "element.h"
#include "impactsim.h"

namespace impactsim {
namespace detail {

inline void need(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument(what);
}

// Flush denormals to zero while stepping (wave fronts have exponentially small tails; denormal arithmetic is
// ~100x slower on x86). Restores the caller's mode.
struct DenormalGuard {
#ifdef IMPACTSIM_X86
  unsigned int saved = _mm_getcsr();
  DenormalGuard() { _mm_setcsr(saved | 0x8040u); }
  ~DenormalGuard() { _mm_setcsr(saved); }
#endif
};

template <typename T>
const Coef<T>& coef_of(const Plate::Special& sp);
template <>
inline const Coef<float>& coef_of<float>(const Plate::Special& sp) {
  return sp.kf;
}
template <>
inline const Coef<double>& coef_of<double>(const Plate::Special& sp) {
  return sp.kd;
}

// Edge accumulators of two node rows (rolling), each array padded by one zero on both sides.
template <typename T>
struct Accumulators {
  std::vector<T> buf;
  RowAcc<T> row[2];
  int nx;
  explicit Accumulators(int nx_) : buf(static_cast<size_t>(12) * (nx_ + 2), T(0)), nx(nx_) {
    for (int r = 0; r < 2; ++r) {
      T* b = buf.data() + static_cast<size_t>(6 * r) * (nx + 2) + 1;
      const size_t l = static_cast<size_t>(nx) + 2;
      row[r] = {b, b + l, b + 2 * l, b + 3 * l, b + 4 * l, b + 5 * l};
    }
  }
  void clear(int r) {
    const RowAcc<T>& a = row[r];
    for (T* p : {a.pw, a.qw, a.px, a.qx, a.py, a.qy}) std::fill(p, p + nx, T(0));
  }
};

// One pass over the element rows (state rows rs apart): after element row j (and its corrections) node row j is complete and
// done(j, acc) is called with its accumulators; node row ny last. done may overwrite node row j's state:
// later element rows no longer read it.
template <typename T, typename Done>
IMPACTSIM_INLINE void sweep(int nx, int ny, int64_t rs, const Coef<T>& base, const Plate::Special* special,
                            const int64_t* row_start, const T* w, const T* bx, const T* by, Accumulators<T>& acc,
                            Done&& done) {
  int cur = 0;
  acc.clear(cur);
  for (int j = 0; j < ny; ++j) {
    const int64_t o0 = j * rs, o1 = o0 + rs;
    const RowIn<T> in{w + o0, w + o1, bx + o0, bx + o1, by + o0, by + o1};
    const RowAcc<T>& lo = acc.row[cur];
    const RowAcc<T>& hi = acc.row[1 - cur];
    element_row<T, false>(nx, in, base, lo, hi);
    for (int64_t k = row_start[j]; k < row_start[j + 1]; ++k) {
      const int i = special[k].i;
      element_row<T, true>(1, in.at(i), coef_of<T>(special[k]), lo.at(i), hi.at(i));
    }
    done(j, lo);
    cur = 1 - cur;
  }
  done(ny, acc.row[cur]);
}

}  // namespace detail
}  // namespace impactsim
