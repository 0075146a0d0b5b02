// Streaming threshold trigger with hysteresis, hold-off and re-arm: the only state in the core.
#include <math.h>

#include "impactcore.h"

namespace impactcore {

Trigger::Trigger(const TriggerConfig& cfg, float initial_baseline) : cfg_(cfg) {
  for (int c = 0; c < kChannels; ++c) baseline_[c] = initial_baseline;
}

bool Trigger::feed(const int16_t frame[kChannels]) {
  float level = 0.0f;
  for (int c = 0; c < kChannels; ++c) {
    const float a = fabsf(static_cast<float>(frame[c]) - baseline_[c]);
    if (a > level) level = a;
  }
  const long now = frames_++;
  switch (state_) {
    case kArmed:
      if (level >= cfg_.threshold_counts) {
        fired_at_ = now;
        state_ = kHoldoff;
        counter_ = 0;
        return true;
      }
      track_baseline(frame);
      return false;
    case kHoldoff:
      track_baseline(frame);
      if (++counter_ >= cfg_.holdoff_frames) {
        state_ = kWaitQuiet;
        counter_ = 0;
      }
      return false;
    case kWaitQuiet:
      // The baseline keeps tracking while the plate rings down (the ringing averages out): a baseline that
      // was wrong when armed -- a hit during warm-up, a drifting bias -- converges, so the trigger re-arms
      // instead of waiting for a quiet that its stale baseline never shows.
      track_baseline(frame);
      counter_ = (level < cfg_.rearm_counts) ? counter_ + 1 : 0;
      if (counter_ >= cfg_.rearm_quiet_frames) {
        state_ = kArmed;
        counter_ = 0;
      }
      return false;
  }
  return false;
}

void Trigger::track_baseline(const int16_t frame[kChannels]) {
  for (int c = 0; c < kChannels; ++c) {
    baseline_[c] += cfg_.baseline_alpha * (static_cast<float>(frame[c]) - baseline_[c]);
  }
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
