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
  const float lo = rails ? static_cast<float>(cfg.adc_min) : -32768.0f;
  const float hi = rails ? static_cast<float>(cfg.adc_max) : 32767.0f;
  const float x0 = static_cast<float>(x[0]);
  float prev_v = 0.0f, prev_y = 0.0f;
  for (int i = 0; i < n; ++i) {
    const float v = static_cast<float>(x[i]) - x0;
    const float bx = b0 * v;
    const float bp = b1 * prev_v;
    const float ay = a1 * prev_y;
    const float y = (bx + bp) - ay;
    prev_v = v;
    prev_y = y;
    float r = x0 + y;
    r = r < lo ? lo : (r > hi ? hi : r);
    // to the nearest count (halves up): truncation of a positive value, no library call (one VCVT on the M4F)
    out[i] = static_cast<int16_t>(static_cast<int32_t>(r + 32768.5f) - 32768);
  }
}

}  // namespace impactcore
