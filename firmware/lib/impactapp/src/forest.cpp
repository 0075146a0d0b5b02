#include "forest.h"

namespace impactapp {

// The walk is the per-event cost of every model (~12 instructions a node under qemu, 14 before): each
// tree's three arrays are offset once (the empty asm keeps the compiler from folding the tree's root back
// into every node's index) and the loop tests for a leaf at its bottom (-O2 rotates it; the image is -Os).
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("O2")))
#endif
float forest_mean(const ForestTables& f, const float* x) {
  float sum = 0.0f;
  for (int32_t t = 0; t < f.n_trees; ++t) {
    const uint8_t* feat = f.feature + f.roots[t];
    const float* val = f.value + f.roots[t];
    const uint16_t* right = f.right + f.roots[t];
#if defined(__GNUC__)
    __asm__("" : "+r"(feat), "+r"(val), "+r"(right));
#endif
    uint32_t i = 0;
    uint32_t k = feat[0];
    if (k != kLeaf) {
      do {
        i = (x[k] <= val[i]) ? i + 1 : right[i];
        k = feat[i];
      } while (k != kLeaf);
    }
    sum += val[i];
  }
  return f.n_trees > 0 ? sum / static_cast<float>(f.n_trees) : 0.0f;
}

float linear_terms(const ForestTables& f, const float* x) {
  const float* coef = f.value;
  const float* standard = f.value + f.n_trees + 1;   // offset, scale per input
  float sum = f.value[f.n_trees];
  for (int32_t t = 0; t < f.n_trees; ++t) {
    float p = coef[t];
    for (int32_t m = 0; m < 3; ++m) {
      const uint32_t k = f.feature[f.roots[t] + m];
      if (k != kLeaf) p *= (x[k] - standard[2 * k]) * standard[2 * k + 1];
    }
    sum += p;
  }
  return 0.5f + sum;
}

}  // namespace impactapp
