// Glue between the generated models (models/impactsense_models.h, written by `impactsense export`) and
// impactapp: the TableModels over the exported tables and the signal configuration the models were trained
// with. Header-only; include it only where the generated models are compiled in (board, qemu image).
#pragma once

#include "impactapp.h"
#include "impactsense_models.h"

namespace impactapp {

static_assert(IMPACTSENSE_N_FEATURES == impactcore::kNumFeatures,
              "models exported for another feature vector: re-export them with this core");

inline ModelSpec exported_spec(const impactsense_model& m) {
  return ModelSpec{ForestTables{m.forest.n_trees, m.forest.roots, m.forest.feature, m.forest.value, m.forest.right},
                   m.inputs, m.n_inputs};
}

inline TableModels exported_models() {
  return TableModels(exported_spec(impactsense_model_x), exported_spec(impactsense_model_y),
                     exported_spec(impactsense_model_energy), IMPACTSENSE_RESIDUAL_XY != 0);
}

// The signal and localiser settings of the model card, with sample counts scaled to the board rate.
inline AppConfig exported_config(AppConfig cfg) {
  const impactsense_signal_config& s = impactsense_signal;
  const float scale = static_cast<float>(cfg.fs_hz) / s.fs_hz;
  cfg.core.baseline_samples = s.baseline_samples;
  cfg.core.onset_threshold_counts = s.onset_threshold_counts;
  cfg.core.onset_noise_factor = s.onset_noise_factor;
  cfg.core.aic_before = static_cast<int>(s.aic_before * scale + 0.5f);
  cfg.core.aic_after = static_cast<int>(s.aic_after * scale + 0.5f);
  cfg.core.aic_blend = s.aic_blend;
  cfg.core.dead_rms_counts = s.dead_rms_counts;
  cfg.core.n2_fraction = s.n2_fraction;
  cfg.core.diff_window_us = s.diff_window_us;
  cfg.loc.velocity_mm_per_us = s.velocity_mm_per_us;
  cfg.loc.sigma_us = s.sigma_us;
  cfg.loc.huber_us = s.huber_us;
  cfg.loc.accept_tol_us = s.accept_tol_us;
  cfg.loc.accept_margin_mm = s.accept_margin_mm;
  for (int c = 0; c < 4; ++c) {
    cfg.rig_delay_us[c] = s.channel_delay_us[c];
    cfg.core.channel_gain[c] = s.channel_gain[c];
    cfg.loc.sensor_x_mm[c] = s.sensor_x_mm[c];
    cfg.loc.sensor_y_mm[c] = s.sensor_y_mm[c];
  }
  cfg.loc.plate_x_mm = s.plate_x_mm;
  cfg.loc.plate_y_mm = s.plate_y_mm;
  return cfg;
}

}  // namespace impactapp
