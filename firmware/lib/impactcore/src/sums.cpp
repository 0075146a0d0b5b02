// Exact block sums of a channel: the only pass over every sample of a capture (impactcore.h).
#include <stdint.h>
#include <string.h>

#include "impactcore.h"

#if defined(__ARM_FEATURE_DSP) || defined(__ARM_FEATURE_SIMD32)
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
#if defined(__ARM_FEATURE_DSP)
// Eight samples (b word aligned) in four registers by two LDRD: one load instruction per four samples
// (GCC splits a 64-bit load from a word-aligned address into two LDR; LDRD needs word alignment only).
typedef uint32_t __attribute__((may_alias)) Word;
__attribute__((always_inline)) inline void load8(const int16_t* b, int32_t& w0, int32_t& w1, int32_t& w2, int32_t& w3) {
  __asm__("ldrd %0, %1, [%4]\n\tldrd %2, %3, [%4, #8]"
          : "=&r"(w0), "=&r"(w1), "=&r"(w2), "=r"(w3)
          : "r"(b), "m"(*reinterpret_cast<const Word(*)[4]>(b)));
}

// Eight samples into the running sums (b word aligned when kAligned).
template <bool kAligned>
__attribute__((always_inline)) inline void add8(const int16_t* b, int64_t& s2, int32_t& s1) {
  int32_t w0, w1, w2, w3;
  if (kAligned) {
    load8(b, w0, w1, w2, w3);
  } else {
    memcpy(&w0, b, sizeof(w0));
    memcpy(&w1, b + 2, sizeof(w1));
    memcpy(&w2, b + 4, sizeof(w2));
    memcpy(&w3, b + 6, sizeof(w3));
  }
  s2 = __smlald(w0, w0, s2);
  s1 = __smlad(w0, 0x00010001, s1);
  s2 = __smlald(w1, w1, s2);
  s1 = __smlad(w1, 0x00010001, s1);
  s2 = __smlald(w2, w2, s2);
  s1 = __smlad(w2, 0x00010001, s1);
  s2 = __smlald(w3, w3, s2);
  s1 = __smlad(w3, 0x00010001, s1);
}

// One block (two eights) into the running sums, and the sums after it into *out.
template <bool kAligned>
__attribute__((always_inline)) inline void add_block(const int16_t* b, int64_t& s2, int32_t& s1, Sums* out) {
  add8<kAligned>(b, s2, s1);
  add8<kAligned>(b + 8, s2, s1);
  out->s2 = s2;
  out->s1 = s1;
}

// The blocks four at a time (the sums in registers, pointers walked: fewer loop instructions a block).
template <bool kAligned>
inline Sums dsp_blocks(const int16_t* x, int blocks, Sums run, Sums* prefix) {
  static_assert(kBlock == 16, "the DSP kernel takes a block as two eights");
  int64_t s2 = run.s2;
  int32_t s1 = run.s1;
  const int16_t* b = x;
  Sums* out = prefix + 1;
  Sums* const quads_end = out + (blocks & ~3);
  for (; out < quads_end; out += 4, b += 4 * kBlock) {
    add_block<kAligned>(b, s2, s1, out);
    add_block<kAligned>(b + kBlock, s2, s1, out + 1);
    add_block<kAligned>(b + 2 * kBlock, s2, s1, out + 2);
    add_block<kAligned>(b + 3 * kBlock, s2, s1, out + 3);
  }
  Sums* const pairs_end = out + (blocks & 2);
  for (; out < pairs_end; out += 2, b += 2 * kBlock) {
    add_block<kAligned>(b, s2, s1, out);
    add_block<kAligned>(b + kBlock, s2, s1, out + 1);
  }
  if (blocks & 1) add_block<kAligned>(b, s2, s1, out);
  return Sums{s2, s1};
}
#endif

int block_prefix_sums(const int16_t* x, int n, Sums* prefix) {
  Sums run = {0, 0};
  prefix[0] = run;
  int k = n / kBlock;
  int i = k * kBlock;
#if defined(__ARM_FEATURE_DSP)
  if ((reinterpret_cast<uintptr_t>(x) & 3u) == 0) {
    run = dsp_blocks<true>(x, k, run, prefix);
  } else {
    run = dsp_blocks<false>(x, k, run, prefix);
  }
#else
  for (int m = 0; m < i; m += kBlock) {
    for (int j = m; j < m + kBlock; ++j) add_sample(&run, x, j);
    prefix[m / kBlock + 1] = run;
  }
#endif
  if (i < n) {
    for (; i < n; ++i) add_sample(&run, x, i);
    prefix[++k] = run;
  }
  return k;
}

