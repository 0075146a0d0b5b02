// Eq. 35: a drop is kept only if the sensor nearer the impact is never reached later.
#include <math.h>

#include "impactcore.h"

namespace impactcore {

bool accept_eq35(const float toa_us[kChannels], const float sensor_x_mm[kChannels],
                 const float sensor_y_mm[kChannels], float x_mm, float y_mm, float tol_us,
                 float margin_mm, const float* travel_metric) {
  float dist[kChannels];
  for (int c = 0; c < kChannels; ++c) {
    if (!(toa_us[c] == toa_us[c])) return false;  // NaN: a channel without an onset
    const float dx = x_mm - sensor_x_mm[c], dy = y_mm - sensor_y_mm[c];
    if (travel_metric == nullptr) {
      dist[c] = hypotf(dx, dy);
    } else {  // the travel distance sqrt(d^T Q d): "nearer" in time on an anisotropic plate
      const float q = travel_metric[0] * dx * dx + 2.0f * travel_metric[1] * dx * dy + travel_metric[2] * dy * dy;
      dist[c] = vsqrt_f32(q > 0.0f ? q : 0.0f);  // the FPU instruction: sqrtf's result, no libm call
    }
  }
  for (int i = 0; i < kChannels; ++i) {
    for (int j = 0; j < kChannels; ++j) {
      if (i == j) continue;
      if (dist[i] + margin_mm <= dist[j] && toa_us[i] > toa_us[j] + tol_us) return false;
    }
  }
  return true;
}

}  // namespace impactcore
