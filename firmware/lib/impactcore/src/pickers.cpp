// Onset pickers: plain functions of a buffer.
#include <math.h>
#include <string.h>

#include "impactcore.h"
#ifndef AIC_STEP
#define AIC_STEP 1
#endif

namespace impactcore {

void baseline_from_sums(const Sums& s, int n, float* mean, float* rms) {
  if (n <= 0) {
    *mean = 0.0f;
    *rms = 0.0f;
    return;
  }
  // n^2 var = n S2 - S1^2 >= 0, exact in int64 for n <= kMaxBaselineSamples.
  const int64_t nn = static_cast<int64_t>(n) * n;
  const int64_t var_nn = static_cast<int64_t>(n) * s.s2 - static_cast<int64_t>(s.s1) * s.s1;
  *mean = static_cast<float>(s.s1) / static_cast<float>(n);
  *rms = vsqrt_f32(int64_to_float(var_nn) / int64_to_float(nn));
}

void baseline_stats(const int16_t* x, int n, float* mean, float* rms) {
  Sums s = {0, 0};
  for (int i = 0; i < n; ++i) {
    s.s1 += x[i];
    s.s2 += static_cast<int64_t>(x[i]) * x[i];
  }
  baseline_from_sums(s, n, mean, rms);
}

float crossing_subsample(const int16_t* x, int i, float base, float thr) {
  const float a = fabsf(static_cast<float>(x[i]) - base);
  const float a0 = fabsf(static_cast<float>(x[i - 1]) - base);
  const float frac = (a > a0) ? (thr - a0) / (a - a0) : 1.0f;
  return static_cast<float>(i - 1) + (frac < 0.0f ? 0.0f : frac);
}

bool is_transient(const int16_t* x, int n, int i, float b, float thr) {
  const auto dev = [x, b](int j) { return fabsf(static_cast<float>(x[j]) - b); };
  if (i + 2 + kTransientQuiet >= n) return false;
  int end = i + 1;                       // first sample after the excursion
  if (dev(end) >= thr) ++end;
  if (dev(end) >= thr) return false;     // three samples or more: not a transient
  const float peak = dev(i) > dev(i + 1) ? dev(i) : dev(i + 1);
  float after = 0.0f;
  for (int j = end; j < end + kTransientQuiet; ++j) {
    const float d = dev(j);
    if (d >= thr) return false;
    if (d > after) after = d;
  }
  return peak >= kGlitchRatio * thr || after < 0.5f * thr;
}

float threshold_crossing(const int16_t* x, int n, float base, float thr, int start) {
  if (start < 1) start = 1;
  for (int i = start; i < n; ++i) {
    if (fabsf(static_cast<float>(x[i]) - base) < thr) continue;
    if (is_transient(x, n, i, base, thr)) {
      i += 2;
      continue;
    }
    return crossing_subsample(x, i, base, thr);
  }
  return -1.0f;
}

namespace {

#if defined(__GNUC__)
#define IC_INLINE inline __attribute__((always_inline))
#else
#define IC_INLINE inline
#endif

// The AIC / ln 2 at a split with n1 samples before it (variance + eps: y1) and n2 from it (y2).
IC_INLINE float aic_value(float n1, float y1, float n2, float y2) {
  return n1 * fast_log2(y1) + (n2 - 1.0f) * fast_log2(y2);
}

// A lower bound of fast_log2(v) for v in the AIC's range (1e-3 <= v < 2^32), without the series: the bits
// of v = 2^e m (1 <= m < 2) read as a fixed-point number are e + (m - 1) <= log2(v) (log2 lies above its
// chord on [1, 2]; 0.086 below at most). Minus 0.001: more than this line's rounding (< 3e-6) and
// fast_log2's error (< 3e-6, tests/test_core.py) together.
IC_INLINE float log2_below(float v) {
  int32_t u;
  memcpy(&u, &v, sizeof(u));
  return static_cast<float>(u - 0x3F800000) * (1.0f / 8388608.0f) - 0.001f;
}

// aic_value with log2_below for fast_log2. Never above aic_value(n1, y1, n2, y2) as computed: the float
// operations are the same, rounding to nearest is monotone and n1, n2 - 1 >= 0.
IC_INLINE float aic_below(float n1, float y1, float n2, float y2) {
  return n1 * log2_below(y1) + (n2 - 1.0f) * log2_below(y2);
}

// The variances (+ eps) either side of a split with n1 samples before it and n2 from it, from the running
// sums of the samples before it (s1, s2) and of the whole window (t1, t2), deviations about the window mean.
struct SplitVar {
  float y1, y2;
};
IC_INLINE SplitVar split_variances(float s1, float s2, float t1, float t2, float n1, float n2, float eps) {
  const float i1 = 1.0f / n1;
  const float i2 = 1.0f / n2;
  const float m1 = s1 * i1;
  const float v1 = s2 * i1 - m1 * m1;
  const float m2 = (t1 - s1) * i2;
  const float v2 = (t2 - s2) * i2 - m2 * m2;
  return {(v1 > 0.0f ? v1 : 0.0f) + eps, (v2 > 0.0f ? v2 : 0.0f) + eps};
}

// The first pass's record of one split: the variances' operands and the AIC's lower bound.
struct Split {
  float y1, y2, below;
};
constexpr int kMaxSplits = 64;  // splits searched in two passes (board 17, 100 kHz 33); more: one pass

// The AIC at split k from the first pass's record (sp[0] is split k_eval): n1 = k, n2 = len - k.
IC_INLINE float aic_split(const Split* sp, int k_eval, int len, int k) {
  const Split& p = sp[k - k_eval];
  return aic_value(static_cast<float>(k), p.y1, static_cast<float>(len - k), p.y2);
}

}  // namespace

float aic_pick_subsample(const int16_t* x, int begin, int end, int search_from) {
  IC_WORK(aic_picks, 1);
  if (begin < 0) begin = 0;
  const int len = end - begin;
  if (len < 6 || len > kMaxAicWindow) return -1.0f;
  // The arg-min is sought over k >= k_first; with k_first > 2 the AIC at k_first - 1 is evaluated too, as
  // the parabola's left neighbour. Before that only the running sums advance (no logs).
  int k_first = search_from - begin;
  if (k_first < 2) k_first = 2;
  if (k_first > len - 2) k_first = len - 2;
  const int k_eval = k_first > 2 ? k_first - 1 : 2;
  const int16_t* w = x + begin;
  // Centre the window to keep the float running sums well conditioned. The mean from the integer sum:
  // a float sum of these integers would be exact too (|partial sums| <= 512 x 32768 = 2^24).
  const int32_t isum = range_sum(w, 0, len);
  const float mean = static_cast<float>(isum) / static_cast<float>(len);
  // AIC / ln 2 = k log2 var(x[0..k)) + (len - k - 1) log2 var(x[k..len)), one pass with the sums s1, s2
  // over x[0..k) running; the values either side of the best k are kept for the parabola. The sums over
  // the whole window (t1, t2) continue those over x[0..k_eval) in the same order: one pass for both.
  const float eps = 1e-3f;
  float s1 = 0.0f, s2 = 0.0f;
  for (int i = 0; i < k_eval; ++i) {
    const float d = static_cast<float>(w[i]) - mean;
    s1 += d;
    s2 += d * d;
  }
  float t1 = s1, t2 = s2;
  for (int i = k_eval; i < len; ++i) {
    const float d = static_cast<float>(w[i]) - mean;
    t1 += d;
    t2 += d * d;
  }
  float best = 0.0f, best_prev = 0.0f, best_next = 0.0f;
  int best_k = -1;
  const int splits = len - 1 - k_eval;  // k = k_eval .. len - 2
  if (splits <= kMaxSplits) {
    // Two passes, the logarithms only where the minimum can be. The first runs the sums and keeps, for
    // every k, the operands y1, y2 and a lower bound of the AIC (aic_below, no series); kc is the k >=
    // k_first with the least bound. The second computes the AIC at kc, then, in order, only at the k whose
    // bound is below the least AIC found so far (before kc: not above it). That finds what a one-pass
    // scan finds, the first k of the least AIC, k*: the AIC so far is never below aic(k*), and after kc it
    // is above it (k* is the first of the least, kc is not), so k*'s bound (<= aic(k*)) passes; a skipped
    // k's AIC is not below the least so far (not above it, before kc), so it could not have replaced it
    // in the scan. The AIC at a k is the same expression on the same operands as in the one-pass scan
    // (n1 = k, n2 = len - k exactly), so the same float; so are the parabola's neighbours. On the board's
    // captures 3-4 of the ~17 AICs are computed.
    Split sp[kMaxSplits];
    int kc = -1;
    float kc_below = 0.0f;
    float n1 = static_cast<float>(k_eval), n2 = static_cast<float>(len - k_eval);
    for (int j = 0; j < splits; ++j, n1 += 1.0f, n2 -= 1.0f) {
      const SplitVar v = split_variances(s1, s2, t1, t2, n1, n2, eps);
      Split& p = sp[j];
      p.y1 = v.y1;
      p.y2 = v.y2;
      p.below = aic_below(n1, p.y1, n2, p.y2);
      if (k_eval + j >= k_first && (kc < 0 || p.below < kc_below)) {
        kc = k_eval + j;
        kc_below = p.below;
      }
      const float d = static_cast<float>(w[k_eval + j]) - mean;
      s1 += d;
      s2 += d * d;
    }
    best = aic_split(sp, k_eval, len, kc);
    best_k = kc;
    for (int k = k_first; k < kc; ++k) {
      if (sp[k - k_eval].below > best) continue;
      const float aic = aic_split(sp, k_eval, len, k);
      if (aic <= best && (aic < best || k < best_k)) {
        best = aic;
        best_k = k;
      }
    }
    for (int k = kc + 1; k <= len - 2; ++k) {
      if (sp[k - k_eval].below >= best) continue;
      const float aic = aic_split(sp, k_eval, len, k);
      if (aic < best) {
        best = aic;
        best_k = k;
      }
    }
    // The parabola's neighbours (used when 2 < best_k < len - 2; k_eval <= best_k - 1 then).
    if (best_k > k_eval) best_prev = aic_split(sp, k_eval, len, best_k - 1);
    if (best_k < len - 2) best_next = aic_split(sp, k_eval, len, best_k + 1);
  } else {
    float prev = 0.0f;
    bool want_next = false;
    float n1 = static_cast<float>(k_eval), n2 = static_cast<float>(len - k_eval);
    for (int k = k_eval; k <= len - 2; ++k, n1 += 1.0f, n2 -= 1.0f) {
      const SplitVar v = split_variances(s1, s2, t1, t2, n1, n2, eps);
      const float aic = aic_value(n1, v.y1, n2, v.y2);
      if (want_next) {
        best_next = aic;
        want_next = false;
      }
      if (k >= k_first && (best_k < 0 || aic < best)) {
        best = aic;
        best_k = k;
        best_prev = prev;
        want_next = true;
      }
      prev = aic;
      const float d = static_cast<float>(w[k]) - mean;
      s1 += d;
      s2 += d * d;
    }
  }
  if (best_k < 0) return -1.0f;
  // Parabola through the minimum and its neighbours: the sub-sample position of the minimum.
  float offset = 0.0f;
  if (best_k > 2 && best_k < len - 2) {
    const float curv = best_prev - 2.0f * best + best_next;
    if (curv > 0.0f) offset = 0.5f * (best_prev - best_next) / curv;
    if (offset > 0.5f) offset = 0.5f;
    if (offset < -0.5f) offset = -0.5f;
  }
  return static_cast<float>(begin + best_k) + offset;
}

int aic_pick(const int16_t* x, int begin, int end) {
  const float k = aic_pick_subsample(x, begin, end, begin);
  return k < 0.0f ? -1 : static_cast<int>(k + 0.5f);
}

float pick_period(const int16_t* x, int n, float base, float cross, bool wide) {
  if (!(cross >= 0.0f)) return NAN;
  const int at = static_cast<int>(cross);
  const int reach = wide ? kPeriodSearchWide : kPeriodSearch;
  // The zero crossing at or before the threshold crossing: the last sign change within `reach`
  // samples before it (the pair around the crossing included); the loop leaves i one below its pair.
  float z[4];
  int found = 0;
  int lo = at - reach;
  if (lo < 0) lo = 0;
  int i = at + 1 < n ? at + 1 : n - 1;
  for (; i > lo && found == 0; --i) {
    const float a = static_cast<float>(x[i - 1]) - base, b = static_cast<float>(x[i]) - base;
    if ((a < 0.0f) != (b < 0.0f)) {
      const float zc = static_cast<float>(i - 1) + a / (a - b);
      if (zc <= cross) {
        z[0] = zc;
        found = 1;
      }
    }
  }
  if (found == 0) return NAN;
  // The next three, with the shortest and longest half period; the loop leaves j one above the last's pair.
  int hi = at + reach;
  if (hi > n - 1) hi = n - 1;
  // Starts that a VFP immediate holds (no literal): no half period reaches kPeriodHalfRatio x 31 (the span is at most
  // 2 reach + 1 samples), and the longest is over 2/3 (the last crossing lies 2 pairs past the first's).
  static_assert(kPeriodHalfRatio * 31.0f > 2 * kPeriodSearchWide + 1, "h_min's start");
  float h_min = 31.0f, h_max = 0.5f;
  int j = at;
  for (; j < hi && found < 4; ++j) {
    const float a = static_cast<float>(x[j]) - base, b = static_cast<float>(x[j + 1]) - base;
    if ((a < 0.0f) != (b < 0.0f)) {
      const float zc = static_cast<float>(j) + a / (a - b);
      if (zc > z[found - 1]) {
        const float h = zc - z[found - 1];
        z[found++] = zc;
        if (h < h_min) h_min = h;
        if (h > h_max) h_max = h;
      }
    }
  }
  if (found < 4) return NAN;
  // Beyond the short search (a pair further than kPeriodSearch from the crossing): one cycle only.
  if ((at - i > kPeriodSearch || j - at > kPeriodSearch) && h_max > kPeriodHalfRatio * h_min) return NAN;
  return (z[3] - z[0]) * (2.0f / 3.0f);
}

// 2^t from IEEE float +, -, * and the exponent's bits (2^k times a degree-7 series of e^(f ln 2) for
// f = t - k in [-1/2, 1/2]: truncation < 6e-9 relative). With fast_log2 it gives the dispersion scales the same
// bits on the board and the host, where libm's powf is not the same function: newlib's differed from glibc's by
// one ulp on a recorded drop, which moved the localiser's end along a flat Huber valley, so the board's report
// was not the host's.
static float portable_exp2(float t) {
  if (t > 127.0f) t = 127.0f;
  if (t < -126.0f) t = -126.0f;
  const int32_t k = static_cast<int32_t>(t >= 0.0f ? t + 0.5f : t - 0.5f);
  const float z = (t - static_cast<float>(k)) * 0.693147181f;
  const float e = 1.0f + z * (1.0f + z * (0.5f + z * (1.0f / 6.0f + z * (1.0f / 24.0f + z * (1.0f / 120.0f +
                  z * (1.0f / 720.0f + z * (1.0f / 5040.0f)))))));
  const int32_t bits = (k + 127) << 23;
  float two_k;
  memcpy(&two_k, &bits, sizeof(two_k));
  return e * two_k;
}

void dispersion_scales(const EventFeatures& f, float fs_hz, float exponent, float ref_hz,
                       float out[kChannels]) {
  for (int c = 0; c < kChannels; ++c) {
    const float period = f.ch[c].pick_period;
    out[c] = 1.0f;
    if (period > 0.0f && ref_hz > 0.0f && fs_hz > 0.0f) out[c] = portable_exp2(-exponent * fast_log2(fs_hz / (period * ref_hz)));
  }
}

}  // namespace impactcore
