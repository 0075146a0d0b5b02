/* Host driver for the exported C models: reads float32 feature rows from stdin (n_features each) and
   prints, per row, the table and m2cgen predictions (x, y, P(high)) with %.9g. Used by
   tests/test_firmware_export.py to check the generated C against scikit-learn. */
#include <stdio.h>

#include "impactsense_models.h"

static float forest_mean(const impactsense_forest* f, const float* x) {
  /* Same walk as impactapp::forest_mean (C here so the generated C is checked without C++). */
  float sum = 0.0f;
  for (int t = 0; t < f->n_trees; ++t) {
    const uint8_t* feat = f->feature + f->roots[t];
    const float* val = f->value + f->roots[t];
    const uint16_t* right = f->right + f->roots[t];
    unsigned i = 0;
    while (feat[i] != 0xFF) i = (x[feat[i]] <= val[i]) ? i + 1 : right[i];
    sum += val[i];
  }
  return sum / (float)f->n_trees;
}

int main(void) {
  float x[IMPACTSENSE_N_FEATURES];
  while (fread(x, sizeof(float), IMPACTSENSE_N_FEATURES, stdin) == IMPACTSENSE_N_FEATURES) {
    printf("%.9g %.9g %.9g %.9g %.9g %.9g\n", forest_mean(&impactsense_forest_x, x),
           forest_mean(&impactsense_forest_y, x), forest_mean(&impactsense_forest_energy, x),
           impactsense_m2c_x(x), impactsense_m2c_y(x), impactsense_m2c_energy(x));
  }
  return 0;
}
