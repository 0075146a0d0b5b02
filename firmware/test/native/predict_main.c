/* Host driver for the exported C models: reads float32 rows from stdin (the core's feature vector,
   IMPACTSENSE_N_FEATURES values, then the twin's log10 height estimate: the input IMPACTSENSE_TWIN_INPUT a
   twin model's energy classifier reads, NaN otherwise) and prints, per row, the forests' outputs from the node tables and from
   m2cgen (x, y, P(high); x and y before adding the physics position; for a linear energy estimate 0.5 + its
   score) with %.9g. Used by
   tests/test_firmware_export.py to check the generated C against scikit-learn. */
#include <stdio.h>
#include <string.h>

#include "impactsense_models.h"

static int32_t order_key(float v) {
  uint32_t b;
  memcpy(&b, &v, sizeof b);
  return (int32_t)(b ^ ((0u - (b >> 31)) >> 1));
}

static float forest_mean(const impactsense_forest* f, const float* x, int n_inputs) {
  /* Same walk as impactapp::forest_mean (C here so the generated C is checked without C++). */
  int32_t key[32];
  for (int k = 0; k < n_inputs; ++k) key[k] = order_key(x[k]);
  float sum = 0.0f;
  for (int t = 0; t < f->n_trees; ++t) {
    const int32_t root = f->roots[t];
    unsigned i = (unsigned)root, l = (unsigned)(root + t), c = (unsigned)(f->roots[t + 1] - root);
    do {
      const unsigned s = f->skip[i];
      if (key[f->feature[i]] <= f->threshold[i]) {
        ++i;
        c = s - 1;
      } else {
        i += s;
        l += s;
        c -= s;
      }
    } while (c != 0);
    sum += f->leaf_value[f->leaf[l]];
  }
  return sum / (float)f->n_trees;
}

#if defined(IMPACTSENSE_ENERGY_LINEAR) && IMPACTSENSE_ENERGY_LINEAR
static float linear_terms(const impactsense_forest* f, const float* x, int n_inputs) {
  (void)n_inputs;
  /* Same arithmetic as impactapp::linear_terms: the energy arrays of a linear estimate of log m g h. */
  const float* standard = f->value + f->n_trees + 1;
  float sum = f->value[f->n_trees];
  for (int t = 0; t < f->n_trees; ++t) {
    float p = f->value[t];
    for (int m = 0; m < 3; ++m) {
      const unsigned k = f->feature[f->roots[t] + m];
      if (k != 0xFF) p *= (x[k] - standard[2 * k]) * standard[2 * k + 1];
    }
    sum += p;
  }
  return 0.5f + sum;
}
#define ENERGY_MODEL linear_terms
#else
#define ENERGY_MODEL forest_mean
#endif

static const float* gather(const impactsense_model* m, const float* v, float* out) {
  for (int k = 0; k < m->n_inputs; ++k) out[k] = v[m->inputs[k]];
  return out;
}

int main(void) {
  float v[IMPACTSENSE_N_FEATURES + 1], a[32], b[32], c[32];
  while (fread(v, sizeof(float), IMPACTSENSE_N_FEATURES + 1, stdin) == IMPACTSENSE_N_FEATURES + 1) {
    gather(&impactsense_model_x, v, a);
    gather(&impactsense_model_y, v, b);
    gather(&impactsense_model_energy, v, c);
    printf("%.9g %.9g %.9g %.9g %.9g %.9g\n", forest_mean(&impactsense_model_x.forest, a, impactsense_model_x.n_inputs),
           forest_mean(&impactsense_model_y.forest, b, impactsense_model_y.n_inputs),
           ENERGY_MODEL(&impactsense_model_energy.forest, c, impactsense_model_energy.n_inputs),
           impactsense_m2c_x(a), impactsense_m2c_y(b), impactsense_m2c_energy(c));
  }
  return 0;
}
