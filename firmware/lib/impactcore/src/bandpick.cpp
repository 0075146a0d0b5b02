// The band pick: the onset of a channel's envelope at one frequency (impactcore.h, band_onset).
#include <math.h>

#include "impactcore.h"

namespace impactcore {

float band_onset(const int16_t* x, int n, float baseline, float noise_rms, int anchor, const CoreConfig& cfg) {
  const float nan = NAN;
  const float fs = cfg.fs_hz;
  const float f0 = cfg.band_pick_hz;
  if (x == nullptr || !(fs > 0.0f) || !(f0 > 0.0f) || f0 >= kBandMaxRate * fs || anchor < 0 || anchor >= n ||
      !(cfg.band_pick_fraction > 0.0f) || !(cfg.band_pick_fraction < 1.0f) || !(cfg.band_window_us > 0.0f)) {
    return nan;
  }
  const float wc = 6.28318531f * (f0 / kBandCutoffDivisor) / fs;
  const float alpha = wc / (1.0f + wc);
  int lo = anchor - static_cast<int>(kBandBeforeUs * 1e-6f * fs + 0.5f);
  int hi = anchor + static_cast<int>(cfg.band_window_us * 1e-6f * fs + 0.5f);
  if (lo < 0) lo = 0;
  if (hi > n) hi = n;
  if (hi - lo > kBandMaxWindow) hi = lo + kBandMaxWindow;
  if (hi - lo < 2) return nan;
  // The cascade settles within ~2 kBandPoles time constants (1 / alpha samples each) before the window.
  int start = lo - static_cast<int>(2.0f * kBandPoles / alpha + 0.5f);
  if (start < 0) start = 0;
  const float w = 6.28318531f * f0 / fs;
  float rot_s, rot_c;
  sin_cos(w, &rot_s, &rot_c);
  float ph_s = 0.0f, ph_c = 1.0f;   // the envelope does not depend on the phasor's starting phase
  float si[kBandPoles] = {}, sq[kBandPoles] = {};
  float env2[kBandMaxWindow];
  float peak2 = 0.0f;
  int ipeak = 0;
  for (int i = start; i < hi; ++i) {
    const float v = static_cast<float>(x[i]) - baseline;
    float a = v * ph_c, b = v * ph_s;
    for (int k = 0; k < kBandPoles; ++k) {
      si[k] += alpha * (a - si[k]);
      sq[k] += alpha * (b - sq[k]);
      a = si[k];
      b = sq[k];
    }
    const float c = ph_c * rot_c - ph_s * rot_s;
    ph_s = ph_s * rot_c + ph_c * rot_s;
    ph_c = c;
    if (i >= lo) {
      const float e2 = a * a + b * b;
      env2[i - lo] = e2;
      if (e2 > peak2) {
        peak2 = e2;
        ipeak = i - lo;
      }
    }
  }
  float floor = kBandNoiseFactor * noise_rms;
  if (cfg.band_noise_counts > 0.0f) {
    // E|envelope|^2 of white noise = noise_rms^2 x sum h^2 of the cascade, (alpha / (1 - beta z^-1))^4:
    // alpha^8 sum C(n+3, 3)^2 beta^2n = alpha (1 + 9 b + 9 b^2 + b^3) / (2 - alpha)^7, b = beta^2.
    static_assert(kBandPoles == 4, "the envelope's noise gain is the four-pole cascade's");
    const float b = (1.0f - alpha) * (1.0f - alpha), d = 2.0f - alpha, d2 = d * d;
    const float gain2 = alpha * (1.0f + b * (9.0f + b * (9.0f + b))) / (d2 * d2 * d2 * d);
    const float env = kBandEnvFactor * noise_rms * vsqrt_f32(gain2);
    floor = kBandNoiseFactor * cfg.band_noise_counts;
    if (env > floor) floor = env;
  }
  const float peak = vsqrt_f32(peak2);
  if (!(peak >= 2.0f * floor) || !(peak > 0.0f)) return nan;
  float level = cfg.band_pick_fraction * peak;
  if (level < floor) level = floor;
  const float level2 = level * level;
  int k = 0;
  while (k < ipeak && env2[k] < level2) ++k;
  if (k == 0) return static_cast<float>(lo);
  const float e0 = vsqrt_f32(env2[k - 1]);
  const float e1 = vsqrt_f32(env2[k]);
  const float t = e1 > e0 ? (level - e0) / (e1 - e0) : 1.0f;
  return static_cast<float>(lo + k - 1) + t;
}

}  // namespace impactcore