namespace {
// The sums of x[a .. b) added into *s (b - a < kBlock). On the DSP extension two samples a step (SMLALD,
// SMLAD on an unaligned word: the M4 allows it), the odd one last: integers, the same sums as add_sample's.
#if defined(__GNUC__)
__attribute__((always_inline))
#endif
inline void add_range(Sums* s, const int16_t* x, int a, int b) {
  int64_t s2 = s->s2;
  int32_t s1 = s->s1;
  const int16_t* p = x + a;
  const int16_t* const end = x + b;
#if defined(__ARM_FEATURE_DSP)
  for (const int16_t* const pairs_end = p + ((b - a) & ~1); p < pairs_end; p += 2) {
    int32_t w;
    memcpy(&w, p, sizeof(w));
    s2 = __smlald(w, w, s2);
    s1 = __smlad(w, 0x00010001, s1);
  }
#endif
  for (; p < end; ++p) {
    const int32_t v = *p;
    s1 += v;
    s2 += static_cast<int64_t>(v * v);
  }
  s->s2 = s2;
  s->s1 = s1;
}
}  // namespace

Sums prefix_at_partial(const int16_t* x, const Sums* prefix, int n, int i) {
  IC_WORK(partial_prefix, 1);
  const int k = i / kBlock;
  const int next = (k + 1) * kBlock < n ? (k + 1) * kBlock : n;  // the boundary after i: prefix[k + 1]
  if (next - i < i - k * kBlock) {  // nearer the next boundary: take its sums back to i
    const Sums& p = prefix[k + 1];
    Sums t = {0, 0};
    add_range(&t, x, i, next);
    Sums s;
    s.s1 = p.s1 - t.s1;
    s.s2 = p.s2 - t.s2;
    return s;
  }
  Sums s = prefix[k];
  add_range(&s, x, k * kBlock, i);
  return s;
}

int32_t range_sum(const int16_t* x, int a, int b) {
  int32_t s = 0;
  int i = a;
#if defined(__ARM_FEATURE_DSP)
  // Four samples a step: SMLAD adds both halves of a word (unaligned LDR is allowed on the M4).
  for (; i + 4 <= b; i += 4) {
    int32_t w0, w1;
    memcpy(&w0, x + i, sizeof(w0));
    memcpy(&w1, x + i + 2, sizeof(w1));
    s = __smlad(w0, 0x00010001, s);
    s = __smlad(w1, 0x00010001, s);
  }
#endif
  for (; i < b; ++i) s += x[i];
  return s;
}

namespace {

// S0 = sum x[i]^2 and the lagged products P_l = sum x[i] x[i-l], l = 1..3, over i in [a, b): the one pass
// the difference energies need. On the DSP extension two samples per step: with w0 = (x[i], x[i+1]) and
// wl = (x[i-l], x[i+1-l]) packed, SMLALD(w0, wl) adds x[i] x[i-l] + x[i+1] x[i+1-l].
#if defined(__GNUC__) && !defined(__clang__)
// Its own register allocation and -O2 even in an -Os build: inlined, or at -Os, GCC spills the int64
// accumulators every step (18 instead of 14 instructions a pair of samples on the M4).
__attribute__((noinline, optimize("O2")))
#endif
void lagged_products(const int16_t* x, int a, int b, int64_t p[kDiffOrders + 1]) {
  int64_t p0 = 0, p1 = 0, p2 = 0, p3 = 0;
  int i = a;
#if defined(__ARM_FEATURE_DSP)
  // One pass, four samples a step: with w0 = (x[i], x[i+1]) and w1 = (x[i-1], x[i]) loaded, the lag-2
  // and lag-3 pairs (x[i-2], x[i-1]) and (x[i-3], x[i-2]) are the previous step's w0 and w1 (unaligned
  // LDR is allowed on the M4). Two steps per iteration, so the previous pair needs no register moves.
  const int quads_end = a + ((b - a) & ~3);
  if (quads_end > a) {
    int32_t u0, u1;
    memcpy(&u0, x + a - 2, sizeof(u0));
    memcpy(&u1, x + a - 3, sizeof(u1));
    for (const int16_t* q = x + a; q < x + quads_end; q += 4) {
      int32_t w0, w1, v0, v1;
      memcpy(&w0, q, sizeof(w0));
      memcpy(&w1, q - 1, sizeof(w1));
      p0 = __smlald(w0, w0, p0);
      p1 = __smlald(w0, w1, p1);
      p2 = __smlald(w0, u0, p2);
      p3 = __smlald(w0, u1, p3);
      memcpy(&v0, q + 2, sizeof(v0));
      memcpy(&v1, q + 1, sizeof(v1));
      p0 = __smlald(v0, v0, p0);
      p1 = __smlald(v0, v1, p1);
      p2 = __smlald(v0, w0, p2);
      p3 = __smlald(v0, w1, p3);
      u0 = v0;
      u1 = v1;
    }
  }
  const int pairs_end = quads_end;
  i = pairs_end;
#endif
  for (; i < b; ++i) {
    const int32_t v = x[i];
    p0 += v * v;
    p1 += v * x[i - 1];
    p2 += v * x[i - 2];
    p3 += v * x[i - 3];
  }
  p[0] = p0;
  p[1] = p1;
  p[2] = p2;
  p[3] = p3;
}

}  // namespace

