#include "forest.h"

namespace impactapp {

// The walk is the per-event cost of every model (~12 instructions a split node under qemu): each tree's
// split-node arrays are offset once (the empty asm keeps the compiler from folding the tree's root back into
// every node's index); a step left moves to the next split node, a step right moves both cursors by skip.
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("O2")))
#endif
float forest_mean(const ForestTables& f, const float* x) {
  float sum = 0.0f;
  for (int32_t t = 0; t < f.n_trees; ++t) {
    const int32_t root = f.roots[t];
    const uint8_t* feat = f.feature + root;
    const float* val = f.value + root;
    const uint16_t* skip = f.skip + root;
#if defined(__GNUC__)
    __asm__("" : "+r"(feat), "+r"(val), "+r"(skip));
#endif
    uint32_t i = 0;
    uint32_t l = static_cast<uint32_t>(root + t);
    for (;;) {
      const uint32_t k = feat[i];
      if (x[k & kInputMask] <= val[i]) {
        if (k & kLeftLeaf) break;
        ++i;
      } else {
        const uint32_t s = skip[i];
        l += s;
        if (k & kRightLeaf) break;
        i += s;
      }
    }
    sum += f.leaf_value[f.leaf[l]];
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
