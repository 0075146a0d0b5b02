// Eq. 35: a drop is kept only if the sensor nearer the impact is never reached later.
#include <math.h>

#include "impactcore.h"

namespace impactcore {

bool accept_eq35(const float toa_us[kChannels], const float sensor_x_mm[kChannels],
                 const float sensor_y_mm[kChannels], float x_mm, float y_mm, float tol_us,
                 float margin_mm) {
  float dist[kChannels];
  for (int c = 0; c < kChannels; ++c) {
    if (!(toa_us[c] == toa_us[c])) return false;  // NaN: a channel without an onset
    dist[c] = hypotf(x_mm - sensor_x_mm[c], y_mm - sensor_y_mm[c]);
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
