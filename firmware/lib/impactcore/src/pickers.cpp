// Onset pickers: plain functions of a buffer.
#include <math.h>

#include "impactcore.h"

namespace impactcore {

void baseline_stats(const int16_t* x, int n, float* mean, float* rms) {
  float s = 0.0f;
  for (int i = 0; i < n; ++i) s += static_cast<float>(x[i]);
  const float m = n > 0 ? s / static_cast<float>(n) : 0.0f;
  float ss = 0.0f;
  for (int i = 0; i < n; ++i) {
    const float d = static_cast<float>(x[i]) - m;
    ss += d * d;
  }
  *mean = m;
  *rms = n > 0 ? sqrtf(ss / static_cast<float>(n)) : 0.0f;
}

float threshold_crossing(const int16_t* x, int n, float base, float thr, int start) {
  if (start < 1) start = 1;
  for (int i = start; i < n; ++i) {
    const float a = fabsf(static_cast<float>(x[i]) - base);
    if (a >= thr) {
      const float a0 = fabsf(static_cast<float>(x[i - 1]) - base);
      const float frac = (a > a0) ? (thr - a0) / (a - a0) : 1.0f;
      return static_cast<float>(i - 1) + (frac < 0.0f ? 0.0f : frac);
    }
  }
  return -1.0f;
}

float aic_pick_subsample(const int16_t* x, int begin, int end) {
  if (begin < 0) begin = 0;
  const int len = end - begin;
  if (len < 6 || len > kMaxAicWindow) return -1.0f;
  // Centre the window to keep float prefix sums well conditioned.
  float mean = 0.0f;
  for (int i = begin; i < end; ++i) mean += static_cast<float>(x[i]);
  mean /= static_cast<float>(len);
  float s1[kMaxAicWindow + 1];
  float s2[kMaxAicWindow + 1];
  s1[0] = 0.0f;
  s2[0] = 0.0f;
  for (int k = 0; k < len; ++k) {
    const float d = static_cast<float>(x[begin + k]) - mean;
    s1[k + 1] = s1[k] + d;
    s2[k + 1] = s2[k] + d * d;
  }
  const float eps = 1e-3f;
  auto aic_at = [&](int k) {
    const float n1 = static_cast<float>(k);
    const float n2 = static_cast<float>(len - k);
    const float m1 = s1[k] / n1;
    const float v1 = s2[k] / n1 - m1 * m1;
    const float m2 = (s1[len] - s1[k]) / n2;
    const float v2 = (s2[len] - s2[k]) / n2 - m2 * m2;
    return n1 * logf((v1 > 0.0f ? v1 : 0.0f) + eps) + (n2 - 1.0f) * logf((v2 > 0.0f ? v2 : 0.0f) + eps);
  };
  float best = 0.0f;
  int best_k = -1;
  for (int k = 2; k <= len - 2; ++k) {
    const float aic = aic_at(k);
    if (best_k < 0 || aic < best) {
      best = aic;
      best_k = k;
    }
  }
  if (best_k < 0) return -1.0f;
  // Parabola through the minimum and its neighbours: the sub-sample position of the minimum.
  float offset = 0.0f;
  if (best_k > 2 && best_k < len - 2) {
    const float am = aic_at(best_k - 1);
    const float ap = aic_at(best_k + 1);
    const float curv = am - 2.0f * best + ap;
    if (curv > 0.0f) offset = 0.5f * (am - ap) / curv;
    if (offset > 0.5f) offset = 0.5f;
    if (offset < -0.5f) offset = -0.5f;
  }
  return static_cast<float>(begin + best_k) + offset;
}

int aic_pick(const int16_t* x, int begin, int end) {
  const float k = aic_pick_subsample(x, begin, end);
  return k < 0.0f ? -1 : static_cast<int>(k + 0.5f);
}

}  // namespace impactcore
