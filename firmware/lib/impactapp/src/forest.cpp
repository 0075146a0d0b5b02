#include "forest.h"

namespace impactapp {

float forest_mean(const ForestTables& f, const float* x) {
  float sum = 0.0f;
  for (int32_t t = 0; t < f.n_trees; ++t) {
    const uint8_t* feat = f.feature + f.roots[t];
    const float* val = f.value + f.roots[t];
    const uint16_t* right = f.right + f.roots[t];
    uint32_t i = 0;
    while (feat[i] != kLeaf) i = (x[feat[i]] <= val[i]) ? i + 1 : right[i];
    sum += val[i];
  }
  return f.n_trees > 0 ? sum / static_cast<float>(f.n_trees) : 0.0f;
}

}  // namespace impactapp
