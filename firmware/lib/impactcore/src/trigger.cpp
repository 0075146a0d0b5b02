// Streaming threshold trigger with hysteresis, hold-off and re-arm: the only state in the core.
#include <math.h>

#include "impactcore.h"

namespace impactcore {

Trigger::Trigger(const TriggerConfig& cfg, float initial_baseline) : cfg_(cfg) {
  quiet_step_unclamped_ = cfg_.noise_factor >= 2.5f && cfg_.noise_alpha >= 0.0f && cfg_.noise_alpha <= 0.5f;
  for (int c = 0; c < kChannels; ++c) {
    baseline_[c] = initial_baseline;
    noise_var_[c] = 0.0f;
    thr_[c] = cfg_.threshold_counts;
    above_[c] = 0;
  }
}

Trigger::Trigger(const TriggerConfig& cfg, const float initial_baseline[kChannels]) : Trigger(cfg, 0.0f) {
  for (int c = 0; c < kChannels; ++c) baseline_[c] = initial_baseline[c];
}

float Trigger::noise_rms(int c) const { return vsqrt_f32(noise_var_[c]); }

float Trigger::threshold() const {
  float t = thr_[0];
  for (int c = 1; c < kChannels; ++c) t = thr_[c] > t ? thr_[c] : t;
  return t;
}

// dev: this frame's deviation from the baseline (the baseline has not moved since it was taken).
__attribute__((always_inline)) inline void Trigger::track_baseline(const float dev[kChannels]) {
  // Each step is limited to the channel's threshold: a glitch of any size moves the baseline by at most
  // baseline_alpha x threshold (a fraction of it), a hum or an offset is followed, a stale start recovers.
  #pragma GCC unroll 4
  for (int c = 0; c < kChannels; ++c) {
    const float d = dev[c] > thr_[c] ? thr_[c] : (dev[c] < -thr_[c] ? -thr_[c] : dev[c]);
    baseline_[c] += cfg_.baseline_alpha * d;
  }
}

bool Trigger::feed(const int16_t frame[kChannels]) {
  bool above = false;
  uint32_t up_mask = 0;  // bit c: channel c above its threshold on this frame
  float dev[kChannels];
  #pragma GCC unroll 4
  for (int c = 0; c < kChannels; ++c) {
    dev[c] = static_cast<float>(frame[c]) - baseline_[c];
    const bool up = fabsf(dev[c]) >= thr_[c];
    above |= up;
    up_mask |= (up ? 1u : 0u) << c;
    above_[c] = ((above_[c] << 1) | (up ? 1u : 0u)) & ((1u << kTriggerHistory) - 1u);
  }
  const long now = frames_++;
  switch (state_) {
    case kArmed: {
      // Fires when a channel has fire_frames of the last kTriggerHistory frames above its threshold. Only a
      // channel above on this frame can have reached that count now (armed, every count was below it on the
      // previous frame, and a frame without a new bit only shifts bits out), so only those are counted.
      int count = 0;
      for (uint32_t m = up_mask; m != 0; m &= m - 1) {
        int k = 0;
        for (uint32_t h = above_[__builtin_ctz(m)]; h != 0; h &= h - 1) ++k;
        if (k > count) count = k;
      }
      if (count >= cfg_.fire_frames) {
        fired_at_ = now;
        state_ = kHoldoff;
        counter_ = 0;
        return true;
      }
      if (!above) {
        // The noise floor from the quiet frames: each channel's threshold follows it. A frame adds at most
        // (threshold / 2)^2: a slowly rising arrival cannot raise the threshold it has to cross.
        #pragma GCC unroll 4
        for (int c = 0; c < kChannels; ++c) {
          const float cap = 0.25f * thr_[c] * thr_[c];
          const float d2 = dev[c] * dev[c] < cap ? dev[c] * dev[c] : cap;
          noise_var_[c] += cfg_.noise_alpha * (d2 - noise_var_[c]);
          const float t = cfg_.noise_factor * vsqrt_f32(noise_var_[c]);
          thr_[c] = t > cfg_.threshold_counts ? t : cfg_.threshold_counts;
        }
        if (quiet_step_unclamped_) {
          // Every |dev| < its threshold before the update, and still after it: with d2 = min(dev^2, thr^2 / 4),
          // d2 >= var leaves var, and the threshold, no lower (the operations are monotone); d2 < var needs
          // |dev| < sigma <= thr / 2.5 (thr >= noise_factor sigma, thr^2 / 4 >= 1.56 var), and the threshold
          // falls to no less than sqrt(1 - noise_alpha) >= 0.7 of it, or stays at threshold_counts. So the
          // clamp in track_baseline is the identity here: the same floats, ~7 instructions a channel less.
          #pragma GCC unroll 4
          for (int c = 0; c < kChannels; ++c) baseline_[c] += cfg_.baseline_alpha * dev[c];
          return false;
        }
      }
      track_baseline(dev);
      return false;
    }
    case kHoldoff:
      track_baseline(dev);
      if (++counter_ >= cfg_.holdoff_frames) {
        state_ = kWaitQuiet;
        counter_ = 0;
      }
      return false;
    case kWaitQuiet:
      // The baseline keeps tracking while the plate rings down (the ringing averages out): a baseline that
      // was wrong when armed -- a hit during warm-up, a drifting bias -- converges, so the trigger re-arms
      // instead of waiting for a quiet that its stale baseline never shows.
      track_baseline(dev);
      {
        // Quiet: every channel below rearm_counts, or half its threshold when the noise floor raised it.
        bool quiet = true;
        for (int c = 0; c < kChannels; ++c) {
          const float q = 0.5f * thr_[c] > cfg_.rearm_counts ? 0.5f * thr_[c] : cfg_.rearm_counts;
          quiet &= fabsf(dev[c]) < q;
        }
        counter_ = quiet ? counter_ + 1 : 0;
      }
      if (counter_ >= cfg_.rearm_quiet_frames) {
        state_ = kArmed;
        counter_ = 0;
        for (int c = 0; c < kChannels; ++c) above_[c] = 0;
      }
      return false;
  }
  return false;
}

long find_trigger(const int16_t* const adc[kChannels], int n, const TriggerConfig& cfg) {
  // Start from the mean of the first frames so a recording's bias does not fire the trigger.
  const int warm = n < 32 ? n : 32;
  float base = 0.0f;
  for (int c = 0; c < kChannels; ++c) {
    for (int i = 0; i < warm; ++i) base += static_cast<float>(adc[c][i]);
  }
  base /= static_cast<float>(warm * kChannels > 0 ? warm * kChannels : 1);
  Trigger trig(cfg, base);
  int16_t frame[kChannels];
  for (int i = 0; i < n; ++i) {
    for (int c = 0; c < kChannels; ++c) frame[c] = adc[c][i];
    if (trig.feed(frame)) return i;
  }
  return -1;
}

}  // namespace impactcore
