// The channel check: one channel's energies against the other three's (impactcore.h, "the channel check").
#include <math.h>

#include "impactcore.h"

namespace impactcore {

namespace {

constexpr float kLog10Of2 = 0.301029996f;
constexpr float kFloor = 1e-30f;

inline float log10_floored(float v) { return fast_log2(v > kFloor ? v : kFloor) * kLog10Of2; }

inline bool finite(float v) { return v - v == 0.0f; }

// -z of a ratio against its fit at the cubic's terms.
float neg_z(float value, const ChannelCheckFit& fit, const float terms[kCheckTerms]) {
  float expected = fit.median;
  for (int k = 0; k < kCheckTerms; ++k) expected += fit.coef[k] * terms[k];
  return (expected - value) / fit.scale;
}

// Median of the n (>= 1) values in v (sorted in place; n <= kMaxCheckEvents).
float median_of(float* v, int n) {
  for (int i = 1; i < n; ++i) {
    const float t = v[i];
    int j = i - 1;
    while (j >= 0 && v[j] > t) {
      v[j + 1] = v[j];
      --j;
    }
    v[j + 1] = t;
  }
  return (n & 1) ? v[n / 2] : 0.5f * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace

void channel_check_terms(float x_mm, float y_mm, float plate_x_mm, float plate_y_mm, float out[kCheckTerms]) {
  const float x = x_mm / plate_x_mm * 2.0f - 1.0f;
  const float y = y_mm / plate_y_mm * 2.0f - 1.0f;
  int k = 0;
  float xi = 1.0f;
  for (int i = 0; i < 4; ++i) {
    float term = xi;
    for (int j = 0; j < 4 - i; ++j) {
      out[k++] = term;
      term *= y;
    }
    xi *= x;
  }
}

void channel_check_ratios(const float energy[kChannels], const float diff3[kChannels], float level[kChannels],
                          float tilt[kChannels]) {
  float log_e[kChannels], log_t[kChannels], sum_e = 0.0f, sum_t = 0.0f;
  for (int c = 0; c < kChannels; ++c) {
    log_e[c] = log10_floored(energy[c]);
    log_t[c] = log10_floored(diff3[c]) - log_e[c];
    sum_e += log_e[c];
    sum_t += log_t[c];
  }
  for (int c = 0; c < kChannels; ++c) {
    level[c] = log_e[c] - (sum_e - log_e[c]) * (1.0f / 3.0f);
    tilt[c] = log_t[c] - (sum_t - log_t[c]) * (1.0f / 3.0f);
  }
}

void channel_check_scores(const float energy[kChannels], const float diff3[kChannels], const uint8_t flags[kChannels],
                          const float xy_mm[2 * kChannels], const ChannelCheck& check, float out[kChannels]) {
  bool read = true;
  for (int c = 0; c < kChannels; ++c) {
    out[c] = NAN;
    if (flags[c] & (kFlagNoOnset | kFlagDead)) read = false;
  }
  if (!read) return;
  float level[kChannels], tilt[kChannels], terms[kCheckTerms];
  channel_check_ratios(energy, diff3, level, tilt);
  bool have_terms = false;  // the terms at the previous channel's position (one position for all four: once)
  for (int c = 0; c < kChannels; ++c) {
    const float x = xy_mm[2 * c], y = xy_mm[2 * c + 1];
    if (!finite(x) || !finite(y)) continue;
    if (!have_terms || x != xy_mm[2 * c - 2] || y != xy_mm[2 * c - 1]) {
      channel_check_terms(x, y, check.plate_x_mm, check.plate_y_mm, terms);
      have_terms = true;
    }
    const float nzl = neg_z(level[c], check.level[c], terms);
    const float nzt = neg_z(tilt[c], check.tilt[c], terms);
    const float both = nzl < nzt ? nzl : nzt;
    const float alone = kCheckLevelAlone * nzl;
    out[c] = both > alone ? both : alone;
  }
}

int channel_check_flag(const float* window, int rows, const ChannelCheck& check) {
  if (rows < 1) return -1;
  const float* now = window + kChannels * (rows - 1);
  int top = -1;
  for (int c = 0; c < kChannels; ++c) {
    if (finite(now[c]) && (top < 0 || now[c] > now[top])) top = c;
  }
  if (top < 0) return -1;   // this event is not checked
  if (now[top] > check.event_score) return top;
  int w = check.run_events < kMaxCheckEvents ? check.run_events : kMaxCheckEvents;
  if (rows < w) w = rows;
  if (w < (check.run_events + 1) / 2) return -1;
  int best = -1;
  float best_median = 0.0f;
  float v[kMaxCheckEvents];
  for (int c = 0; c < kChannels; ++c) {
    int n = 0;
    for (int r = rows - w; r < rows; ++r) {
      const float s = window[kChannels * r + c];
      if (finite(s)) v[n++] = s;
    }
    if (n == 0) continue;
    const float m = median_of(v, n);
    if (best < 0 || m > best_median) {
      best = c;
      best_median = m;
    }
  }
  if (best < 0 || !(best_median > check.run_score) || !finite(now[best])) return -1;
  return best;
}

}  // namespace impactcore
