/* Host driver for the exported C models: reads float32 rows from stdin (the core's feature vector,
   IMPACTSENSE_N_FEATURES values, then the twin's log10 height estimate: the input IMPACTSENSE_TWIN_INPUT a
   twin model's energy classifier reads, NaN otherwise) and prints, per row, the forests' outputs from the node tables and from
   m2cgen (x, y, P(high); x and y before adding the physics position; for a linear energy estimate 0.5 + its
   score) with %.9g. Used by
   tests/test_firmware_export.py to check the generated C against scikit-learn. */
#include <stdio.h>

#include "impactsense_models.h"

static float forest_mean(const impactsense_forest* f, const float* x) {
  /* Same walk as impactapp::forest_mean (C here so the generated C is checked without C++). */
  float sum = 0.0f;
  for (int t = 0; t < f->n_trees; ++t) {
    const uint8_t* feat = f->feature + f->roots[t];
    const float* val = f->value + f->roots[t];
    const uint16_t* skip = f->skip + f->roots[t];
    unsigned i = 0, l = (unsigned)(f->roots[t] + t);
    for (;;) {
      const unsigned k = feat[i];
      if (x[k & 0x3F] <= val[i]) {
        if (k & 0x40) break;
        ++i;
      } else {
        l += skip[i];
        if (k & 0x80) break;
        i += skip[i];
      }
    }
    sum += f->leaf_value[f->leaf[l]];
  }
  return sum / (float)f->n_trees;
}

#if defined(IMPACTSENSE_ENERGY_LINEAR) && IMPACTSENSE_ENERGY_LINEAR
static float linear_terms(const impactsense_forest* f, const float* x) {
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
    printf("%.9g %.9g %.9g %.9g %.9g %.9g\n", forest_mean(&impactsense_model_x.forest, a),
           forest_mean(&impactsense_model_y.forest, b), ENERGY_MODEL(&impactsense_model_energy.forest, c),
           impactsense_m2c_x(a), impactsense_m2c_y(b), impactsense_m2c_energy(c));
  }
  return 0;
}
