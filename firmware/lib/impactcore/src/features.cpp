// Per-channel onset and energy features of one capture.
#include <math.h>

#include "impactcore.h"

namespace impactcore {
namespace {

const float kNaN = NAN;

// Index of the first local maximum of |x - base| at or after `from` (the first lobe of the arrival).
int first_extremum(const int16_t* x, int n, float base, int from) {
  if (from < 0) from = 0;
  float prev = -1.0f;
  for (int i = from; i < n; ++i) {
    const float a = fabsf(static_cast<float>(x[i]) - base);
    if (a < prev) return i - 1;
    prev = a;
  }
  return n - 1;
}

// Amplitude features in units of a unit-gain channel (ratios are gain free).
void apply_gain(ChannelFeatures* f, float gain) {
  if (!(gain > 0.0f) || gain == 1.0f) return;
  const float inv = 1.0f / gain;
  const float inv2 = inv * inv;
  f->peak *= inv;
  f->first_peak *= inv;
  f->energy *= inv2;
  for (int w = 0; w < kEnergyWindows; ++w) f->window_energy[w] *= inv2;
}

void channel_features(const int16_t* x, int n, const CoreConfig& cfg, int c, ChannelFeatures* f) {
  baseline_stats(x, cfg.baseline_samples, &f->baseline, &f->noise_rms);
  const float base = f->baseline;
  f->flags = 0;

  // Energy, peak and clipping over the whole capture.
  float energy = 0.0f;
  float peak = 0.0f;
  bool clipped = false;
  for (int i = 0; i < n; ++i) {
    const int v = x[i];
    if (v <= cfg.adc_min || v >= cfg.adc_max) clipped = true;
    const float d = static_cast<float>(v) - base;
    energy += d * d;
    const float a = fabsf(d);
    if (a > peak) peak = a;
  }
  f->energy = energy;
  f->peak = peak;
  if (clipped) f->flags |= kFlagClipped;

  const float signal_rms = sqrtf(energy / static_cast<float>(n));
  if (peak == 0.0f || signal_rms < cfg.dead_rms_counts) f->flags |= kFlagDead;

  // Onset: sub-sample threshold crossing, refined by AIC in a window around it.
  // The onset threshold is in unit-gain counts: a channel with gain g crosses at the same wave phase.
  const float gain = cfg.channel_gain[c] > 0.0f ? cfg.channel_gain[c] : 1.0f;
  float thr = cfg.onset_threshold_counts * gain;
  const float noise_thr = cfg.onset_noise_factor * f->noise_rms;
  if (noise_thr > thr) thr = noise_thr;
  const float cross = threshold_crossing(x, n, base, thr, cfg.baseline_samples);
  f->toa_threshold = cross;
  f->toa_aic = kNaN;
  f->first_peak = 0.0f;
  f->n2 = n - 1;
  for (int w = 0; w < kEnergyWindows; ++w) f->window_energy[w] = 0.0f;
  f->residual_ratio = kNaN;
  if (cross < 0.0f || (f->flags & kFlagDead)) {
    f->flags |= kFlagNoOnset;
    f->toa_us = kNaN;
    apply_gain(f, cfg.channel_gain[c]);
    return;
  }
  const int icross = static_cast<int>(cross);
  int begin = icross - cfg.aic_before;
  if (begin < 0) begin = 0;
  int end = icross + cfg.aic_after + 1;
  if (end > n) end = n;
  const float aic = aic_pick_subsample(x, begin, end);
  float toa = cross;
  if (aic >= 0.0f && aic <= cross + 1.0f) {
    f->toa_aic = aic;
    toa = (1.0f - cfg.aic_blend) * cross + cfg.aic_blend * f->toa_aic;
  } else {
    f->flags |= kFlagAicFallback;
  }
  f->toa_us = toa * (1.0e6f / cfg.fs_hz) - cfg.channel_delay_us[c];

  const int ipk = first_extremum(x, n, base, icross);
  f->first_peak = fabsf(static_cast<float>(x[ipk]) - base);

  // n2: where the cumulative energy stops growing (reaches n2_fraction of the total).
  const float target = cfg.n2_fraction * energy;
  float cum = 0.0f;
  int n2 = n - 1;
  for (int i = 0; i < n; ++i) {
    const float d = static_cast<float>(x[i]) - base;
    cum += d * d;
    if (cum >= target) {
      n2 = i;
      break;
    }
  }
  f->n2 = n2;
  // Five equal windows from the onset to n2; the last one is the residual energy.
  const int start = static_cast<int>(toa);
  const int span = n2 + 1 - start;
  if (span >= kEnergyWindows) {
    for (int w = 0; w < kEnergyWindows; ++w) {
      const int a = start + (span * w) / kEnergyWindows;
      const int b = start + (span * (w + 1)) / kEnergyWindows;
      float e = 0.0f;
      for (int i = a; i < b; ++i) {
        const float d = static_cast<float>(x[i]) - base;
        e += d * d;
      }
      f->window_energy[w] = e;
    }
    f->residual_ratio = energy > 0.0f ? f->window_energy[kEnergyWindows - 1] / energy : kNaN;
  }
  apply_gain(f, cfg.channel_gain[c]);
}

}  // namespace

int32_t extract_features(const int16_t* const adc[kChannels], int n, const CoreConfig& cfg,
                         EventFeatures* out) {
  if (out == nullptr) return kErrNullInput;
  out->status = kOk;
  for (int c = 0; c < kChannels; ++c) {
    if (adc[c] == nullptr) return out->status = kErrNullInput;
  }
  if (n > kMaxSamples) return out->status = kErrTooManySamples;
  if (cfg.baseline_samples < 2 || n < cfg.baseline_samples + 16) {
    return out->status = kErrTooFewSamples;
  }
  if (!(cfg.fs_hz > 0.0f) || cfg.aic_before < 0 || cfg.aic_after < 0 ||
      cfg.aic_before + cfg.aic_after + 1 > kMaxAicWindow || !(cfg.n2_fraction > 0.0f) ||
      cfg.n2_fraction > 1.0f) {
    return out->status = kErrBadConfig;
  }
  int onsets = 0;
  for (int c = 0; c < kChannels; ++c) {
    channel_features(adc[c], n, cfg, c, &out->ch[c]);
    if (!(out->ch[c].flags & kFlagNoOnset)) ++onsets;
  }
  for (int p = 0; p < kPairs; ++p) {
    out->dtoa_us[p] = out->ch[kPairI[p]].toa_us - out->ch[kPairJ[p]].toa_us;
  }
  // ToA order: insertion sort, channels without an onset last.
  for (int c = 0; c < kChannels; ++c) out->order[c] = static_cast<uint8_t>(c);
  for (int a = 1; a < kChannels; ++a) {
    const uint8_t key = out->order[a];
    const float tk = out->ch[key].toa_us;
    int b = a - 1;
    while (b >= 0) {
      const float tb = out->ch[out->order[b]].toa_us;
      const bool later = (tb != tb) ? (tk == tk) : (tk == tk && tk < tb);
      if (!later) break;
      out->order[b + 1] = out->order[b];
      --b;
    }
    out->order[b + 1] = key;
  }
  if (onsets == 0) out->status = kErrNoTrigger;
  return out->status;
}

}  // namespace impactcore
