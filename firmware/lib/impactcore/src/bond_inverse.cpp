// The bond inverse: a debonded disc passes the plate's wave through a one-pole low-pass and a gain
// (docs/method.md, "The bond inverse"); a channel with bond_corner_hz > 0 is picked on the capture through
// its inverse, limited above bond_limit_hz, so the threshold crossing lands on the arrival's first cycle as
// on the other channels. Cost: one multiply-add pair and a rounding a sample, on the channel's span only
// (bond_span_end: from the capture start to the windows the pick, the band pick and the difference energies
// read); the channel's features read that span alone.
#include <math.h>
#include <stdint.h>

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
  const uint32_t range = static_cast<uint32_t>(hi - lo);
  // y_i = (b0 v_i + b1 v_(i-1)) - a1 y_(i-1), v_i = x_i - x_0, two samples a pass (the state stays in registers).
  float pv = 0.0f, py = 0.0f;
  const int16_t* p = x;
  const int16_t* const pair_end = x + (n & ~1);
  while (p != pair_end) {
    const float v1 = static_cast<float>(p[0]) - x0;
    const float y1 = (b0 * v1 + b1 * pv) - a1 * py;
    const float v2 = static_cast<float>(p[1]) - x0;
    const float y2 = (b0 * v2 + b1 * v1) - a1 * y1;
    p += 2;
    pv = v2;
    py = y2;
    int32_t s1 = static_cast<int32_t>((x0 + y1) + 32768.5f) - 32768;
    int32_t s2 = static_cast<int32_t>((x0 + y2) + 32768.5f) - 32768;
    if (static_cast<uint32_t>(s1 - lo) > range) s1 = s1 < lo ? lo : hi;
    if (static_cast<uint32_t>(s2 - lo) > range) s2 = s2 < lo ? lo : hi;
    out[0] = static_cast<int16_t>(s1);
    out[1] = static_cast<int16_t>(s2);
    out += 2;
  }
  if (n & 1) {
    const float v = static_cast<float>(*p) - x0;
    const float y = (b0 * v + b1 * pv) - a1 * py;
    int32_t s = static_cast<int32_t>((x0 + y) + 32768.5f) - 32768;
    if (static_cast<uint32_t>(s - lo) > range) s = s < lo ? lo : hi;
    *out = static_cast<int16_t>(s);
  }
}

}  // namespace impactcore
