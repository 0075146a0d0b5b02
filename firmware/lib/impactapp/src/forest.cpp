#include "forest.h"

namespace impactapp {

// The walk is the per-event cost of every model (~10 instructions a split node under qemu): the inputs' order
// keys once a call, then per tree a walk from its root with c, the split nodes under the current node: a step
// that leaves none under it has reached a leaf.
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("O2", "no-if-conversion", "no-if-conversion2")))
#endif
float forest_mean(const ForestTables& f, const float* x) {
  int32_t keys[kMaxModelInputs];
  const int32_t n_inputs = f.n_inputs < kMaxModelInputs ? f.n_inputs : kMaxModelInputs;
  for (int32_t k = 0; k < n_inputs; ++k) keys[k] = order_key(x[k]);
  const int32_t* key = keys;
  const uint8_t* feat = f.feature;
  const int32_t* thr = f.threshold;
  const uint16_t* skip = f.skip;
#if defined(__GNUC__)
  __asm__("" : "+r"(key));   // the keys' address in a register, not recomputed from sp at every node
#endif
  float sum = 0.0f;
  for (int32_t t = 0; t < f.n_trees; ++t) {
    uint32_t i = static_cast<uint32_t>(f.roots[t]);
    uint32_t c = static_cast<uint32_t>(f.roots[t + 1]) - i;
    uint32_t l = i + static_cast<uint32_t>(t);
    for (;;) {
      const uint32_t s = skip[i];
      if (key[feat[i]] <= thr[i]) {
        ++i;
        if ((c = s - 1) == 0) break;
      } else {
        i += s;
        l += s;
        if ((c -= s) == 0) break;
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
