// Python binding of the portable signal core. Only glue: loops over recordings and array plumbing;
// every number is computed by firmware/lib/impactcore.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <vector>

#include "impactcore.h"
#include "twin.h"

namespace nb = nanobind;
using namespace nb::literals;
namespace ic = impactcore;

template <typename T, typename... Shape>
using Array = nb::ndarray<T, nb::numpy, Shape...>;
using In16 = nb::ndarray<const int16_t, nb::c_contig, nb::device::cpu>;
using InF = nb::ndarray<const float, nb::c_contig, nb::device::cpu>;
using InU8 = nb::ndarray<const uint8_t, nb::c_contig, nb::device::cpu>;

namespace {

template <typename T>
nb::ndarray<nb::numpy, T> make_array(std::vector<size_t> shape) {
  size_t count = 1;
  for (size_t s : shape) count *= s;
  T* data = new T[count == 0 ? 1 : count]();
  nb::capsule owner(data, [](void* p) noexcept { delete[] static_cast<T*>(p); });
  return nb::ndarray<nb::numpy, T>(data, shape.size(), shape.data(), owner);
}

// Argument checks: an array's shape, with kAny for a dimension of any size (ndim must match).
constexpr size_t kAny = static_cast<size_t>(-1);

template <typename A>
bool has_shape(const A& a, std::initializer_list<size_t> dims) {
  if (a.ndim() != dims.size()) return false;
  size_t k = 0;
  for (size_t d : dims) {
    if (d != kAny && a.shape(k) != d) return false;
    ++k;
  }
  return true;
}

template <typename A>
size_t rows_of(const A& a) {
  return a.ndim() >= 1 ? a.shape(0) : 0;
}

// (recordings, samples) of a batch of captures, checked: int16 [recording, 4, sample], sample <= kMaxSamples.
std::pair<size_t, int> capture_batch(const In16& adc) {
  if (!has_shape(adc, {kAny, ic::kChannels, kAny})) {
    throw std::invalid_argument("adc must be int16 [recording, 4, sample]");
  }
  if (adc.shape(2) > static_cast<size_t>(ic::kMaxSamples)) {
    throw std::invalid_argument("capture longer than the core's kMaxSamples");
  }
  return {adc.shape(0), static_cast<int>(adc.shape(2))};
}

std::vector<float> four(const std::vector<float>& v, const char* name) {
  if (v.size() != ic::kChannels) throw std::invalid_argument(std::string(name) + " needs 4 values");
  return v;
}

nb::dict extract_batch(In16 adc, const ic::CoreConfig& cfg) {
  const auto [r, n] = capture_batch(adc);
  auto toa = make_array<float>({r, 4});
  auto toa_thr = make_array<float>({r, 4});
  auto toa_aic = make_array<float>({r, 4});
  auto dtoa = make_array<float>({r, 6});
  auto order = make_array<uint8_t>({r, 4});
  auto flags = make_array<uint8_t>({r, 4});
  auto energy = make_array<float>({r, 4});
  auto wins = make_array<float>({r, 4, 5});
  auto resid = make_array<float>({r, 4});
  auto diffe = make_array<float>({r, 4, ic::kDiffOrders});
  auto peak = make_array<float>({r, 4});
  auto fpeak = make_array<float>({r, 4});
  auto period = make_array<float>({r, 4});
  auto noise = make_array<float>({r, 4});
  auto hum = make_array<float>({r, 4});
  auto base = make_array<float>({r, 4});
  auto n2 = make_array<int32_t>({r, 4});
  auto toa_band = make_array<float>({r, 4});
  auto status = make_array<int32_t>({r});
  const int16_t* data = adc.data();
  ic::EventFeatures ev;
  {
    nb::gil_scoped_release release;
    for (size_t k = 0; k < r; ++k) {
      const int16_t* chans[4];
      for (int c = 0; c < 4; ++c) chans[c] = data + (k * 4 + c) * static_cast<size_t>(n);
      status.data()[k] = ic::extract_features(chans, n, cfg, &ev);
      for (int c = 0; c < 4; ++c) {
        const auto& f = ev.ch[c];
        const size_t i = k * 4 + c;
        const bool ok = status.data()[k] == ic::kOk || status.data()[k] == ic::kErrNoTrigger;
        toa.data()[i] = ok ? f.toa_us : NAN;
        toa_thr.data()[i] = ok ? f.toa_threshold : NAN;
        toa_aic.data()[i] = ok ? f.toa_aic : NAN;
        order.data()[i] = ok ? ev.order[c] : static_cast<uint8_t>(c);
        flags.data()[i] = ok ? f.flags : static_cast<uint8_t>(ic::kFlagNoOnset);
        energy.data()[i] = ok ? f.energy : NAN;
        for (int w = 0; w < 5; ++w) wins.data()[i * 5 + w] = ok ? f.window_energy[w] : NAN;
        resid.data()[i] = ok ? f.residual_ratio : NAN;
        for (int k = 0; k < ic::kDiffOrders; ++k) diffe.data()[i * ic::kDiffOrders + k] = ok ? f.diff_energy[k] : NAN;
        peak.data()[i] = ok ? f.peak : NAN;
        fpeak.data()[i] = ok ? f.first_peak : NAN;
        period.data()[i] = ok ? f.pick_period : NAN;
        noise.data()[i] = ok ? f.noise_rms : NAN;
        hum.data()[i] = ok ? f.hum_counts : NAN;
        base.data()[i] = ok ? f.baseline : NAN;
        n2.data()[i] = ok ? f.n2 : -1;
        toa_band.data()[i] = ok ? f.toa_band_us : NAN;
      }
      for (int p = 0; p < 6; ++p) {
        const bool ok = status.data()[k] == ic::kOk || status.data()[k] == ic::kErrNoTrigger;
        dtoa.data()[k * 6 + p] = ok ? ev.dtoa_us[p] : NAN;
      }
    }
  }
  nb::dict out;
  out["toa_us"] = toa;
  out["toa_threshold"] = toa_thr;
  out["toa_aic"] = toa_aic;
  out["dtoa_us"] = dtoa;
  out["order"] = order;
  out["flags"] = flags;
  out["energy"] = energy;
  out["window_energy"] = wins;
  out["residual_ratio"] = resid;
  out["diff_energy"] = diffe;
  out["peak"] = peak;
  out["first_peak"] = fpeak;
  out["pick_period"] = period;
  out["noise_rms"] = noise;
  out["hum_counts"] = hum;
  out["baseline"] = base;
  out["n2"] = n2;
  out["toa_band_us"] = toa_band;
  out["status"] = status;
  return out;
}

nb::dict localise_batch(InF toa, InU8 use, std::vector<float> sx, std::vector<float> sy, float v,
                        float sigma_us, float plate_x_mm, float plate_y_mm, float huber_us,
                        std::vector<float> travel_metric, std::vector<float> slowness_scale, int starts,
                        int posterior_grid, int max_evaluations) {
  if (!has_shape(toa, {kAny, 4})) throw std::invalid_argument("toa_us must be float32 [n, 4]");
  if (!has_shape(use, {toa.shape(0), 4})) {
    throw std::invalid_argument("use must be uint8 [n, 4] like toa_us");
  }
  four(sx, "sensor_x_mm");
  four(sy, "sensor_y_mm");
  if (!travel_metric.empty() && travel_metric.size() != 3) {
    throw std::invalid_argument("travel_metric must be [Q_xx, Q_xy, Q_yy] (or empty: isotropic)");
  }
  const size_t r = toa.shape(0);
  if (!slowness_scale.empty() && slowness_scale.size() != 4 * r) {
    throw std::invalid_argument("slowness_scale must be [n * 4] like toa_us (or empty: one velocity)");
  }
  auto x = make_array<float>({r});
  auto y = make_array<float>({r});
  auto t0 = make_array<float>({r});
  auto cov = make_array<float>({r, 3});
  auto rms = make_array<float>({r});
  auto status = make_array<int32_t>({r});
  auto evaluations = make_array<int32_t>({r});
  for (size_t k = 0; k < r; ++k) {
    const auto res = ic::localise_tdoa(toa.data() + 4 * k, use.data() + 4 * k, sx.data(), sy.data(), v,
                                       sigma_us, plate_x_mm, plate_y_mm, huber_us,
                                       travel_metric.empty() ? nullptr : travel_metric.data(),
                                       slowness_scale.empty() ? nullptr : slowness_scale.data() + 4 * k, starts,
                                       posterior_grid, max_evaluations);
    x.data()[k] = res.x_mm;
    y.data()[k] = res.y_mm;
    t0.data()[k] = res.t0_us;
    cov.data()[3 * k] = res.cov_xx;
    cov.data()[3 * k + 1] = res.cov_xy;
    cov.data()[3 * k + 2] = res.cov_yy;
    rms.data()[k] = res.rms_residual_us;
    status.data()[k] = res.status;
    evaluations.data()[k] = res.evaluations;
  }
  nb::dict out;
  out["x_mm"] = x;
  out["y_mm"] = y;
  out["t0_us"] = t0;
  out["cov"] = cov;
  out["rms_residual_us"] = rms;
  out["status"] = status;
  out["evaluations"] = evaluations;  // normal-equation evaluations, every start's (the localiser's cost)
  return out;
}

nb::ndarray<nb::numpy, uint8_t> accept_batch(InF toa, std::vector<float> sx, std::vector<float> sy,
                                            InF xy, float tol_us, float margin_mm,
                                            std::vector<float> travel_metric) {
  if (!has_shape(toa, {kAny, 4})) throw std::invalid_argument("toa_us must be float32 [n, 4]");
  if (!has_shape(xy, {toa.shape(0), 2})) {
    throw std::invalid_argument("xy_mm must be float32 [n, 2] like toa_us");
  }
  four(sx, "sensor_x_mm");
  four(sy, "sensor_y_mm");
  if (!travel_metric.empty() && travel_metric.size() != 3) {
    throw std::invalid_argument("travel_metric must be empty or (Q_xx, Q_xy, Q_yy)");
  }
  const float* metric = travel_metric.empty() ? nullptr : travel_metric.data();
  const size_t r = toa.shape(0);
  auto out = make_array<uint8_t>({r});
  for (size_t k = 0; k < r; ++k) {
    out.data()[k] = ic::accept_eq35(toa.data() + 4 * k, sx.data(), sy.data(), xy.data()[2 * k],
                                    xy.data()[2 * k + 1], tol_us, margin_mm, metric)
                        ? 1
                        : 0;
  }
  return out;
}

#define IC_BIND_COUNT_ONE(name) +1
nb::dict process_batch(In16 adc, const ic::CoreConfig& cfg, const ic::LocaliserConfig& loc) {
  const auto [r, n] = capture_batch(adc);
  auto vec = make_array<float>({r, static_cast<size_t>(ic::kNumFeatures)});
  auto phys = make_array<float>({r, 2});
  auto band = make_array<float>({r, 2});
  auto cov = make_array<float>({r, 3});
  auto accepted = make_array<uint8_t>({r});
  auto status = make_array<int32_t>({r});
  auto evals = make_array<int32_t>({r, 2});
  constexpr size_t kWork = 0 IMPACTCORE_WORK_FIELDS(IC_BIND_COUNT_ONE);
  auto work = make_array<int32_t>({r, kWork});
  const int16_t* data = adc.data();
  {
    nb::gil_scoped_release release;
    ic::EventResult ev;
    for (size_t k = 0; k < r; ++k) {
      const int16_t* chans[4];
      for (int c = 0; c < 4; ++c) chans[c] = data + (k * 4 + c) * static_cast<size_t>(n);
      ic::reset_work_counts();
      status.data()[k] = ic::process_event(chans, n, cfg, loc, &ev);
      {
        const ic::WorkCounts& w = ic::work_counts();
        int32_t* row = work.data() + k * kWork;
        size_t j = 0;
#define IC_BIND_WORK_ONE(name) row[j++] = w.name;
        IMPACTCORE_WORK_FIELDS(IC_BIND_WORK_ONE)
#undef IC_BIND_WORK_ONE
      }
      std::memcpy(vec.data() + k * ic::kNumFeatures, ev.vector, sizeof(ev.vector));
      phys.data()[2 * k] = ev.phys.x_mm;
      phys.data()[2 * k + 1] = ev.phys.y_mm;
      const bool band_ok = status.data()[k] == ic::kOk && ev.band.status == ic::kOk;
      band.data()[2 * k] = band_ok ? ev.band.x_mm : NAN;
      band.data()[2 * k + 1] = band_ok ? ev.band.y_mm : NAN;
      cov.data()[3 * k] = ev.phys.cov_xx;
      cov.data()[3 * k + 1] = ev.phys.cov_xy;
      cov.data()[3 * k + 2] = ev.phys.cov_yy;
      accepted.data()[k] = ev.accepted;
      evals.data()[2 * k] = status.data()[k] == ic::kOk ? ev.phys.evaluations : 0;
      evals.data()[2 * k + 1] = status.data()[k] == ic::kOk && ev.band.status == ic::kOk ? ev.band.evaluations : 0;
      if (status.data()[k] != ic::kOk) {
        phys.data()[2 * k] = phys.data()[2 * k + 1] = NAN;
      }
    }
  }
  nb::dict out;
  out["vector"] = vec;
  out["phys_xy_mm"] = phys;
  out["band_xy_mm"] = band;   // the band picks' own position (NaN: not run); phys_xy_mm is then the mean
  out["phys_cov"] = cov;
  out["accepted"] = accepted;
  out["status"] = status;
  // the localiser's normal-equation evaluations (its cost: board.cost), the physics run's and the band run's
  out["localiser_evaluations"] = evals;
  // the features' work on each event (impactcore.h WorkCounts, in work_fields' order: board.cost's signal bound)
  out["work"] = work;
  nb::list names;
#define IC_BIND_WORK_NAME(name) names.append(#name);
  IMPACTCORE_WORK_FIELDS(IC_BIND_WORK_NAME)
#undef IC_BIND_WORK_NAME
  out["work_fields"] = names;
  return out;
}

// Row k, channel c of extract_batch's window_energy [R,4,5] and diff_energy [R,4,3] into ch.
void copy_energies(const InF& window_energy, const InF& diff_energy, size_t k, int c, ic::ChannelFeatures* ch) {
  for (int w = 0; w < ic::kEnergyWindows; ++w)
    ch->window_energy[w] = window_energy.data()[(k * ic::kChannels + c) * ic::kEnergyWindows + w];
  for (int d = 0; d < ic::kDiffOrders; ++d)
    ch->diff_energy[d] = diff_energy.data()[(k * ic::kChannels + c) * ic::kDiffOrders + d];
}

// The twin's per-channel log-energies of every recording, from extract_batch's arrays (twin.h).
nb::tuple twin_features_batch(InF window_energy, InF diff_energy, InU8 flags) {
  const size_t r = rows_of(flags);
  if (!has_shape(flags, {r, ic::kChannels}) || !has_shape(window_energy, {r, ic::kChannels, ic::kEnergyWindows}) ||
      !has_shape(diff_energy, {r, ic::kChannels, ic::kDiffOrders})) {
    throw std::invalid_argument("window_energy [R,4,5], diff_energy [R,4,3] float32 and flags [R,4] uint8 needed");
  }
  auto feats = make_array<float>({r, static_cast<size_t>(ic::kTwinFeatures)});
  auto usable = make_array<uint16_t>({r});
  ic::EventFeatures ev;
  std::memset(&ev, 0, sizeof(ev));
  for (size_t k = 0; k < r; ++k) {
    for (int c = 0; c < ic::kChannels; ++c) {
      copy_energies(window_energy, diff_energy, k, c, &ev.ch[c]);
      ev.ch[c].flags = flags.data()[k * ic::kChannels + c];
    }
    usable.data()[k] = ic::twin_features(ev, feats.data() + k * ic::kTwinFeatures);
  }
  return nb::make_tuple(feats, usable);
}

// The three-channel class's inputs (impactcore three_channel_inputs) of every recording without channel left_out,
// from extract_batch's arrays and the physics positions.
nb::ndarray<nb::numpy, float> three_channel_inputs_batch(InF window_energy, InF diff_energy, InF energy,
                                                         InF phys_xy_mm, int left_out) {
  const size_t r = rows_of(energy);
  if (!has_shape(energy, {r, ic::kChannels}) || !has_shape(window_energy, {r, ic::kChannels, ic::kEnergyWindows}) ||
      !has_shape(diff_energy, {r, ic::kChannels, ic::kDiffOrders}) || !has_shape(phys_xy_mm, {r, 2})) {
    throw std::invalid_argument("window_energy [R,4,5], diff_energy [R,4,3], energy [R,4] and phys_xy_mm [R,2] "
                                "float32 needed");
  }
  if (left_out < 0 || left_out >= ic::kChannels) throw std::invalid_argument("left_out must be a channel 0..3");
  auto out = make_array<float>({r, static_cast<size_t>(ic::kThreeChannelInputs)});
  ic::EventFeatures ev;
  std::memset(&ev, 0, sizeof(ev));
  for (size_t k = 0; k < r; ++k) {
    for (int c = 0; c < ic::kChannels; ++c) {
      copy_energies(window_energy, diff_energy, k, c, &ev.ch[c]);
      ev.ch[c].energy = energy.data()[k * ic::kChannels + c];
    }
    ic::three_channel_inputs(ev, phys_xy_mm.data()[2 * k], phys_xy_mm.data()[2 * k + 1], left_out,
                             out.data() + k * ic::kThreeChannelInputs);
  }
  return out;
}

// The three-sensor position correction's inputs (impactcore three_position_inputs) of every row without channel
// left_out, from the feature vectors [R, kNumFeatures] and the three-sensor positions [R, 2].
nb::ndarray<nb::numpy, float> three_position_inputs_batch(InF vector, InF xy_mm, int left_out) {
  const size_t r = rows_of(vector);
  if (!has_shape(vector, {r, static_cast<size_t>(ic::kNumFeatures)}) || !has_shape(xy_mm, {r, 2})) {
    throw std::invalid_argument("vector [R, kNumFeatures] and xy_mm [R, 2] float32 needed");
  }
  if (left_out < 0 || left_out >= ic::kChannels) throw std::invalid_argument("left_out must be a channel 0..3");
  auto out = make_array<float>({r, static_cast<size_t>(ic::kThreePositionInputs)});
  for (size_t k = 0; k < r; ++k) {
    ic::three_position_inputs(vector.data() + k * ic::kNumFeatures, xy_mm.data()[2 * k], xy_mm.data()[2 * k + 1],
                              left_out, out.data() + k * ic::kThreePositionInputs);
  }
  return out;
}

using InU16 = nb::ndarray<const uint16_t, nb::c_contig, nb::device::cpu>;

void copy16(float* dst, InF src, const char* name) {
  if (!has_shape(src, {ic::kTwinFeatures}))
    throw std::invalid_argument(std::string(name) + " needs 16 float32 values");
  std::memcpy(dst, src.data(), sizeof(float) * ic::kTwinFeatures);
}

// twin_estimate over every row: features [R,16], usable [R] (uint16 masks), xy_mm [R,2] model positions.
// The site map and the twin's configuration from the binding's arguments (q stays the caller's array).
void twin_setup(InU8 q, int nx, int ny, float x0_mm, float y0_mm, float step_mm, InF base, InF scale,
                InF offset, InF slope, InF weight, float ref_log10_height_mm, float prior_mm, float cutoff_mm,
                float temperature, ic::SiteMap* map, ic::TwinConfig* cfg) {
  if (nx < 1 || ny < 1 || !has_shape(q, {static_cast<size_t>(nx) * ny, ic::kTwinFeatures})) {
    throw std::invalid_argument("site map q must be uint8 [nx*ny, 16]");
  }
  *map = ic::SiteMap{nx, ny, x0_mm, y0_mm, step_mm, {}, {}, q.data()};
  copy16(map->base, base, "base");
  copy16(map->scale, scale, "scale");
  *cfg = ic::TwinConfig();
  copy16(cfg->offset, offset, "offset");
  copy16(cfg->slope, slope, "slope");
  copy16(cfg->weight, weight, "weight");
  cfg->ref_log10_height_mm = ref_log10_height_mm;
  cfg->prior_mm = prior_mm;
  cfg->cutoff_mm = cutoff_mm;
  cfg->temperature = temperature;
}

// The per-row arrays every twin binding returns (one TwinEstimate a row), and their dict keys.
struct EstimateArrays {
  size_t r;
  nb::ndarray<nb::numpy, float> lh = make_array<float>({r});
  nb::ndarray<nb::numpy, float> pos = make_array<float>({r, 2});
  nb::ndarray<nb::numpy, float> spread = make_array<float>({r});
  nb::ndarray<nb::numpy, float> misfit = make_array<float>({r});
  nb::ndarray<nb::numpy, int32_t> status = make_array<int32_t>({r});