void difference_energies(const int16_t* x, int a, int b, int64_t out[kDiffOrders]) {
  // Delta^k x[i] = sum_j c_kj x[i-j] (binomial, alternating), so
  //   sum_i (Delta^k x[i])^2 = sum_j c_kj^2 S(j) + 2 sum_{j<m} c_kj c_km P_{m-j}(j),
  // where S(s) = sum x[i]^2 and P_l(s) = sum x[i] x[i-l] over the range shifted back by s, i in [a-s, b-s):
  // the one pass's sums plus at most three end products on each side. Exact integers: the same numbers as
  // summing the squared differences directly (tests/test_core.py), whatever the instruction set.
  int64_t p[kDiffOrders + 1];
  lagged_products(x, a, b, p);
  // sh[l][s] = P_l(s) (P_0 = S)
  int64_t sh[kDiffOrders + 1][kDiffOrders + 1];
  for (int l = 0; l <= kDiffOrders; ++l) {
    int64_t v = p[l];
    sh[l][0] = v;
    for (int s = 1; s + l <= kDiffOrders; ++s) {
      v += static_cast<int32_t>(x[a - s]) * x[a - s - l] - static_cast<int32_t>(x[b - s]) * x[b - s - l];
      sh[l][s] = v;
    }
  }
  // c = (1, -1), (1, -2, 1), (1, -3, 3, -1)
  out[0] = sh[0][0] + sh[0][1] - 2 * sh[1][0];
  out[1] = sh[0][0] + 4 * sh[0][1] + sh[0][2] - 4 * (sh[1][0] + sh[1][1]) + 2 * sh[2][0];
  out[2] = sh[0][0] + 9 * (sh[0][1] + sh[0][2]) + sh[0][3] - 6 * (sh[1][0] + sh[1][2]) - 18 * sh[1][1] +
           6 * (sh[2][0] + sh[2][1]) - 2 * sh[3][0];
}

void range_extremes(const int16_t* x, int a, int b, int32_t* lo, int32_t* hi) {
  int32_t mn = x[a], mx = x[a];
  int i = a;
#if defined(__ARM_FEATURE_SIMD32)
  // Two samples a word (PairExtremes); a full block unrolled (block_extremes).
  if (b - a == kBlock) {
    block_extremes(x + a, lo, hi);
    return;
  }
  if (b - a >= 2) {
    PairExtremes e(x + a);
    for (i = a + 2; i + 2 <= b; i += 2) e.add(x + i);
    e.get(&mn, &mx);
  }
#endif
  for (; i < b; ++i) {
    const int32_t v = x[i];
    if (v > mx) mx = v;
    if (v < mn) mn = v;
  }
  *lo = mn;
  *hi = mx;
}

int64_t scaled_energy(const Sums& r, int m, int n_b, int32_t sum_b) {
  const int64_t nb = n_b;
  const int64_t b = sum_b;
  return nb * nb * r.s2 - 2 * nb * b * r.s1 + static_cast<int64_t>(m) * b * b;
}

}  // namespace impactcore
