// Glue between the generated models (models/impactsense_models.h, written by `impactsense export`) and
// impactapp: the TableModels over the exported tables and the signal configuration the models were trained
// with. Header-only; include it only where the generated models are compiled in (board, qemu image).
#pragma once

#include <math.h>

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
  t.cfg.coarse_cutoff_mm = c.coarse_cutoff_mm;
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

// The m2cgen export (impactsense_models_m2c.c, one function per tree) behind the same interface and with the
// same logic as TableModels: gathers its inputs like TableModels, then impactcore::twin_match at the forests'
// x, y (the reported position, its calibrated uncertainty, the twin's estimate for IMPACTSENSE_TWIN_INPUT;
// a dead channel: the physics localiser's three-sensor position on the other three channels; an inconsistent
// one left out, with the localiser's geometry, predict_event). The firmware's env nano33ble_m2cgen builds
// with it (IMPACTSENSE_MODELS_M2CGEN: the node tables are left out, their inputs kept).
class M2cModels : public Models {
 public:
  bool predict(const impactcore::EventResult& ev, float* x, float* y, uint8_t* c) const override {
    float uncertainty = 0.0f;
    int8_t left_out = -1;
    return predict_impl(ev, nullptr, x, y, c, &uncertainty, &left_out);
  }
  bool predict_with_uncertainty(const impactcore::EventResult& ev, float* x, float* y, uint8_t* c,
                                float* uncertainty_mm) const override {
    int8_t left_out = -1;
    return predict_impl(ev, nullptr, x, y, c, uncertainty_mm, &left_out);
  }
  bool predict_event(const impactcore::EventResult& ev, const impactcore::LocaliserConfig& loc, float* x,
                     float* y, uint8_t* c, float* uncertainty_mm, int8_t* left_out) const override {
    return predict_impl(ev, &loc, x, y, c, uncertainty_mm, left_out);
  }

 private:
  bool predict_impl(const impactcore::EventResult& ev, const impactcore::LocaliserConfig* loc, float* x_mm,
                    float* y_mm, uint8_t* c, float* uncertainty_mm, int8_t* left_out) const {
    float in[kMaxModelInputs];
    *left_out = -1;
    if (ev.status != impactcore::kOk) return false;
    // The forests' position; NaN when they cannot run (a channel without an onset leaves the vector NaN).
    float x = NAN, y = NAN;
    if (!(IMPACTSENSE_RESIDUAL_XY && ev.phys.status != impactcore::kOk) && gather(impactsense_model_x, ev.vector, NAN, in)) {
      const float dx = impactsense_m2c_x(in);
      if (gather(impactsense_model_y, ev.vector, NAN, in)) {
        x = (IMPACTSENSE_RESIDUAL_XY ? ev.phys.x_mm : 0.0f) + dx;
        y = (IMPACTSENSE_RESIDUAL_XY ? ev.phys.y_mm : 0.0f) + impactsense_m2c_y(in);
      }
    }
    float twin = NAN;
#if IMPACTSENSE_TWIN
    const impactcore::TwinMatch m = impactcore::twin_match(ev, x, y, loc, twin_.map, twin_.cfg,
                                                           twin_.uncertainty_misfit_ref);
    if (m.est.status != impactcore::kOk) return false;
    twin = m.est.log10_height_mm;
    x = m.est.x_mm;
    y = m.est.y_mm;
    *uncertainty_mm = twin_uncertainty_mm(m.est, twin_);
    *left_out = static_cast<int8_t>(m.left_out);
#else
    (void)loc;
    (void)uncertainty_mm;
    if (!(x == x) || !(y == y)) return false;
#endif
    if (!gather(impactsense_model_energy, ev.vector, twin, in)) return false;
    *c = impactsense_m2c_energy(in) > 0.5f ? 1 : 0;
    *x_mm = x;
    *y_mm = y;
    return true;
  }

#if IMPACTSENSE_TWIN
  TwinSpec twin_ = exported_twin();
#endif
  static bool gather(const impactsense_model& m, const float* v, float twin, float* out) {
    if (m.n_inputs > kMaxModelInputs) return false;
    for (int32_t k = 0; k < m.n_inputs; ++k) {
      const float a = m.inputs[k] == IMPACTSENSE_TWIN_INPUT ? twin : v[m.inputs[k]];
      if (!(a == a) || a - a != 0.0f) return false;  // NaN or inf: the event is not usable
      out[k] = a;
    }
    return true;
  }
};

#define IMPACTAPP_CARD_FIELD(kind, type, name, def, role) IMPACTAPP_CARD_##role(name)
#define IMPACTAPP_CARD_COPY(name) memcpy(&card.name, &s.name, sizeof(card.name));
#define IMPACTAPP_CARD_SAMPLES(name) IMPACTAPP_CARD_COPY(name)
#define IMPACTAPP_CARD_RATE(name) IMPACTAPP_CARD_COPY(name)
#define IMPACTAPP_CARD_ACQUISITION(name)  // the board's own acquisition; not in the card
#define IMPACTAPP_LOC_FIELD(kind, type, name, def, role) memcpy(&cfg.loc.name, &s.name, sizeof(cfg.loc.name));

// The signal and localiser settings of the model card (every field of impactcore.h's lists the exporter
// writes), taken to the board's rate and acquisition by board_core_config.
inline AppConfig exported_config(AppConfig cfg) {
  const impactsense_signal_config& s = impactsense_signal;
  impactcore::CoreConfig card;
  IMPACTCORE_CONFIG_FIELDS(IMPACTAPP_CARD_FIELD)
  cfg.core = board_core_config(card, cfg.fs_hz, cfg.core.adc_min, cfg.core.adc_max);
  IMPACTCORE_LOCALISER_FIELDS(IMPACTAPP_LOC_FIELD)
  return cfg;
}

}  // namespace impactapp
