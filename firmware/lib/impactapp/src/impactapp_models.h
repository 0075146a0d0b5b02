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

#if IMPACTSENSE_TWIN
static_assert(IMPACTSENSE_TWIN_FEATURES == impactcore::kTwinFeatures,
              "site map exported for another twin feature set: re-export it with this core");

// The twin's site map (flash) and its configuration from the model card (the energy forest reads the twin's
// height estimate: input index kTwinInput).
inline TwinSpec exported_twin() {
  const impactsense_site_map& m = impactsense_twin_map;
  const impactsense_twin_config& c = impactsense_twin;
  TwinSpec t{};
  t.map.nx = m.nx;
  t.map.ny = m.ny;
  t.map.x0_mm = m.x0_mm;
  t.map.y0_mm = m.y0_mm;
  t.map.step_mm = m.step_mm;
  t.map.q = m.q;
  for (int k = 0; k < impactcore::kTwinFeatures; ++k) {
    t.map.base[k] = m.base[k];
    t.map.scale[k] = m.scale[k];
    t.cfg.offset[k] = c.offset[k];
    t.cfg.slope[k] = c.slope[k];
    t.cfg.weight[k] = c.weight[k];
  }
  t.cfg.ref_log10_height_mm = c.ref_log10_height_mm;
  t.cfg.prior_mm = c.prior_mm;
  t.cfg.cutoff_mm = c.cutoff_mm;
  t.cfg.temperature = c.temperature;
  t.uncertainty_offset_mm = c.uncertainty_offset_mm;
  t.uncertainty_scale = c.uncertainty_scale;
  t.uncertainty_misfit_ref = c.uncertainty_misfit_ref;
  return t;
}
#endif

inline TableModels exported_models() {
#if IMPACTSENSE_TWIN
  const TwinSpec twin = exported_twin();
  return TableModels(exported_spec(impactsense_model_x), exported_spec(impactsense_model_y),
                     exported_spec(impactsense_model_energy), IMPACTSENSE_RESIDUAL_XY != 0, &twin);
#else
  return TableModels(exported_spec(impactsense_model_x), exported_spec(impactsense_model_y),
                     exported_spec(impactsense_model_energy), IMPACTSENSE_RESIDUAL_XY != 0);
#endif
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
