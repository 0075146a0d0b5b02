// Glue between the generated models (models/impactsense_models.h, written by `impactsense export`) and
// impactapp: the TableModels over the exported forests (node tables, or the m2cgen code) and the signal
// configuration the models were trained with. Header-only; include it only where the generated models are compiled in (board, qemu image).
#pragma once

#include <math.h>

#include "impactapp.h"
#include "impactsense_models.h"

namespace impactapp {

static_assert(IMPACTSENSE_N_FEATURES == impactcore::kNumFeatures,
              "models exported for another feature vector: re-export them with this core");

// One exported forest, evaluated by `evaluate` (forest_mean: its node tables).
inline ModelSpec exported_spec(const impactsense_model& m, ForestEvaluator evaluate) {
  return ModelSpec{ForestTables{m.forest.n_trees, m.forest.roots, m.forest.feature, m.forest.threshold, m.forest.skip,
                                m.forest.leaf, m.forest.leaf_value, m.forest.value, m.n_inputs},
                   m.inputs, m.n_inputs, evaluate};
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
  t.cfg.coarse_cutoff_mm = c.coarse_cutoff_mm;
  t.cfg.weak_channel = static_cast<int32_t>(c.weak_channel);
  t.uncertainty_offset_mm = c.uncertainty_offset_mm;
  t.uncertainty_scale = c.uncertainty_scale;
  t.uncertainty_misfit_ref = c.uncertainty_misfit_ref;
#if defined(IMPACTSENSE_TWIN_EDGE) && IMPACTSENSE_TWIN_EDGE   // an export from before the edge term: none
  t.edge_log10_bias = c.edge_log10_bias;
  t.edge_ramp_mm = c.edge_ramp_mm;
  t.plate_x_mm = c.plate_x_mm;
  t.plate_y_mm = c.plate_y_mm;
#endif
  return t;
}
#endif

#if defined(IMPACTSENSE_THREE_CHANNEL_CLASS) && IMPACTSENSE_THREE_CHANNEL_CLASS
// A model without a twin: per channel the energy class of a drop without that channel (linear_terms over
// impactcore::three_channel_inputs; TableModels' three_channel).
inline const ModelSpec* exported_three_channel() {
  static const ModelSpec three[impactcore::kChannels] = {
      exported_spec(impactsense_model_energy_without[0], linear_terms),
      exported_spec(impactsense_model_energy_without[1], linear_terms),
      exported_spec(impactsense_model_energy_without[2], linear_terms),
      exported_spec(impactsense_model_energy_without[3], linear_terms)};
  return three;
}
#else
inline const ModelSpec* exported_three_channel() { return nullptr; }
#endif

#if defined(IMPACTSENSE_THREE_POSITION) && IMPACTSENSE_THREE_POSITION
// A model without a twin: per channel c the pair (x, y) correcting the three-sensor position of a drop without c
// (node tables over impactcore::three_position_inputs; a pair of 0 trees: none; TableModels' three_position).
inline const ModelSpec* exported_three_position() {
  static const ModelSpec pairs[2 * impactcore::kChannels] = {
      exported_spec(impactsense_model_position_without[0], forest_mean),
      exported_spec(impactsense_model_position_without[1], forest_mean),
      exported_spec(impactsense_model_position_without[2], forest_mean),
      exported_spec(impactsense_model_position_without[3], forest_mean),
      exported_spec(impactsense_model_position_without[4], forest_mean),
      exported_spec(impactsense_model_position_without[5], forest_mean),
      exported_spec(impactsense_model_position_without[6], forest_mean),
      exported_spec(impactsense_model_position_without[7], forest_mean)};
  return pairs;
}
#else
inline const ModelSpec* exported_three_position() { return nullptr; }
#endif

#if defined(IMPACTSENSE_CHANNEL_CHECK) && IMPACTSENSE_CHANNEL_CHECK
// A model without a twin: the channel check (impactcore::ChannelCheck) from the card's fits.
inline impactcore::ChannelCheck exported_channel_check_value() {
  const impactsense_channel_check& s = impactsense_check;
  impactcore::ChannelCheck check;
  for (int c = 0; c < impactcore::kChannels; ++c) {
    for (int k = 0; k < impactcore::kCheckTerms; ++k) {
      check.level[c].coef[k] = s.level[c][k];
      check.tilt[c].coef[k] = s.tilt[c][k];
    }
    check.level[c].median = s.level[c][impactcore::kCheckTerms];
    check.level[c].scale = s.level[c][impactcore::kCheckTerms + 1];
    check.tilt[c].median = s.tilt[c][impactcore::kCheckTerms];
    check.tilt[c].scale = s.tilt[c][impactcore::kCheckTerms + 1];
  }
  check.plate_x_mm = s.plate_x_mm;
  check.plate_y_mm = s.plate_y_mm;
  check.event_score = s.event_score;
  check.run_score = s.run_score;
  check.run_events = s.run_events;
  check.four_channel_mask = s.four_channel_mask;
  return check;
}
inline const impactcore::ChannelCheck* exported_channel_check() {
  static const impactcore::ChannelCheck check = exported_channel_check_value();
  return &check;
}
#else
inline const impactcore::ChannelCheck* exported_channel_check() { return nullptr; }
#endif

// The exported models, their forests (x, y, energy) evaluated by the given functions.
inline TableModels exported_models_with(ForestEvaluator x, ForestEvaluator y, ForestEvaluator energy) {
#if IMPACTSENSE_TWIN
  const TwinSpec twin = exported_twin();
  return TableModels(exported_spec(impactsense_model_x, x), exported_spec(impactsense_model_y, y),
                     exported_spec(impactsense_model_energy, energy), IMPACTSENSE_RESIDUAL_XY != 0, &twin);
#else
  return TableModels(exported_spec(impactsense_model_x, x), exported_spec(impactsense_model_y, y),
                     exported_spec(impactsense_model_energy, energy), IMPACTSENSE_RESIDUAL_XY != 0, nullptr,
                     exported_three_channel(), exported_channel_check(), exported_three_position());
#endif
}

// The node-table form (forest.h).
// The energy class of a model that chose the linear estimate (IMPACTSENSE_ENERGY_LINEAR) is linear_terms over
// the same arrays.
#if defined(IMPACTSENSE_ENERGY_LINEAR) && IMPACTSENSE_ENERGY_LINEAR
inline TableModels exported_models() { return exported_models_with(forest_mean, forest_mean, linear_terms); }
#else
inline TableModels exported_models() { return exported_models_with(forest_mean, forest_mean, forest_mean); }
#endif

// The m2cgen form (impactsense_models_m2c.c, one function per tree): the same TableModels logic (the inputs
// gathered, impactcore::twin_match, the energy class) with the forests run as that code. The firmware's env
// nano33ble_m2cgen builds it (IMPACTSENSE_MODELS_M2CGEN: the node tables are left out, their inputs kept).
inline float m2cgen_x(const ForestTables&, const float* in) { return impactsense_m2c_x(in); }
inline float m2cgen_y(const ForestTables&, const float* in) { return impactsense_m2c_y(in); }
inline float m2cgen_energy(const ForestTables&, const float* in) { return impactsense_m2c_energy(in); }
inline TableModels exported_m2cgen_models() { return exported_models_with(m2cgen_x, m2cgen_y, m2cgen_energy); }

#define IMPACTAPP_CARD_FIELD(kind, type, name, def, role) IMPACTAPP_CARD_##role(name)
#define IMPACTAPP_CARD_COPY(name) memcpy(&card.name, &s.name, sizeof(card.name));
#define IMPACTAPP_CARD_SAMPLES(name) IMPACTAPP_CARD_COPY(name)
#define IMPACTAPP_CARD_RATE(name) IMPACTAPP_CARD_COPY(name)
#define IMPACTAPP_CARD_ACQUISITION(name)  // the board's own acquisition; not in the card
#define IMPACTAPP_LOC_FIELD(kind, type, name, def, role) memcpy(&cfg.loc.name, &s.name, sizeof(cfg.loc.name));

// The signal and localiser settings of the model card (every field of impactcore.h's lists the exporter
// writes), taken to the board's rate and acquisition by board_core_config; and the trigger threshold the export
// chose from the model's drops (IMPACTSENSE_TRIGGER_COUNTS, board counts; absent: cfg's, the firmware's default),
// the re-arm level lowered as set_threshold lowers it. The link's set_threshold still overrides it at run time.
inline AppConfig exported_config(AppConfig cfg) {
  const impactsense_signal_config& s = impactsense_signal;
  impactcore::CoreConfig card;
  IMPACTCORE_CONFIG_FIELDS(IMPACTAPP_CARD_FIELD)
  cfg.core = board_core_config(card, cfg.fs_hz, cfg.core.adc_min, cfg.core.adc_max);
  IMPACTCORE_LOCALISER_FIELDS(IMPACTAPP_LOC_FIELD)
#ifdef IMPACTSENSE_TRIGGER_COUNTS
  cfg.threshold_counts = IMPACTSENSE_TRIGGER_COUNTS;
  if (cfg.rearm_counts >= cfg.threshold_counts) cfg.rearm_counts = cfg.threshold_counts / 3.0f;
#endif
  return cfg;
}

}  // namespace impactapp
