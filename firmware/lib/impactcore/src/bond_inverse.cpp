// The bond inverse: a debonded disc passes the plate's wave through a one-pole low-pass and a gain
// (docs/method.md, "The bond inverse"); a channel with bond_corner_hz > 0 is picked on the capture through
// its inverse, limited above bond_limit_hz, so the threshold crossing lands on the arrival's first cycle as
// on the other channels. Cost: one multiply-add pair and a rounding a sample, on the channel's span only
// (bond_span_end: from the capture start to the windows the pick, the band pick and the difference energies
// read); the channel's features read that span alone.
#include <math.h>
#include <stdint.h>
#if defined(__ARM_FEATURE_SAT)
#include <arm_acle.h>
#endif

#include "impactcore.h"

namespace impactcore {

int32_t check_bond_inverse(const CoreConfig& cfg) {
  int on = 0;
  for (int c = 0; c < kChannels; ++c) {
    const float fc = cfg.bond_corner_hz[c];
    if (fc == 0.0f) continue;
    const float f2 = cfg.bond_limit_hz[c], g = cfg.bond_gain[c];
    if (!(fc > 0.0f) || !(f2 > fc) || !(g > 0.0f) || isinf(fc) || isinf(f2) || isinf(g)) return kErrBadConfig;
    ++on;
  }
  return on > kMaxBondChannels ? kErrBadConfig : kOk;
}

int bond_span_end(const CoreConfig& cfg, int n, float anchor) {
  const int limit = n < kBondSpanMax ? n : kBondSpanMax;
  const int dcap = static_cast<int>(cfg.diff_window_us * cfg.fs_hz * 1.0e-6f + 0.5f);
  if (!(anchor >= 0.0f) || dcap <= 0) return limit;
  int reach = kBondReach * dcap + cfg.aic_after;
  if (cfg.band_pick_hz > 0.0f) {
    const int band = static_cast<int>(cfg.band_window_us * cfg.fs_hz * 1.0e-6f + 0.5f);
    if (band > reach) reach = band;
  }
  const int floor_n = cfg.baseline_samples + 16;  // what extract_features asks of a capture
  const float end = anchor + 1.0f + static_cast<float>(reach);
  int e = end < static_cast<float>(limit) ? static_cast<int>(end) : limit;
  if (e < floor_n) e = floor_n < limit ? floor_n : limit;
  return e;
}

namespace {

// One sample of the inverse: y = (b0 v + b1 v_prev) - a1 y_prev, v = x - x0; out = x0 + y to the nearest count
// (halves up: truncation of r + 32768.5 less 32768), held to the rails in integers. kHigh > 0: the rails are
// [0, kHigh], known to the compiler (one USAT on the M4F for a 2^k - 1 rail); 0: [lo, hi] at run time.
template <int kHigh>
struct BondStep {
  float b0, b1, a1, x0;
  int32_t lo, hi;
  uint32_t range;
  __attribute__((always_inline)) inline float operator()(int16_t xi, float& pv, float py, int16_t* o) const {
    const float v = static_cast<float>(xi) - x0;
    const float y = (b0 * v + b1 * pv) - a1 * py;
    pv = v;
    int32_t s = static_cast<int32_t>((x0 + y) + 32768.5f) - 32768;
    if (kHigh > 0) {
#if defined(__ARM_FEATURE_SAT)
      static_assert(kHigh <= 0 || ((kHigh + 1) & kHigh) == 0, "kHigh is a 2^k - 1 rail");
      s = static_cast<int32_t>(__usat(s, __builtin_ctz(static_cast<unsigned>(kHigh) + 1u)));
#else
      s = s < 0 ? 0 : (s > kHigh ? kHigh : s);
#endif
    } else if (__builtin_expect(static_cast<uint32_t>(s - lo) > range, 0)) {  // on a rail: rare
      s = s < lo ? lo : hi;
    }
    *o = static_cast<int16_t>(s);
    return y;
  }
};

// The loop, eight samples a pass (the state stays in registers).
template <int kHigh>
void bond_loop(const int16_t* x, int n, float b0, float b1, float a1, int32_t lo, int32_t hi, int16_t* out) {
  const BondStep<kHigh> step{b0, b1, a1, static_cast<float>(x[0]), lo, hi, static_cast<uint32_t>(hi - lo)};
  float pv = 0.0f, py = 0.0f;
  const int16_t* p = x;
  const int16_t* const run_end = x + (n & ~7);
  while (p != run_end) {
    py = step(p[0], pv, py, out);
    py = step(p[1], pv, py, out + 1);
    py = step(p[2], pv, py, out + 2);
    py = step(p[3], pv, py, out + 3);
    py = step(p[4], pv, py, out + 4);
    py = step(p[5], pv, py, out + 5);
    py = step(p[6], pv, py, out + 6);
    py = step(p[7], pv, py, out + 7);
    p += 8;
    out += 8;
  }
  for (const int16_t* const end = x + n; p != end; ++p, ++out) py = step(*p, pv, py, out);
}

}  // namespace

void bond_inverse(const int16_t* x, int n, float fc_hz, float gain, float f2_hz, const CoreConfig& cfg,
                  int16_t* out) {
  // s = 2 fs (z - 1) / (z + 1): H(z) = (b0 + b1 z^-1) / (1 + a1 z^-1) with k1 = 2 fs / wc, k2 = 2 fs / w2,
  // b0 = (1 + k1) / (g (1 + k2)), b1 = (1 - k1) / (g (1 + k2)), a1 = (1 - k2) / (1 + k2).
  const float two_pi = 6.28318530717958647692f;
  const float k1 = 2.0f * cfg.fs_hz / (two_pi * fc_hz);
  const float k2 = 2.0f * cfg.fs_hz / (two_pi * f2_hz);
  const float norm = 1.0f / (gain * (1.0f + k2));
  const float b0 = (1.0f + k1) * norm, b1 = (1.0f - k1) * norm, a1 = (1.0f - k2) / (1.0f + k2);
  const bool rails = cfg.adc_max > cfg.adc_min;
  const int32_t lo = rails ? cfg.adc_min : -32768, hi = rails ? cfg.adc_max : 32767;
  const float x0 = static_cast<float>(x[0]);
  // r = x0 + y to the nearest count (halves up: truncation of r + 32768.5, one VCVT on the M4F), held to the
  // rails after the rounding, in integers (the rounding is monotone and the rails whole counts, so this is the
  // rails' clamp of r then rounded, bit for bit, while r + 32768.5 stays inside int32: |y| is at most the
  // filter's l1 gain x 2^16; a filter that could leave it (a corner near 0 Hz) takes the float clamp).
  const float l1 = fabsf(b0) + fabsf(b1 - a1 * b0) / (1.0f - fabsf(a1));
  if (lo < -32768 || hi > 32767 || !(l1 < 16384.0f)) {
    const float flo = static_cast<float>(lo), fhi = static_cast<float>(hi);
    float prev_v = 0.0f, prev_y = 0.0f;
    for (int i = 0; i < n; ++i) {
      const float v = static_cast<float>(x[i]) - x0;
      const float y = (b0 * v + b1 * prev_v) - a1 * prev_y;
      prev_v = v;
      prev_y = y;
      float r = x0 + y;
      r = r < flo ? flo : (r > fhi ? fhi : r);
      out[i] = static_cast<int16_t>(static_cast<int32_t>(r + 32768.5f) - 32768);
    }
    return;
  }
  if (lo == 0 && hi == 4095) {  // a 12-bit ADC's rails (the board's)
    bond_loop<4095>(x, n, b0, b1, a1, lo, hi, out);
  } else {
    bond_loop<0>(x, n, b0, b1, a1, lo, hi, out);
  }
}

}  // namespace impactcore
