// The per-event path shared by the board and the host.
#include <math.h>

#include "impactcore.h"

namespace impactcore {

const char* const kFeatureNames[kNumFeatures] = {
    "dtoa_01_us", "dtoa_02_us", "dtoa_03_us", "dtoa_12_us", "dtoa_13_us", "dtoa_23_us",
    "rel_toa_0_us", "rel_toa_1_us", "rel_toa_2_us", "rel_toa_3_us",
    "phys_x_mm", "phys_y_mm",
    "log_energy_rel_0", "log_energy_rel_1", "log_energy_rel_2", "log_energy_rel_3",
    "log_energy_mean",
    "log_first_peak_0", "log_first_peak_1", "log_first_peak_2", "log_first_peak_3",
    "residual_ratio_0", "residual_ratio_1", "residual_ratio_2", "residual_ratio_3",
    "phys_rms_us",
    "log_arrival_energy_sum", "log_diff1_energy_sum", "log_diff2_energy_sum", "log_diff3_energy_sum",
};

// log10 x = log10(2) log2 x (fast_log2: no libm log10f, ~100 instructions a call on the M4F).
constexpr float kLog10Of2 = 0.301029996f;

// log10(1 + the arrival energy summed over the channels but `skip`) and the same of each difference order's
// (skip -1: all four; the feature vector's log_arrival_energy_sum, log_diff{1,2,3}_energy_sum).
static inline void summed_energies(const EventFeatures& f, int skip, float out[1 + kDiffOrders]) {
  float arrival = 0.0f;
  float diff[kDiffOrders] = {0.0f, 0.0f, 0.0f};
  for (int c = 0; c < kChannels; ++c) {
    if (c == skip) continue;
    for (int w = 0; w < kEnergyWindows; ++w) arrival += f.ch[c].window_energy[w];
    for (int k = 0; k < kDiffOrders; ++k) diff[k] += f.ch[c].diff_energy[k];
  }
  out[0] = kLog10Of2 * fast_log2(arrival + 1.0f);
  for (int k = 0; k < kDiffOrders; ++k) out[1 + k] = kLog10Of2 * fast_log2(diff[k] + 1.0f);
}

// The band localiser's velocity for this event: 1 / (1 / v_band + slope (log10(sum_c E_c / fs) - ref)); the
// higher the drop, the shorter the contact and the more of the faster high frequencies in the band's rise
// (docs/findings.md "Band picks: the speed follows the drop"). v_band itself when the slope is 0, the
// energy is not positive or the slowness would not be. A dead or left-out channel's energy is taken as the
// mean of the others' (its silence is not a softer drop); with every channel read, the sum is the four's.
bool summed_log_energy(const float energy[kChannels], float fs_hz, float* log_e) {
  float sum = 0.0f;
  for (int c = 0; c < kChannels; ++c) sum += energy[c];
  if (!(sum > 0.0f) || !(fs_hz > 0.0f)) return false;
  *log_e = kLog10Of2 * (fast_log2(sum) - fast_log2(fs_hz));
  return true;
}

bool band_log_energy(const float energy[kChannels], const uint8_t flags[kChannels],
                     const int channel_left_out[kChannels], float fs_hz, float* log_e) {
  float read_energy[kChannels];
  bool missing[kChannels];
  float read_sum = 0.0f;
  int read = 0;
  for (int c = 0; c < kChannels; ++c) {
    read_energy[c] = energy[c];
    missing[c] = (flags[c] & kFlagDead) || channel_left_out[c];
    if (!missing[c]) {
      read_sum += energy[c];
      ++read;
    }
  }
  if (read > 0 && read < kChannels) {
    for (int c = 0; c < kChannels; ++c) {
      if (missing[c]) read_energy[c] = read_sum / static_cast<float>(read);
    }
  }
  return summed_log_energy(read_energy, fs_hz, log_e);
}

float band_velocity_for(const EventFeatures& f, const CoreConfig& cfg, const LocaliserConfig& loc) {
  const float v = loc.band_velocity_mm_per_us;
  if (loc.band_slowness_per_decade == 0.0f) return v;
  float energy[kChannels];
  uint8_t flags[kChannels];
  for (int c = 0; c < kChannels; ++c) {
    energy[c] = f.ch[c].energy;
    flags[c] = f.ch[c].flags;
  }
  float log_e;
  if (!band_log_energy(energy, flags, cfg.channel_left_out, cfg.fs_hz, &log_e)) return v;
  const float slowness = 1.0f / v + loc.band_slowness_per_decade * (log_e - loc.band_log_energy_ref);
  return slowness > 0.0f ? 1.0f / slowness : v;
}

void localise_event(const EventFeatures& f, const CoreConfig& cfg, const LocaliserConfig& loc, int without,
                    const float slowness_scale[kChannels], LocaliserResult* phys, LocaliserResult* band,
                    int max_evaluations) {
  float toa[kChannels];
  uint8_t use[kChannels];
  for (int c = 0; c < kChannels; ++c) {
    toa[c] = f.ch[c].toa_us;
    use[c] = (c == without || (f.ch[c].flags & (kFlagNoOnset | kFlagDead))) ? 0 : 1;
  }
  const float metric[3] = {loc.travel_metric_xx, loc.travel_metric_xy, loc.travel_metric_yy};
  *phys = localise_tdoa(toa, use, loc.sensor_x_mm, loc.sensor_y_mm, loc.velocity_mm_per_us, loc.sigma_us,
                        loc.plate_x_mm, loc.plate_y_mm, loc.huber_us, metric,
                        loc.dispersion_exponent != 0.0f ? slowness_scale : nullptr, loc.localiser_starts,
                        loc.posterior_grid, max_evaluations);
  // The band picks' own position (averaged with the threshold picks' by average_band: their errors are partly
  // independent, docs/findings.md "Picks in one band"). Like the threshold localiser it runs on the channels that
  // have a pick, at least three: a far channel's band peak under the noise floor gives no band pick, and the other
  // three still place the drop (docs/findings.md "Band picks on three channels"); fewer: not run.
  clear_result(band);
  band->x_mm = band->y_mm = NAN;
  band->status = kErrBadConfig;
  if (!(cfg.band_pick_hz > 0.0f && loc.band_velocity_mm_per_us > 0.0f && phys->status == kOk)) return;
  float toa_band[kChannels];
  uint8_t band_use[kChannels];
  int picked = 0;
  for (int c = 0; c < kChannels; ++c) {
    toa_band[c] = f.ch[c].toa_band_us - loc.band_delay_us[c];
    band_use[c] = (use[c] && toa_band[c] == toa_band[c]) ? 1 : 0;
    if (!band_use[c]) toa_band[c] = 0.0f;
    picked += band_use[c];
  }
  if (picked < 3) return;
  const float band_metric[3] = {loc.band_metric_xx, loc.band_metric_xy, loc.band_metric_yy};
  *band = localise_tdoa(toa_band, band_use, loc.sensor_x_mm, loc.sensor_y_mm, band_velocity_for(f, cfg, loc),
                        loc.sigma_us, loc.plate_x_mm, loc.plate_y_mm, loc.huber_us, band_metric, nullptr,
                        loc.localiser_starts, loc.posterior_grid, max_evaluations);
}

void average_band(LocaliserResult* phys, const LocaliserResult& band) {
  if (phys->status != kOk || band.status != kOk) return;
  phys->x_mm = 0.5f * (phys->x_mm + band.x_mm);
  phys->y_mm = 0.5f * (phys->y_mm + band.y_mm);
}

LocaliserResult three_sensor_position(const EventResult& ev, const CoreConfig& cfg, const LocaliserConfig& loc,
                                      int without) {
  LocaliserResult phys, band;
  localise_event(ev.features, cfg, loc, without, ev.slowness_scale, &phys, &band, kFlaggedEvaluations);
  average_band(&phys, band);
  return phys;
}

#if defined(IMPACTCORE_WORK_COUNTS)
WorkCounts& work_counts() {
  static thread_local WorkCounts counts;
  return counts;
}
void reset_work_counts() { work_counts() = WorkCounts{}; }
#endif

int32_t process_event(const int16_t* const adc[kChannels], int n, const CoreConfig& cfg,
                      const LocaliserConfig& loc, EventResult* out) {
  if (out == nullptr) return kErrNullInput;
  out->accepted = 0;
  for (int k = 0; k < kNumFeatures; ++k) out->vector[k] = NAN;
  for (int c = 0; c < kChannels; ++c) out->slowness_scale[c] = 1.0f;
  out->status = extract_features(adc, n, cfg, &out->features);
  if (out->status != kOk) return out->status;
  const EventFeatures& f = out->features;
  float toa[kChannels];
  for (int c = 0; c < kChannels; ++c) toa[c] = f.ch[c].toa_us;
  // A dispersive plate: each channel's slowness follows the frequency of the cycle its onset caught.
  float* scale = out->slowness_scale;
  for (int c = 0; c < kChannels; ++c) scale[c] = 1.0f;
  if (loc.dispersion_exponent != 0.0f) {
    dispersion_scales(f, cfg.fs_hz, loc.dispersion_exponent, loc.dispersion_ref_hz, scale);
  }
  localise_event(f, cfg, loc, -1, scale, &out->phys, &out->band, loc.localiser_evaluation_cap);
  if (out->phys.status == kOk) {
    const float metric[3] = {loc.travel_metric_xx, loc.travel_metric_xy, loc.travel_metric_yy};
    out->accepted = accept_eq35(toa, loc.sensor_x_mm, loc.sensor_y_mm, out->phys.x_mm, out->phys.y_mm,
                                loc.accept_tol_us, loc.accept_margin_mm, metric)
                        ? 1
                        : 0;
  }
  average_band(&out->phys, out->band);
  float* v = out->vector;
  float tmin = INFINITY;
  for (int c = 0; c < kChannels; ++c) {
    if (toa[c] < tmin) tmin = toa[c];
  }
  for (int p = 0; p < kPairs; ++p) v[p] = f.dtoa_us[p];
  for (int c = 0; c < kChannels; ++c) v[6 + c] = toa[c] - tmin;
  v[10] = out->phys.x_mm;
  v[11] = out->phys.y_mm;
  float le[kChannels];
  float le_mean = 0.0f;
  for (int c = 0; c < kChannels; ++c) {
    le[c] = kLog10Of2 * fast_log2(f.ch[c].energy + 1.0f);
    le_mean += le[c];
  }
  le_mean *= 0.25f;
  for (int c = 0; c < kChannels; ++c) v[12 + c] = le[c] - le_mean;
  v[16] = le_mean;
  for (int c = 0; c < kChannels; ++c) v[17 + c] = kLog10Of2 * fast_log2(f.ch[c].first_peak + 1.0f);
  for (int c = 0; c < kChannels; ++c) v[21 + c] = f.ch[c].residual_ratio;
  v[25] = out->phys.rms_residual_us;
  // Energies of the arrival summed over the channels (the plate's response at all four sensors).
  summed_energies(f, -1, v + 26);
  return out->status;
}

void three_channel_inputs(const EventFeatures& f, float phys_x_mm, float phys_y_mm, int left_out,
                          float out[kThreeChannelInputs]) {
  summed_energies(f, left_out, out);
  float mean = 0.0f;
  for (int c = 0; c < kChannels; ++c) {
    if (c != left_out) mean += kLog10Of2 * fast_log2(f.ch[c].energy + 1.0f);
  }
  out[1 + kDiffOrders] = mean * (1.0f / 3.0f);
  out[2 + kDiffOrders] = phys_x_mm;
  out[3 + kDiffOrders] = phys_y_mm;
}

void three_position_inputs(const float* v, float x_mm, float y_mm, int left_out, float out[kThreePositionInputs]) {
  out[0] = x_mm;
  out[1] = y_mm;
  int k = 2;
  for (int p = 0; p < kPairs; ++p) {
    if (kPairI[p] != left_out && kPairJ[p] != left_out) out[k++] = v[p];
  }
  float e[3];
  int n = 0;
  for (int c = 0; c < kChannels; ++c) {
    if (c != left_out) e[n++] = v[12 + c];
  }
  const float mean = (e[0] + e[1] + e[2]) / 3.0f;
  for (int j = 0; j < 3; ++j) out[k++] = e[j] - mean;
  for (int c = 0; c < kChannels; ++c) {
    if (c != left_out) out[k++] = v[17 + c];
  }
}

}  // namespace impactcore