  void set(size_t k, const ic::TwinEstimate& e) {
    lh.data()[k] = e.log10_height_mm;
    pos.data()[2 * k] = e.x_mm;
    pos.data()[2 * k + 1] = e.y_mm;
    spread.data()[k] = e.spread_mm;
    misfit.data()[k] = e.misfit;
    status.data()[k] = e.status;
  }
  nb::dict dict() const {
    nb::dict out;
    out["log10_height_mm"] = lh;
    out["xy_mm"] = pos;
    out["spread_mm"] = spread;
    out["misfit"] = misfit;
    out["status"] = status;
    return out;
  }
};

nb::dict twin_estimate_batch(InF features, InU16 usable, InF xy_mm, InU8 q, int nx, int ny, float x0_mm,
                             float y0_mm, float step_mm, InF base, InF scale, InF offset, InF slope,
                             InF weight, float ref_log10_height_mm, float prior_mm, float cutoff_mm,
                             float temperature, float coarse_cutoff_mm) {
  const size_t r = rows_of(features);
  if (!has_shape(features, {r, ic::kTwinFeatures}) || !has_shape(usable, {r}) || !has_shape(xy_mm, {r, 2})) {
    throw std::invalid_argument("features [R,16] float32, usable [R] uint16 and xy_mm [R,2] float32 needed");
  }
  ic::SiteMap map;
  ic::TwinConfig cfg;
  twin_setup(q, nx, ny, x0_mm, y0_mm, step_mm, base, scale, offset, slope, weight, ref_log10_height_mm, prior_mm,
             cutoff_mm, temperature, &map, &cfg);
  cfg.coarse_cutoff_mm = coarse_cutoff_mm;
  EstimateArrays est{r};
  auto npts = make_array<int32_t>({r});
  {
    nb::gil_scoped_release release;
    for (size_t k = 0; k < r; ++k) {
      const ic::TwinEstimate e = ic::twin_estimate(features.data() + k * ic::kTwinFeatures, usable.data()[k],
                                                   xy_mm.data()[2 * k], xy_mm.data()[2 * k + 1], map, cfg);
      est.set(k, e);
      npts.data()[k] = e.n_points;
    }
  }
  nb::dict out = est.dict();
  out["n_points"] = npts;
  return out;
}

// twin_match (twin.h) over every row of featurize()'s arrays: the twin's match around xy_mm [R,2] (the
// forests' position; NaN rows: the forests did not run), with a dead or inconsistent channel left out.
nb::dict twin_match_batch(nb::ndarray<const int32_t, nb::c_contig, nb::device::cpu> status, InU8 flags,
                          InF toa_us, InF window_energy, InF diff_energy, InF phys_xy_mm, InF xy_mm,
                          const ic::LocaliserConfig& loc, InU8 q, int nx, int ny, float x0_mm, float y0_mm,
                          float step_mm, InF base, InF scale, InF offset, InF slope, InF weight,
                          float ref_log10_height_mm, float prior_mm, float cutoff_mm, float temperature,
                          float misfit_ref, std::vector<float> slowness_scale, float coarse_cutoff_mm,
                          int weak_channel, bool full_search) {
  const size_t r = rows_of(status);
  if (!slowness_scale.empty() && slowness_scale.size() != 4 * r) {
    throw std::invalid_argument("slowness_scale must be [R * 4] (or empty: one velocity)");
  }
  if (!has_shape(status, {r}) || !has_shape(flags, {r, ic::kChannels}) || !has_shape(toa_us, {r, ic::kChannels}) ||
      !has_shape(window_energy, {r, ic::kChannels, ic::kEnergyWindows}) ||
      !has_shape(diff_energy, {r, ic::kChannels, ic::kDiffOrders}) || !has_shape(phys_xy_mm, {r, 2}) ||
      !has_shape(xy_mm, {r, 2})) {
    throw std::invalid_argument("status [R] int32, flags [R,4] uint8, toa_us [R,4], window_energy [R,4,5], "
                                "diff_energy [R,4,3], phys_xy_mm [R,2], xy_mm [R,2] float32 needed");
  }
  ic::SiteMap map;
  ic::TwinConfig cfg;
  twin_setup(q, nx, ny, x0_mm, y0_mm, step_mm, base, scale, offset, slope, weight, ref_log10_height_mm, prior_mm,
             cutoff_mm, temperature, &map, &cfg);
  cfg.coarse_cutoff_mm = coarse_cutoff_mm;
  cfg.weak_channel = weak_channel;
  EstimateArrays est{r};
  auto left = make_array<int32_t>({r});
  auto reason = make_array<int32_t>({r});
  {
    nb::gil_scoped_release release;
    ic::EventResult ev;
    std::memset(&ev, 0, sizeof(ev));
    for (size_t k = 0; k < r; ++k) {
      ev.status = status.data()[k];
      for (int c = 0; c < ic::kChannels; ++c) {
        ic::ChannelFeatures& ch = ev.features.ch[c];
        for (int w = 0; w < ic::kEnergyWindows; ++w)
          ch.window_energy[w] = window_energy.data()[(k * ic::kChannels + c) * ic::kEnergyWindows + w];
        for (int d = 0; d < ic::kDiffOrders; ++d)
          ch.diff_energy[d] = diff_energy.data()[(k * ic::kChannels + c) * ic::kDiffOrders + d];
        ch.flags = flags.data()[k * ic::kChannels + c];
        ch.toa_us = toa_us.data()[k * ic::kChannels + c];
        ev.slowness_scale[c] = slowness_scale.empty() ? 1.0f : slowness_scale[k * ic::kChannels + c];
      }
      ev.phys.x_mm = phys_xy_mm.data()[2 * k];
      ev.phys.y_mm = phys_xy_mm.data()[2 * k + 1];
      ev.phys.status = ev.phys.x_mm == ev.phys.x_mm && ev.phys.y_mm == ev.phys.y_mm ? ic::kOk : ic::kErrSingular;
      const ic::TwinMatch m =
          ic::twin_match(ev, xy_mm.data()[2 * k], xy_mm.data()[2 * k + 1], &loc, map, cfg, misfit_ref,
                         full_search ? ic::kTwinSearchFull : ic::kTwinSearchCued);
      est.set(k, m.est);
      left.data()[k] = m.left_out;
      reason.data()[k] = m.reason;
    }
  }
  nb::dict out = est.dict();
  out["left_out"] = left;
  out["reason"] = reason;
  return out;
}

// --- configuration structs, expanded from impactcore.h's field lists (one source) ---

template <typename T>
const char* type_name();
template <>
const char* type_name<float>() { return "float"; }
template <>
const char* type_name<int>() { return "int"; }

// Values a field must satisfy beyond its type (by name; most fields have none).
void check_field(const char* name, const std::vector<float>& v) {
  if (std::strcmp(name, "channel_gain") == 0) {
    for (float g : v) {
      if (!(g > 0.0f)) throw std::invalid_argument("channel_gain values must be positive");
    }
  }
}
void check_field(const char*, const std::vector<int>&) {}

template <typename Cls, typename T>
void bind_field(nb::class_<Cls>& cls, nb::list& table, const Cls& defaults, const char* name, const char* role,
                T Cls::*member) {
  cls.def_rw(name, member);
  table.append(nb::make_tuple(name, type_name<T>(), 1, defaults.*member, role));
}

template <typename Cls, typename T, size_t N>
void bind_field(nb::class_<Cls>& cls, nb::list& table, const Cls& defaults, const char* name, const char* role,
                T (Cls::*member)[N]) {
  cls.def_prop_rw(
      name, [member](const Cls& c) { return std::vector<T>(c.*member, c.*member + N); },
      [member, name](Cls& c, std::vector<T> v) {
        if (v.size() != N) throw std::invalid_argument(std::string(name) + " needs 4 values");
        check_field(name, v);
        std::copy(v.begin(), v.end(), c.*member);
      });
  const T* d = defaults.*member;
  table.append(nb::make_tuple(name, type_name<T>(), static_cast<int>(N), std::vector<T>(d, d + N), role));
}

// Binds every field of a config struct and returns its table: (name, type, count, default, role) per field,
// in declaration order; the host builds SignalConfig, model cards and the exported C from it.
#define IMPACTSENSE_BIND_FIELD(kind, type, name, def, role) \
  bind_field(cls, table, defaults, #name, #role, &Config::name);

template <typename Config>
nb::list bind_config(nb::module_& m, const char* py_name);

template <>
nb::list bind_config<ic::CoreConfig>(nb::module_& m, const char* py_name) {
  using Config = ic::CoreConfig;
  nb::class_<Config> cls(m, py_name);
  cls.def(nb::init<>());
  nb::list table;
  const Config defaults;
  IMPACTCORE_CONFIG_FIELDS(IMPACTSENSE_BIND_FIELD)
  return table;
}

template <>
nb::list bind_config<ic::LocaliserConfig>(nb::module_& m, const char* py_name) {
  using Config = ic::LocaliserConfig;
  nb::class_<Config> cls(m, py_name);
  cls.def(nb::init<>());
  nb::list table;
  const Config defaults;
  IMPACTCORE_LOCALISER_FIELDS(IMPACTSENSE_BIND_FIELD)
  return table;
}
#undef IMPACTSENSE_BIND_FIELD

}  // namespace

NB_MODULE(_core, m) {
  m.doc() = "impactsense signal core (firmware/lib/impactcore) bound to Python";
  m.attr("CHANNELS") = ic::kChannels;
  m.attr("FLAGGED_EVALUATIONS") = ic::kFlaggedEvaluations;
  m.attr("MAX_SAMPLES") = ic::kMaxSamples;
  m.attr("PERIOD_SEARCH") = ic::kPeriodSearch;
  m.attr("PERIOD_SEARCH_WIDE") = ic::kPeriodSearchWide;
  m.attr("PERIOD_HALF_RATIO") = ic::kPeriodHalfRatio;
  m.attr("PAIR_I") = std::vector<int>(ic::kPairI, ic::kPairI + ic::kPairs);
  m.attr("PAIR_J") = std::vector<int>(ic::kPairJ, ic::kPairJ + ic::kPairs);
  m.attr("FLAG_CLIPPED") = static_cast<int>(ic::kFlagClipped);
  m.attr("FLAG_DEAD") = static_cast<int>(ic::kFlagDead);
  m.attr("FLAG_NO_ONSET") = static_cast<int>(ic::kFlagNoOnset);
  m.attr("FLAG_AIC_FALLBACK") = static_cast<int>(ic::kFlagAicFallback);
  m.attr("FLAG_HUM") = static_cast<int>(ic::kFlagHum);
  m.attr("FLAG_GLITCH") = static_cast<int>(ic::kFlagGlitch);
  m.attr("FLAG_INCONSISTENT") = static_cast<int>(ic::kFlagInconsistent);
  m.attr("STATUS_OK") = static_cast<int>(ic::kOk);
  m.attr("STATUS_NO_TRIGGER") = static_cast<int>(ic::kErrNoTrigger);
  m.def("status_name", &ic::status_name, "status"_a, "The text of an impactcore::Status code (a report's reason).");
  m.def("status_key", &ic::status_key, "status"_a, "The key of an impactcore::Status code (a report's reason).");
  {  // the codes, once (impactcore.h IMPACTCORE_STATUS): code -> key
    nb::dict keys;
#define IMPACTCORE_STATUS_PY(code, name, key, text) keys[nb::int_(code)] = key;
    IMPACTCORE_STATUS(IMPACTCORE_STATUS_PY)
#undef IMPACTCORE_STATUS_PY
    m.attr("STATUS_KEYS") = keys;
  }

  m.attr("CORE_CONFIG_FIELDS") = bind_config<ic::CoreConfig>(m, "CoreConfig");
  m.attr("LOCALISER_CONFIG_FIELDS") = bind_config<ic::LocaliserConfig>(m, "LocaliserConfig");

  m.attr("FEATURE_NAMES") = std::vector<std::string>(ic::kFeatureNames, ic::kFeatureNames + ic::kNumFeatures);
  m.def("process_batch", &process_batch, "adc"_a, "config"_a, "localiser"_a,
        "The board's per-event path over adc int16 [recording, 4, sample]: feature vectors, physics "
        "position and covariance, Eq. 35 flag, status.");

  nb::class_<ic::TriggerConfig>(m, "TriggerConfig")
      .def(nb::init<>())
      .def_rw("threshold_counts", &ic::TriggerConfig::threshold_counts)
      .def_rw("rearm_counts", &ic::TriggerConfig::rearm_counts)
      .def_rw("rearm_quiet_frames", &ic::TriggerConfig::rearm_quiet_frames)
      .def_rw("holdoff_frames", &ic::TriggerConfig::holdoff_frames)
      .def_rw("pretrigger_frames", &ic::TriggerConfig::pretrigger_frames)
      .def_rw("baseline_alpha", &ic::TriggerConfig::baseline_alpha)
      .def_rw("noise_factor", &ic::TriggerConfig::noise_factor)
      .def_rw("fire_frames", &ic::TriggerConfig::fire_frames)
      .def_rw("noise_alpha", &ic::TriggerConfig::noise_alpha);

  nb::class_<ic::Trigger>(m, "Trigger")
      .def(nb::init<const ic::TriggerConfig&, float>(), "config"_a, "initial_baseline"_a = 2048.0f)
      .def(
          "__init__",
          [](ic::Trigger* t, const ic::TriggerConfig& cfg, std::vector<float> base) {
            if (base.size() != ic::kChannels) throw std::invalid_argument("one initial baseline per channel");
            new (t) ic::Trigger(cfg, base.data());
          },
          "config"_a, "initial_baselines"_a)
      .def("feed",
           [](ic::Trigger& t, std::vector<int> frame) {
             if (frame.size() != 4) throw std::invalid_argument("a frame has 4 samples");
             int16_t f[4];
             for (int c = 0; c < 4; ++c) f[c] = static_cast<int16_t>(frame[c]);
             return t.feed(f);
           })
      .def_prop_ro("armed", &ic::Trigger::armed)
      .def_prop_ro("frames_seen", &ic::Trigger::frames_seen)
      .def_prop_ro("fired_at", &ic::Trigger::fired_at)
      .def_prop_ro("threshold", &ic::Trigger::threshold)
      .def(
          "noise_rms",
          [](const ic::Trigger& t, int channel) {
            if (channel < 0 || channel >= ic::kChannels) throw std::out_of_range("channel is 0..3");
            return t.noise_rms(channel);
          },
          "channel"_a)
      .def(
          "baseline",
          [](const ic::Trigger& t, int channel) {
            if (channel < 0 || channel >= ic::kChannels) throw std::out_of_range("channel is 0..3");
            return t.baseline(channel);
          },
          "channel"_a);

  m.def(
      "find_trigger",
      [](In16 adc, const ic::TriggerConfig& cfg) {
        if (!has_shape(adc, {4, kAny})) throw std::invalid_argument("adc must be int16 [4, n]");
        const int n = static_cast<int>(adc.shape(1));
        const int16_t* ch[4];
        for (int c = 0; c < 4; ++c) ch[c] = adc.data() + static_cast<size_t>(c) * n;
        return ic::find_trigger(ch, n, cfg);
      },
      "adc"_a, "config"_a);

  m.attr("TWIN_FEATURES") = ic::kTwinFeatures;
  m.attr("SITE_MAP_MISSING") = static_cast<int>(ic::kSiteMapMissing);
  m.attr("THREE_CHANNEL_INPUTS") = ic::kThreeChannelInputs;
  m.def("three_channel_inputs_batch", &three_channel_inputs_batch, "window_energy"_a, "diff_energy"_a, "energy"_a,
        "phys_xy_mm"_a, "left_out"_a,
        "The energy class's inputs without channel left_out (the other three channels' summed arrival and "
        "difference energies, their mean log10 energy, the physics position) [R, 7] float32.");
  m.attr("THREE_POSITION_INPUTS") = ic::kThreePositionInputs;
  m.def("three_position_inputs_batch", &three_position_inputs_batch, "vector"_a, "xy_mm"_a, "left_out"_a,
        "The three-sensor position correction's inputs without channel left_out (the position, the other three "
        "channels' time differences, relative log energies and log first peaks) [R, 11] float32.");
  m.def("twin_features_batch", &twin_features_batch, "window_energy"_a, "diff_energy"_a, "flags"_a,
        "The twin's 16 log-energies (4 channels x arrival, Delta^1..3) and usable-feature masks.");
  m.def("twin_estimate_batch", &twin_estimate_batch, "features"_a, "usable"_a, "xy_mm"_a, "q"_a, "nx"_a,
        "ny"_a, "x0_mm"_a, "y0_mm"_a, "step_mm"_a, "base"_a, "scale"_a, "offset"_a, "slope"_a, "weight"_a,
        "ref_log10_height_mm"_a, "prior_mm"_a, "cutoff_mm"_a, "temperature"_a, "coarse_cutoff_mm"_a = 0.0f,
        "The twin's energy fingerprint (twin.h) of every row: log10 height, position, spread, misfit, status.");
  m.def("twin_match_batch", &twin_match_batch, "status"_a, "flags"_a, "toa_us"_a, "window_energy"_a,
        "diff_energy"_a, "phys_xy_mm"_a, "xy_mm"_a, "localiser"_a, "q"_a, "nx"_a, "ny"_a, "x0_mm"_a, "y0_mm"_a,
        "step_mm"_a, "base"_a, "scale"_a, "offset"_a, "slope"_a, "weight"_a, "ref_log10_height_mm"_a,
        "prior_mm"_a, "cutoff_mm"_a, "temperature"_a, "misfit_ref"_a, "slowness_scale"_a = std::vector<float>(),
        "coarse_cutoff_mm"_a = 0.0f, "weak_channel"_a = -1, "full_search"_a = false,
        "twin_match (twin.h) of every row: the twin's match with a dead or inconsistent channel left out.");
  m.attr("TWIN_DEAD_CHANNEL") = static_cast<int>(ic::kTwinDeadChannel);
  m.attr("TWIN_INCONSISTENT") = static_cast<int>(ic::kTwinInconsistent);
  m.attr("TWIN_WEAK_CHANNEL") = static_cast<int>(ic::kTwinWeakChannel);
  m.def(
      "summed_log_energy_batch",
      [](InF energy, float fs_hz) {
        if (!has_shape(energy, {kAny, 4})) throw std::invalid_argument("energy must be float32 [R, 4]");
        const size_t r = energy.shape(0);
        auto out = make_array<float>({r});
        for (size_t i = 0; i < r; ++i) {
          float log_e;
          out.data()[i] = ic::summed_log_energy(energy.data() + 4 * i, fs_hz, &log_e) ? log_e : NAN;
        }
        return out;
      },
      "energy"_a, "fs_hz"_a,
      "summed_log_energy (impactcore.h) of every row of the core's channel energies: NaN where not positive.");
  m.def(
      "band_log_energy_batch",
      [](InF energy, InU8 flags, std::vector<int> channel_left_out, float fs_hz) {
        if (!has_shape(energy, {kAny, 4})) throw std::invalid_argument("energy must be float32 [R, 4]");
        if (!has_shape(flags, {energy.shape(0), 4})) throw std::invalid_argument("flags must be uint8 [R, 4]");
        if (channel_left_out.size() != 4) throw std::invalid_argument("channel_left_out must have 4 entries");
        const size_t r = energy.shape(0);
        auto out = make_array<float>({r});
        for (size_t i = 0; i < r; ++i) {
          float log_e;
          out.data()[i] = ic::band_log_energy(energy.data() + 4 * i, flags.data() + 4 * i, channel_left_out.data(),
                                              fs_hz, &log_e) ? log_e : NAN;
        }
        return out;
      },
      "energy"_a, "flags"_a, "channel_left_out"_a, "fs_hz"_a,
      "band_log_energy (impactcore.h) of every row: the summed log energy the band localiser reads, a dead or "
      "left-out channel's energy the mean of the others'; NaN where not positive.");
  m.def(
      "channel_check_terms_batch",
      [](InF xy_mm, float plate_x_mm, float plate_y_mm) {
        if (!has_shape(xy_mm, {kAny, 2})) throw std::invalid_argument("xy_mm must be float32 [R, 2]");
        const size_t r = xy_mm.shape(0);
        auto out = make_array<float>({r, static_cast<size_t>(ic::kCheckTerms)});
        for (size_t i = 0; i < r; ++i) {
          ic::channel_check_terms(xy_mm.data()[2 * i], xy_mm.data()[2 * i + 1], plate_x_mm, plate_y_mm,
                                  out.data() + ic::kCheckTerms * i);
        }
        return out;
      },
      "xy_mm"_a, "plate_x_mm"_a, "plate_y_mm"_a,
      "channel_check_terms (impactcore.h): the channel check's cubic terms at every position [R, 10].");
  m.def(
      "channel_check_ratios_batch",
      [](InF energy, InF diff3) {
        if (!has_shape(energy, {kAny, 4}) || !has_shape(diff3, {energy.shape(0), 4}))
          throw std::invalid_argument("energy and diff3 must be float32 [R, 4]");
        const size_t r = energy.shape(0);
        auto level = make_array<float>({r, 4});
        auto tilt = make_array<float>({r, 4});
        for (size_t i = 0; i < r; ++i) {
          ic::channel_check_ratios(energy.data() + 4 * i, diff3.data() + 4 * i, level.data() + 4 * i,
                                   tilt.data() + 4 * i);
        }
        return nb::make_tuple(level, tilt);
      },
      "energy"_a, "diff3"_a, "channel_check_ratios (impactcore.h) of every row: (level, tilt) [R, 4].");
  m.def(
      "channel_check_scores_batch",
      [](InF energy, InF diff3, InU8 flags, InF xy_mm, InF level_fit, InF tilt_fit, float plate_x_mm,
         float plate_y_mm) {
        const size_t r = energy.shape(0);
        constexpr size_t kFit = ic::kCheckTerms + 2;
        if (!has_shape(energy, {kAny, 4}) || !has_shape(diff3, {r, 4}) || !has_shape(flags, {r, 4}) ||
            !has_shape(xy_mm, {r, 4, 2}))
          throw std::invalid_argument("energy, diff3 float32 [R, 4], flags uint8 [R, 4], xy_mm float32 [R, 4, 2]");
        if (!has_shape(level_fit, {4, kFit}) || !has_shape(tilt_fit, {4, kFit}))
          throw std::invalid_argument("level_fit and tilt_fit must be float32 [4, 12] (10 terms, median, scale)");
        ic::ChannelCheck check;
        check.plate_x_mm = plate_x_mm;
        check.plate_y_mm = plate_y_mm;
        for (int c = 0; c < 4; ++c) {
          for (int pass = 0; pass < 2; ++pass) {
            const float* src = (pass == 0 ? level_fit : tilt_fit).data() + kFit * c;
            ic::ChannelCheckFit& fit = pass == 0 ? check.level[c] : check.tilt[c];
            std::memcpy(fit.coef, src, sizeof(fit.coef));
            fit.median = src[ic::kCheckTerms];
            fit.scale = src[ic::kCheckTerms + 1];
            if (!(fit.scale > 0.0f)) throw std::invalid_argument("a fit's scale must be > 0");
          }
        }
        auto out = make_array<float>({r, 4});
        for (size_t i = 0; i < r; ++i) {
          ic::channel_check_scores(energy.data() + 4 * i, diff3.data() + 4 * i, flags.data() + 4 * i,
                                   xy_mm.data() + 8 * i, check, out.data() + 4 * i);
        }
        return out;
      },
      "energy"_a, "diff3"_a, "flags"_a, "xy_mm"_a, "level_fit"_a, "tilt_fit"_a, "plate_x_mm"_a, "plate_y_mm"_a,
      "channel_check_scores (impactcore.h) of every row; xy_mm [R, 4, 2] the position each channel's cubic reads.");
  m.def(
      "channel_check_flags",
      [](InF scores, float event_score, float run_score, int run_events) {
        if (!has_shape(scores, {kAny, 4})) throw std::invalid_argument("scores must be float32 [R, 4]");
        if (run_events < 1 || run_events > ic::kMaxCheckEvents)
          throw std::invalid_argument("run_events must be 1..32");
        ic::ChannelCheck check;
        check.event_score = event_score;
        check.run_score = run_score;
        check.run_events = run_events;
        const size_t r = scores.shape(0);
        auto out = make_array<int32_t>({r});
        for (size_t i = 0; i < r; ++i) {
          const size_t first = i + 1 > static_cast<size_t>(run_events) ? i + 1 - run_events : 0;
          out.data()[i] = ic::channel_check_flag(scores.data() + 4 * first, static_cast<int>(i + 1 - first), check);
        }
        return out;
      },
      "scores"_a, "event_score"_a, "run_score"_a, "run_events"_a,
      "channel_check_flag (impactcore.h) of every event in the order given: the channel it flags, -1 none.");
  m.def("extract_batch", &extract_batch, "adc"_a, "config"_a,
        "Features of every recording of adc int16 [recording, 4, sample]; a dict of arrays.");
  m.def("localise_batch", &localise_batch, "toa_us"_a, "use"_a, "sensor_x_mm"_a, "sensor_y_mm"_a,
        "velocity_mm_per_us"_a, "sigma_us"_a, "plate_x_mm"_a, "plate_y_mm"_a, "huber_us"_a = 4.0f,
        "travel_metric"_a = std::vector<float>(), "slowness_scale"_a = std::vector<float>(), "starts"_a = 1,
        "posterior_grid"_a = 0, "max_evaluations"_a = 0);
  m.def("accept_batch", &accept_batch, "toa_us"_a, "sensor_x_mm"_a, "sensor_y_mm"_a, "xy_mm"_a,
        "tol_us"_a, "margin_mm"_a, "travel_metric"_a = std::vector<float>{});

  m.def(
      "bond_inverse",
      [](In16 x, const ic::CoreConfig& cfg, int channel) {
        if (channel < 0 || channel >= ic::kChannels || !ic::bond_inverse_on(cfg, channel) ||
            ic::check_bond_inverse(cfg) != ic::kOk)
          throw std::invalid_argument("bond_inverse: channel has no valid bond inverse in config");
        const int n = static_cast<int>(x.shape(0));
        if (n < 1) throw std::invalid_argument("bond_inverse: x is empty");
        auto out = make_array<int16_t>({x.shape(0)});
        ic::bond_inverse(x.data(), n, cfg.bond_corner_hz[channel], cfg.bond_gain[channel],
                         cfg.bond_limit_hz[channel], cfg, out.data());
        return out;
      },
      "x"_a, "config"_a, "channel"_a,
      "The bond inverse (bond_inverse.cpp) of one channel's int16 samples with the config's fields for channel.");
  m.def(
      "threshold_crossing",
      [](In16 x, float base, float thr, int start) {
        return ic::threshold_crossing(x.data(), static_cast<int>(x.shape(0)), base, thr, start);
      },
      "x"_a, "base"_a, "thr"_a, "start"_a = 1);
  m.def(
      "aic_pick", [](In16 x, int begin, int end) { return ic::aic_pick(x.data(), begin, end); }, "x"_a,
      "begin"_a, "end"_a);
  m.def(
      "baseline_stats",
      [](In16 x) {
        float mean, rms;
        ic::baseline_stats(x.data(), static_cast<int>(x.shape(0)), &mean, &rms);
        return nb::make_tuple(mean, rms);
      },
      "x"_a);
}
