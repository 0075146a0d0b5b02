// Python binding of the wire protocol (firmware/lib/impactlink) and the firmware app
// (firmware/lib/impactapp). Only glue: every byte and every number comes from the firmware sources.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <cmath>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "impactapp.h"
#include "impactcore.h"
#include "impactlink.h"
#include "twin.h"

namespace nb = nanobind;
using namespace nb::literals;
namespace il = impactlink;
namespace ia = impactapp;
namespace ic = impactcore;

using In16 = nb::ndarray<const int16_t, nb::c_contig, nb::device::cpu>;
using InF = nb::ndarray<const float, nb::c_contig, nb::device::cpu>;
using InU8 = nb::ndarray<const uint8_t, nb::c_contig, nb::device::cpu>;

namespace {

nb::bytes to_bytes(const uint8_t* p, size_t n) { return nb::bytes(reinterpret_cast<const char*>(p), n); }

std::string as_string(nb::bytes b) { return std::string(b.c_str(), b.size()); }

nb::dict report_dict(const il::Report& r) {
  nb::dict d;
  d["seq"] = r.seq;
  d["timestamp_ms"] = r.timestamp_ms;
  d["x_mm"] = r.x_mm;
  d["y_mm"] = r.y_mm;
  d["uncertainty_mm"] = r.uncertainty_mm < 0.0f ? nb::cast(NAN) : nb::cast(r.uncertainty_mm);
  d["energy_class"] = r.energy_class;
  d["order"] = std::vector<int>(r.order, r.order + 4);
  d["accepted"] = r.accepted;
  d["valid"] = r.valid;
  d["clipped"] = r.clipped;
  d["dead"] = r.dead;
  d["left_out"] = static_cast<int>(r.left_out);
  d["reason"] = static_cast<int>(r.reason);  // 0 valid; else an impactcore::Status code (_core.status_name)
  d["reason_key"] = ic::status_key(r.reason);
  return d;
}

il::Report report_from(nb::dict d) {
  il::Report r{};
  r.seq = nb::cast<uint32_t>(d["seq"]);
  r.timestamp_ms = d.contains("timestamp_ms") ? nb::cast<uint32_t>(d["timestamp_ms"]) : 0;
  r.x_mm = nb::cast<float>(d["x_mm"]);
  r.y_mm = nb::cast<float>(d["y_mm"]);
  r.uncertainty_mm = d.contains("uncertainty_mm") ? nb::cast<float>(d["uncertainty_mm"]) : -1.0f;
  if (!(r.uncertainty_mm >= 0.0f)) r.uncertainty_mm = -1.0f;
  r.energy_class = d.contains("energy_class") ? nb::cast<uint8_t>(d["energy_class"]) : 0;
  std::vector<int> order = d.contains("order") ? nb::cast<std::vector<int>>(d["order"])
                                               : std::vector<int>{0, 1, 2, 3};
  if (order.size() != 4) throw std::invalid_argument("order needs 4 channel indices");
  for (int i = 0; i < 4; ++i) r.order[i] = static_cast<uint8_t>(order[i]);
  r.accepted = d.contains("accepted") ? nb::cast<bool>(d["accepted"]) : false;
  r.valid = d.contains("valid") ? nb::cast<bool>(d["valid"]) : true;
  r.clipped = d.contains("clipped") ? nb::cast<uint8_t>(d["clipped"]) : 0;
  r.dead = d.contains("dead") ? nb::cast<uint8_t>(d["dead"]) : 0;
  r.left_out = d.contains("left_out") ? nb::cast<int8_t>(d["left_out"]) : static_cast<int8_t>(-1);
  r.reason = d.contains("reason") ? nb::cast<uint8_t>(d["reason"]) : 0;
  if (r.valid != (r.reason == 0)) {
    throw std::invalid_argument("a report has a reason (an impactcore status code, 1..255) exactly when it is not valid");
  }
  return r;
}

nb::dict stats_dict(const il::DecoderStats& s) {
  nb::dict d;
  d["frames"] = s.frames;
  d["crc_errors"] = s.crc_errors;
  d["length_errors"] = s.length_errors;
  d["version_errors"] = s.version_errors;
  d["type_errors"] = s.type_errors;
  d["payload_errors"] = s.payload_errors;
  d["bytes_skipped"] = s.bytes_skipped;
  d["other_version"] = s.other_version;
  return d;
}

nb::dict status_dict(const il::Status& s) {
  nb::dict d;
  d["uptime_ms"] = s.uptime_ms;
  d["buffers"] = s.buffers;
  d["overruns"] = s.overruns;
  d["events"] = s.events;
  d["dropped_reports"] = s.dropped_reports;
  d["dropped_bytes"] = s.dropped_bytes;
  d["event_cycles_last"] = s.event_cycles_last;
  d["event_cycles_max"] = s.event_cycles_max;
  d["buffer_cycles_max"] = s.buffer_cycles_max;
  d["idle_load"] = s.idle_load_permille == 0xFFFFu ? nb::cast(NAN) : nb::cast(s.idle_load_permille * 1e-3);
  d["threshold_counts"] = s.threshold_counts;
  d["health"] = std::vector<int>(s.health, s.health + 4);
  std::vector<double> noise(4);
  for (int c = 0; c < 4; ++c) noise[c] = s.noise_x10[c] == 0xFFFFu ? NAN : s.noise_x10[c] * 0.1;
  d["noise_counts"] = noise;
  d["raw_dropped"] = s.raw_dropped;
  d["dump_raw"] = (s.flags & il::kStatusDumpRaw) != 0;
  d["cycle_counter"] = (s.flags & il::kStatusCycleCounter) != 0;
  return d;
}

// A decoded frame as a Python object: (type, dict) for known bodies.
nb::object frame_object(const il::Frame& f) {
  nb::dict d;
  d["type"] = f.type;
  switch (f.type) {
    case il::kTypeReport: {
      il::Report r;
      il::unpack_report(f.body, f.len, &r);  // the decoder only emits well-formed reports
      d["kind"] = "report";
      d["report"] = report_dict(r);
      break;
    }
    case il::kTypeStatus: {
      il::Status st;
      il::unpack_status(f.body, f.len, &st);
      d["kind"] = "status";
      d["status"] = status_dict(st);
      break;
    }
    case il::kTypeAck: {
      il::Ack a;
      il::unpack_ack(f.body, f.len, &a);
      nb::dict ad;
      ad["command"] = a.command;
      ad["status"] = a.status;
      ad["fs_hz"] = a.fs_hz;
      ad["threshold_counts"] = a.threshold_counts;
      ad["capture_frames"] = a.capture_frames;
      ad["dump_raw"] = a.dump_raw;
      d["kind"] = "ack";
      d["ack"] = ad;
      break;
    }
    case il::kTypeRaw: {
      il::RawChunk c;
      il::unpack_raw(f.body, f.len, &c);
      nb::dict rd;
      rd["event_seq"] = c.event_seq;
      rd["channel"] = c.channel;
      rd["total"] = c.total;
      rd["offset"] = c.offset;
      int16_t* s = new int16_t[c.count];
      for (int i = 0; i < c.count; ++i) {
        s[i] = static_cast<int16_t>(c.samples_le[2 * i] | (c.samples_le[2 * i + 1] << 8));
      }
      nb::capsule owner(s, [](void* p) noexcept { delete[] static_cast<int16_t*>(p); });
      size_t shape[1] = {c.count};
      rd["samples"] = nb::ndarray<nb::numpy, int16_t>(s, 1, shape, owner);
      d["kind"] = "raw";
      d["raw"] = rd;
      break;
    }
    default:
      d["kind"] = "command";
      d["body"] = to_bytes(f.body, f.len);
  }
  return d;
}

class PyDecoder {
 public:
  PyDecoder() : frame_(new il::Frame) {}
  // Feeds bytes; returns the frames completed, in order.
  nb::list feed(nb::bytes data) {
    nb::list out;
    const uint8_t* p = reinterpret_cast<const uint8_t*>(data.c_str());
    for (size_t i = 0; i < data.size(); ++i) {
      if (!dec_.push(p[i], frame_.get())) continue;
      do out.append(frame_object(*frame_));
      while (dec_.poll(frame_.get()));
    }
    return out;
  }
  // Fast path for fuzzing/benchmarks: counts frames by type without building objects.
  nb::dict count(nb::bytes data) {
    const uint8_t* p = reinterpret_cast<const uint8_t*>(data.c_str());
    uint64_t reports = 0, other = 0;
    {
      nb::gil_scoped_release release;
      for (size_t i = 0; i < data.size(); ++i) {
        if (!dec_.push(p[i], frame_.get())) continue;
        do (frame_->type == il::kTypeReport ? reports : other)++;
        while (dec_.poll(frame_.get()));
      }
    }
    nb::dict d;
    d["reports"] = reports;
    d["other"] = other;
    return d;
  }
  nb::dict stats() const { return stats_dict(dec_.stats()); }
  uint32_t errors() const { return dec_.errors(); }
  void reset() { dec_.reset(); }

 private:
  il::Decoder dec_;
  std::unique_ptr<il::Frame> frame_;
};

// Forest tables owned by Python-side copies (forest.h's arrays; a linear model has roots, feature, value only).
struct Tables {
  std::vector<int32_t> roots;
  std::vector<uint8_t> feature;
  std::vector<int32_t> threshold;
  std::vector<uint16_t> skip;
  std::vector<uint16_t> leaf;
  std::vector<float> leaf_value;
  std::vector<float> value;
  std::vector<uint8_t> inputs;
  ia::ForestEvaluator evaluate = ia::forest_mean;  // ia::linear_terms for a linear energy estimate
  bool linear = false;
  ia::ModelSpec spec() const {
    const int32_t n_trees = static_cast<int32_t>(roots.size()) - (linear ? 0 : 1);
    return ia::ModelSpec{ia::ForestTables{n_trees, roots.data(), feature.data(), threshold.data(), skip.data(),
                                          leaf.data(), leaf_value.data(), value.data(),
                                          static_cast<int32_t>(inputs.size())},
                         inputs.data(), static_cast<int32_t>(inputs.size()), evaluate};
  }
};

// The linear energy estimate in the node-table arrays (host height_class.linear_tables, impactapp::linear_terms):
// roots[t] = 3 t, feature = the terms' factors (inputs or kLeaf), value = [coef (T), bias, offset, scale per input].
void check_linear(const Tables& t) {
  const size_t n_terms = t.roots.size();
  if (t.feature.size() != 3 * n_terms || t.value.size() != n_terms + 1 + 2 * t.inputs.size()) {
    throw std::invalid_argument("linear model arrays differ in length");
  }
  for (size_t k = 0; k < n_terms; ++k) {
    if (t.roots[k] != static_cast<int32_t>(3 * k)) throw std::invalid_argument("linear model term out of place");
  }
  for (uint8_t f : t.feature) {
    if (f != ia::kLeaf && f >= t.inputs.size()) throw std::invalid_argument("linear model factor out of range");
  }
}

// One tree of a forest's tables is walked exactly as forest_mean walks it: from its root (split node lo, leaf
// cursor lo + tree, c = hi - lo split nodes under it) every split node reached reads a gathered input and has
// 1 <= skip <= c (so c falls at every step and the walk ends), and the split nodes [lo, hi) and leaves
// [lo + tree, hi + tree + 1) are each reached once, in order, every leaf naming a stored value.
void check_tree(const Tables& t, size_t tree, size_t lo, size_t hi) {
  struct Item {
    size_t split, leaf, c;   // split node, leaf cursor, split nodes under it (0: a leaf)
  };
  size_t next_split = lo, next_leaf = lo + tree;
  std::vector<Item> todo{{lo, lo + tree, hi - lo}};
  while (!todo.empty()) {
    const Item it = todo.back();
    todo.pop_back();
    if (it.c == 0) {
      if (it.leaf != next_leaf++ || it.leaf >= t.leaf.size() || t.leaf[it.leaf] >= t.leaf_value.size()) {
        throw std::invalid_argument("forest leaf out of range");
      }
      continue;
    }
    const size_t i = it.split;
    if (i != next_split++ || i >= hi || t.feature[i] >= t.inputs.size() || t.skip[i] == 0 || t.skip[i] > it.c) {
      throw std::invalid_argument("forest node out of range");
    }
    const size_t s = t.skip[i];
    todo.push_back({i + s, it.leaf + s, it.c - s});   // pushed first: the left subtree comes first (preorder)
    todo.push_back({i + 1, it.leaf, s - 1});
  }
  if (next_split != hi || next_leaf != hi + tree + 1) throw std::invalid_argument("forest tree out of place");
}

// allow_twin: the forest may read ia::kTwinInput (the twin's height estimate; the energy classifier only).
Tables tables_from(nb::dict d, bool allow_twin) {
  Tables t;
  t.roots = nb::cast<std::vector<int32_t>>(d["roots"]);
  t.feature = nb::cast<std::vector<uint8_t>>(d["feature"]);
  t.inputs = nb::cast<std::vector<uint8_t>>(d["inputs"]);
  if (d.contains("kind") && nb::cast<std::string>(d["kind"]) == "linear") {
    t.value = nb::cast<std::vector<float>>(d["value"]);
    t.linear = true;
    if (t.inputs.empty() || t.inputs.size() > static_cast<size_t>(ia::kMaxModelInputs)) {
      throw std::invalid_argument("a linear model reads 1..32 features");
    }
    for (uint8_t i : t.inputs) {
      if (i >= ia::kTwinInput) throw std::invalid_argument("linear model input beyond the core's feature vector");
    }
    check_linear(t);
    t.evaluate = ia::linear_terms;
    return t;
  }
  for (const char* key : {"threshold", "skip", "leaf", "leaf_value"}) {
    if (!d.contains(key)) {
      throw std::invalid_argument(std::string("forest tables without ") + key +
                                  " (an export of an older layout: export the model again)");
    }
  }
  t.threshold = nb::cast<std::vector<int32_t>>(d["threshold"]);
  t.skip = nb::cast<std::vector<uint16_t>>(d["skip"]);
  t.leaf = nb::cast<std::vector<uint16_t>>(d["leaf"]);
  t.leaf_value = nb::cast<std::vector<float>>(d["leaf_value"]);
  const size_t n = t.feature.size();
  if (t.roots.empty() || t.threshold.size() != n || t.skip.size() != n || t.leaf.size() != n + t.roots.size() - 1 ||
      t.roots.back() != static_cast<int32_t>(n)) {
    throw std::invalid_argument("forest arrays differ in length");
  }
  if (t.inputs.empty() || t.inputs.size() > static_cast<size_t>(ia::kMaxModelInputs)) {
    throw std::invalid_argument("a forest reads 1..32 features");
  }
  for (uint8_t i : t.inputs) {
    if (i > ia::kTwinInput || (i == ia::kTwinInput && !allow_twin)) {
      throw std::invalid_argument(i == ia::kTwinInput ? "forest reads the twin's estimate but no twin was given"
                                                      : "forest input beyond the core's feature vector");
    }
  }
  for (size_t k = 0; k + 1 < t.roots.size(); ++k) {
    const int32_t lo = t.roots[k], hi = t.roots[k + 1];
    if (lo < 0 || hi <= lo || static_cast<size_t>(hi) > n) throw std::invalid_argument("forest root out of range");
    check_tree(t, k, static_cast<size_t>(lo), static_cast<size_t>(hi));
  }
  return t;
}

std::vector<float> floats(nb::dict d, const char* key, size_t n) {
  if (!d.contains(key)) throw std::invalid_argument(std::string("twin: missing key ") + key);
  auto v = nb::cast<std::vector<float>>(d[key]);
  if (v.size() != n) throw std::invalid_argument(std::string("twin: ") + key + " needs " + std::to_string(n) + " values");
  return v;
}

// The twin's site map and configuration (twin.h), owned here; the dict holds the export's arrays.
struct Twin {
  std::vector<uint8_t> q;
  ia::TwinSpec spec{};
  explicit Twin(nb::dict d) {
    const auto grid = floats(d, "grid", 5);  // nx, ny, x0_mm, y0_mm, step_mm
    // ref_log10_height_mm, prior_mm, cutoff_mm, temperature[, coarse_cutoff_mm[, weak_channel]] (older
    // exports: 4 or 5 values)
    if (!d.contains("config")) throw std::invalid_argument("twin: missing key config");
    auto cfg = nb::cast<std::vector<float>>(d["config"]);
    if (cfg.size() == 4) cfg.push_back(0.0f);
    if (cfg.size() == 5) cfg.push_back(-1.0f);
    if (cfg.size() != 6) throw std::invalid_argument("twin: config needs 6 values (4 or 5 in older exports)");
    ic::SiteMap& m = spec.map;
    m.nx = static_cast<int32_t>(grid[0]);
    m.ny = static_cast<int32_t>(grid[1]);
    m.x0_mm = grid[2];
    m.y0_mm = grid[3];
    m.step_mm = grid[4];
    if (m.nx < 1 || m.ny < 1 || static_cast<float>(m.nx) != grid[0] || static_cast<float>(m.ny) != grid[1]) {
      throw std::invalid_argument("twin: grid nx, ny must be positive integers");
    }
    q = nb::cast<std::vector<uint8_t>>(d["q"]);
    if (q.size() != static_cast<size_t>(m.nx) * m.ny * ic::kTwinFeatures) {
      throw std::invalid_argument("twin: q needs nx * ny * 16 bytes");
    }
    m.q = q.data();
    const size_t n = ic::kTwinFeatures;
    const auto base = floats(d, "base", n), scale = floats(d, "scale", n);
    const auto off = floats(d, "offset", n), slope = floats(d, "slope", n), w = floats(d, "weight", n);
    for (size_t k = 0; k < n; ++k) {
      m.base[k] = base[k];
      m.scale[k] = scale[k];
      spec.cfg.offset[k] = off[k];
      spec.cfg.slope[k] = slope[k];
      spec.cfg.weight[k] = w[k];
    }
    spec.cfg.ref_log10_height_mm = cfg[0];
    spec.cfg.prior_mm = cfg[1];
    spec.cfg.cutoff_mm = cfg[2];
    spec.cfg.temperature = cfg[3];
    spec.cfg.coarse_cutoff_mm = cfg[4];
    spec.cfg.weak_channel = static_cast<int32_t>(cfg[5]);
    if (d.contains("uncertainty")) {  // offset_mm, scale, misfit_ref (impactapp::twin_uncertainty_mm)
      const auto u = floats(d, "uncertainty", 3);
      spec.uncertainty_offset_mm = u[0];
      spec.uncertainty_scale = u[1];
      spec.uncertainty_misfit_ref = u[2];
    }
    if (d.contains("edge")) {  // bias, ramp_mm, plate x, y (impactapp::twin_edge_term)
      const auto e = floats(d, "edge", 4);
      spec.edge_log10_bias = e[0];
      spec.edge_ramp_mm = e[1];
      spec.plate_x_mm = e[2];
      spec.plate_y_mm = e[3];
    }
  }
};

struct PyModels : ia::Models {
  Tables x, y, e;
  bool residual;
  std::unique_ptr<Twin> twin;
  std::vector<Tables> three;        // the three-channel classes (linear, one per channel left out), or none
  std::vector<ia::ModelSpec> three_specs;
  std::unique_ptr<ia::TableModels> impl;
  std::unique_ptr<ic::ChannelCheck> check;  // the channel check (with the three-channel classes), or none
  std::vector<Tables> pairs;        // the three-sensor position's pairs (8: channel c's x at 2c, y at 2c + 1), or none
  std::vector<ia::ModelSpec> pair_specs;
  PyModels(nb::dict dx, nb::dict dy, nb::dict de, bool residual_xy, nb::object dtwin, nb::object dthree,
           nb::object dcheck, nb::object dpairs)
      : x(tables_from(dx, false)), y(tables_from(dy, false)), e(tables_from(de, !dtwin.is_none())),
        residual(residual_xy) {
    if (!dcheck.is_none()) {
      if (dthree.is_none()) throw std::invalid_argument("channel_check: needs the three-channel classes");
      const nb::dict d = nb::cast<nb::dict>(dcheck);
      check.reset(new ic::ChannelCheck());
      const auto level = floats(d, "level", ic::kChannels * (ic::kCheckTerms + 2));
      const auto tilt = floats(d, "tilt", ic::kChannels * (ic::kCheckTerms + 2));
      // plate_x_mm, plate_y_mm, event_score, run_score, run_events[, four_channel_mask] (5: an older export, none)
      if (!d.contains("scores")) throw std::invalid_argument("channel_check: missing key scores");
      auto sc = nb::cast<std::vector<float>>(d["scores"]);
      if (sc.size() != 5 && sc.size() != 6) throw std::invalid_argument("channel_check: scores needs 5 or 6 values");
      if (sc.size() == 5) sc.push_back(0.0f);
      for (int c = 0; c < ic::kChannels; ++c) {
        for (int pass = 0; pass < 2; ++pass) {
          const float* src = (pass == 0 ? level : tilt).data() + (ic::kCheckTerms + 2) * c;
          ic::ChannelCheckFit& fit = pass == 0 ? check->level[c] : check->tilt[c];
          std::memcpy(fit.coef, src, sizeof(fit.coef));
          fit.median = src[ic::kCheckTerms];
          fit.scale = src[ic::kCheckTerms + 1];
          if (!(fit.scale > 0.0f)) throw std::invalid_argument("channel_check: a fit's scale must be > 0");
        }
      }
      check->plate_x_mm = sc[0];
      check->plate_y_mm = sc[1];
      check->event_score = sc[2];
      check->run_score = sc[3];
      check->run_events = static_cast<int32_t>(sc[4]);
      check->four_channel_mask = static_cast<int32_t>(sc[5]);
      if (check->four_channel_mask < 0 || check->four_channel_mask > 15) {
        throw std::invalid_argument("channel_check: four_channel_mask 0..15");
      }
      if (check->run_events < 1 || check->run_events > ic::kMaxCheckEvents || !(sc[0] > 0.0f) || !(sc[1] > 0.0f)) {
        throw std::invalid_argument("channel_check: run_events 1..32 and a positive plate size needed");
      }
    }
    if (!dtwin.is_none()) twin.reset(new Twin(nb::cast<nb::dict>(dtwin)));
    if (!dthree.is_none()) {
      if (twin) throw std::invalid_argument("three_channel: a model with a twin matches without the channel itself");
      const nb::list items = nb::cast<nb::list>(dthree);
      if (items.size() != static_cast<size_t>(ic::kChannels)) {
        throw std::invalid_argument("three_channel: one linear model per channel (4)");
      }
      for (nb::handle d : items) {
        Tables t = tables_from(nb::cast<nb::dict>(d), false);
        if (t.evaluate != ia::linear_terms || t.inputs.size() != static_cast<size_t>(ic::kThreeChannelInputs)) {
          throw std::invalid_argument("three_channel: linear models of the 7 three-channel inputs");
        }
        three.push_back(std::move(t));
      }
      for (const Tables& t : three) three_specs.push_back(t.spec());
    }
    if (!dpairs.is_none()) {
      if (three.empty()) throw std::invalid_argument("three_position: needs the three-channel classes");
      const nb::list items = nb::cast<nb::list>(dpairs);
      if (items.size() != static_cast<size_t>(2 * ic::kChannels)) {
        throw std::invalid_argument("three_position: 8 forests (channel c's x at 2c, y at 2c + 1)");
      }
      for (nb::handle d : items) {
        Tables t = tables_from(nb::cast<nb::dict>(d), false);
        if (t.linear || t.inputs.size() != static_cast<size_t>(ic::kThreePositionInputs)) {
          throw std::invalid_argument("three_position: forests of the 11 three-position inputs");
        }
        pairs.push_back(std::move(t));
      }
      for (const Tables& t : pairs) pair_specs.push_back(t.spec());
    }
    impl.reset(new ia::TableModels(x.spec(), y.spec(), e.spec(), residual, twin ? &twin->spec : nullptr,
                                   three_specs.empty() ? nullptr : three_specs.data(), check.get(),
                                   pair_specs.empty() ? nullptr : pair_specs.data()));
  }
  bool predict(const ic::EventResult& ev, float* xm, float* ym, uint8_t* c) const override {
    return impl->predict(ev, xm, ym, c);
  }
  bool predict_with_uncertainty(const ic::EventResult& ev, float* xm, float* ym, uint8_t* c,
                                float* u) const override {
    return impl->predict_with_uncertainty(ev, xm, ym, c, u);
  }
  bool predict_event(const ic::EventResult& ev, const ic::LocaliserConfig& loc, float* xm, float* ym, uint8_t* c,
                     float* u, int8_t* left_out, int flagged, const ic::CoreConfig* core,
                     int32_t* reason) const override {
    return impl->predict_event(ev, loc, xm, ym, c, u, left_out, flagged, core, reason);
  }
  const ic::ChannelCheck* channel_check() const override { return impl->channel_check(); }
};

// Collects what the app writes.
struct BufferHal : ia::Hal {
  std::string out;
  std::string ble;
  uint32_t last_rate = 0;
  size_t accept = static_cast<size_t>(-1);  // bytes the host takes (writable()); the emulator limits it
  size_t writable() override { return accept; }
  void write(const uint8_t* d, size_t n) override {
    out.append(reinterpret_cast<const char*>(d), n);
    if (accept != static_cast<size_t>(-1)) accept -= n;
  }
  void notify(const uint8_t* d, size_t n) override { ble.append(reinterpret_cast<const char*>(d), n); }
  bool apply_rate(uint32_t hz) override {
    last_rate = hz;
    return true;
  }
};

ia::AppConfig app_config(nb::dict d) {
  ia::AppConfig c;
  for (auto item : d) {
    const std::string k = nb::cast<std::string>(item.first);
    nb::handle v = item.second;
    if (k == "fs_hz") c.fs_hz = nb::cast<uint32_t>(v);
    else if (k == "pretrigger_us") c.pretrigger_us = nb::cast<float>(v);
    else if (k == "capture_us") c.capture_us = nb::cast<float>(v);
    else if (k == "holdoff_us") c.holdoff_us = nb::cast<float>(v);
    else if (k == "quiet_us") c.quiet_us = nb::cast<float>(v);
    else if (k == "threshold_counts") c.threshold_counts = nb::cast<float>(v);
    else if (k == "rearm_counts") c.rearm_counts = nb::cast<float>(v);
    else if (k == "loc") c.loc = nb::cast<ic::LocaliserConfig>(v);
    else if (k == "dump_raw") c.dump_raw = nb::cast<bool>(v);
    else if (k == "status_period_ms") c.status_period_ms = nb::cast<uint32_t>(v);
    else if (k == "core") c.core = nb::cast<ic::CoreConfig>(v);
    else throw std::invalid_argument("unknown app config key: " + k);
  }
  return c;
}

class PyApp {
 public:
  PyApp(nb::dict config, nb::object models) {
    if (!models.is_none()) models_ = nb::cast<PyModels*>(models);
    keep_ = models;
    app_.reset(new ia::App(hal_, models_, ia::AppConfig()));
    if (!app_->configure(app_config(config))) throw std::invalid_argument("app configuration out of range");
  }
  // Interleaved int16 frames [n, 4], in buffers of `buffer` frames with the board's service() between them;
  // returns the serial bytes the host took meanwhile: all of them, or at most `accept` bytes (None: no
  // limit; 0: a host that does not read), the rest staying queued or dropped as on the board.
  nb::bytes feed(In16 frames, int buffer, nb::object accept) {
    if (frames.ndim() != 2 || frames.shape(1) != 4) throw std::invalid_argument("frames must be int16 [n, 4]");
    if (buffer < 1) throw std::invalid_argument("buffer must be >= 1 frame");
    hal_.accept = accept.is_none() ? static_cast<size_t>(-1) : nb::cast<size_t>(accept);
    {
      nb::gil_scoped_release release;
      const int n = static_cast<int>(frames.shape(0));
      for (int off = 0; off < n; off += buffer) {
        app_->on_samples(frames.data() + 4 * off, n - off < buffer ? n - off : buffer);
        while (app_->service()) {
        }
      }
    }
    hal_.accept = static_cast<size_t>(-1);
    return take();
  }
  nb::bytes rx(nb::bytes data) {
    app_->on_rx(reinterpret_cast<const uint8_t*>(data.c_str()), data.size());
    while (app_->service()) {
    }
    return take();
  }
  void add_overruns(uint32_t n) { app_->add_overruns(n); }
  // What the host takes now: at most max_bytes of the transmit queue (raw dump chunks are queued meanwhile).
  nb::bytes pull(size_t max_bytes) {
    hal_.accept = max_bytes;
    while (app_->service()) {
    }
    hal_.accept = static_cast<size_t>(-1);
    return take();
  }
  nb::bytes take() {
    nb::bytes b(hal_.out.data(), hal_.out.size());
    hal_.out.clear();
    return b;
  }
  nb::bytes take_ble() {
    nb::bytes b(hal_.ble.data(), hal_.ble.size());
    hal_.ble.clear();
    return b;
  }
  int capture_frames() const { return app_->capture_frames(); }
  int pretrigger_frames() const { return app_->pretrigger_frames(); }
  uint32_t events() const { return app_->events(); }
  uint32_t fs_hz() const { return app_->config().fs_hz; }
  ic::CoreConfig core_config() const { return app_->config().core; }
  ic::LocaliserConfig localiser_config() const { return app_->config().loc; }
  nb::dict rx_stats() const { return stats_dict(app_->rx_stats()); }

 private:
  BufferHal hal_;
  PyModels* models_ = nullptr;
  nb::object keep_;
  std::unique_ptr<ia::App> app_;
};

}  // namespace

NB_MODULE(_link, m) {
  m.doc() = "impactsense wire protocol (firmware/lib/impactlink) and firmware app (firmware/lib/impactapp)";
  m.attr("VERSION") = il::kVersion;
  m.attr("TYPE_REPORT") = static_cast<int>(il::kTypeReport);
  m.attr("TYPE_RAW") = static_cast<int>(il::kTypeRaw);
  m.attr("TYPE_ACK") = static_cast<int>(il::kTypeAck);
  m.attr("CMD_SET_THRESHOLD") = static_cast<int>(il::kCmdSetThreshold);
  m.attr("CMD_SET_RATE") = static_cast<int>(il::kCmdSetRate);
  m.attr("CMD_DUMP_RAW") = static_cast<int>(il::kCmdDumpRaw);
  m.attr("CMD_GET_CONFIG") = static_cast<int>(il::kCmdGetConfig);
  m.attr("REPORT_FRAME_BYTES") = il::kReportFrame;
  m.attr("TYPE_STATUS") = static_cast<int>(il::kTypeStatus);
  m.attr("STATUS_FRAME_BYTES") = il::kStatusFrame;
  m.attr("TX_QUEUE_BYTES") = ia::kTxQueueBytes;
  m.attr("REPORT_BODY_BYTES") = il::kReportBody;
  m.attr("BLE_PAYLOAD_BYTES") = il::kBlePayload;
  m.attr("MAX_FRAME_BYTES") = il::kMaxFrame;
  m.attr("MAX_RATE_HZ") = ia::kMaxRateHz;
  m.attr("SCAN_STEP_US") = ia::kScanStepUs;
  m.attr("LEAF") = ia::kLeaf;
  m.def("board_core_config", &ia::board_core_config, "card"_a, "fs_hz"_a, "adc_min"_a = 0, "adc_max"_a = 4095,
        "A model card's CoreConfig as the board runs it at fs_hz (impactapp::board_core_config): sample counts "
        "scaled, the board's rate, SAADC scan capture delays and ADC rails.");

  m.def("twin_edge_term", [](float x_mm, float y_mm, float bias, float ramp_mm, float plate_x_mm, float plate_y_mm) {
    ia::TwinSpec spec{};
    spec.edge_log10_bias = bias;
    spec.edge_ramp_mm = ramp_mm;
    spec.plate_x_mm = plate_x_mm;
    spec.plate_y_mm = plate_y_mm;
    return ia::twin_edge_term(x_mm, y_mm, spec);
  }, "x_mm"_a, "y_mm"_a, "bias"_a, "ramp_mm"_a, "plate_x_mm"_a, "plate_y_mm"_a,
        "The log10 height the board's twin estimate at (x_mm, y_mm) loses (impactapp::twin_edge_term).");

  m.def("crc32", [](nb::bytes b) {
    return il::crc32(reinterpret_cast<const uint8_t*>(b.c_str()), b.size());
  });
  m.def("encode_report", [](nb::dict d) {
    uint8_t buf[il::kReportFrame];
    const size_t n = il::encode_report(report_from(d), buf, sizeof(buf));
    return to_bytes(buf, n);
  }, "report"_a, "The serial frame of a report dict.");
  m.def("report_body", [](nb::dict d) {
    uint8_t b[il::kReportBody];
    il::pack_report(report_from(d), b);
    return to_bytes(b, sizeof(b));
  });
  m.def("ble_payload", [](nb::dict d) {
    uint8_t b[il::kBlePayload];
    il::ble_payload(report_from(d), b);
    return to_bytes(b, sizeof(b));
  }, "report"_a, "The BLE GATT notification of a report dict: [version] + report body.");
  m.def("parse_ble_payload", [](nb::bytes b) -> nb::object {
    il::Report r;
    if (!il::parse_ble_payload(reinterpret_cast<const uint8_t*>(b.c_str()), b.size(), &r)) return nb::none();
    return report_dict(r);
  });
  m.def("encode_command", [](int type, uint32_t value) {
    uint8_t buf[16];
    const size_t n = il::encode_command(static_cast<uint8_t>(type), value, buf, sizeof(buf));
    if (n == 0) throw std::invalid_argument("not a command or value out of range");
    return to_bytes(buf, n);
  }, "type"_a, "value"_a = 0);
  m.def("encode_frame", [](int type, nb::bytes body) {
    std::vector<uint8_t> buf(il::kMaxFrame);
    const size_t n = il::encode_frame(static_cast<uint8_t>(type), reinterpret_cast<const uint8_t*>(body.c_str()),
                                      body.size(), buf.data(), buf.size());
    if (n == 0) throw std::invalid_argument("body too long");
    return to_bytes(buf.data(), n);
  }, "type"_a, "body"_a, "A frame of any type around any body (for tests: the decoder must judge it).");

  nb::class_<PyDecoder>(m, "Decoder")
      .def(nb::init<>())
      .def("feed", &PyDecoder::feed, "data"_a, "Feeds bytes; returns the completed frames as dicts.")
      .def("count", &PyDecoder::count, "data"_a)
      .def_prop_ro("stats", &PyDecoder::stats)
      .def_prop_ro("errors", &PyDecoder::errors)
      .def("reset", &PyDecoder::reset);

  m.attr("TWIN_INPUT") = static_cast<int>(ia::kTwinInput);

  nb::class_<PyModels>(m, "ForestModels")
      .def(nb::init<nb::dict, nb::dict, nb::dict, bool, nb::object, nb::object, nb::object, nb::object>(), "x"_a,
           "y"_a, "energy"_a, "residual_xy"_a, "twin"_a = nb::none(), "three_channel"_a = nb::none(),
           "channel_check"_a = nb::none(), "three_position"_a = nb::none(),
           "Forest tables (dicts of roots, feature, value, right, inputs) as the firmware walks them; twin: the "
           "site map and its configuration (dict of grid [nx, ny, x0_mm, y0_mm, step_mm], q, base, scale, offset, "
           "slope, weight, config [ref_log10_height_mm, prior_mm, cutoff_mm, temperature]) when the energy "
           "classifier reads the twin's estimate (input TWIN_INPUT); three_channel (without a twin): a list of 4 "
           "linear models (kind 'linear', inputs 0..6) of impactcore three_channel_inputs, the class of a drop "
           "whose channel c has no onset; channel_check (with three_channel): dict of level and tilt (4 x 12: the "
           "cubic's 10 coefficients, median, scale), scores (plate_x_mm, plate_y_mm, event_score, run_score, "
           "run_events): impactcore's channel check, whose flagged channel the app's reports leave out; "
           "three_position (with three_channel): 8 forests (channel c's x at 2c, y at 2c + 1; 0 trees: none) over "
           "impactcore three_position_inputs, correcting the three-sensor position of a drop without c.")
      .def_prop_ro("residual_xy", [](const PyModels& p) { return p.residual; })
      .def_prop_ro("has_twin", [](const PyModels& p) { return p.twin != nullptr; })
      .def("predict", [](const PyModels& p, InF vector, InF phys_xy, nb::object window_energy,
                         nb::object diff_energy, nb::object flags, nb::object energy) {
        if (vector.ndim() != 2 || vector.shape(1) != static_cast<size_t>(ic::kNumFeatures)) {
          throw std::invalid_argument("vector must be float32 [n, core feature count]");
        }
        if (phys_xy.ndim() != 2 || phys_xy.shape(1) != 2 || phys_xy.shape(0) != vector.shape(0)) {
          throw std::invalid_argument("phys_xy must be float32 [n, 2]");
        }
        const size_t r = vector.shape(0);
        // The per-channel energies and flags the twin reads (EventFeatures), when given.
        const bool energies = !window_energy.is_none();
        const bool channel_energy = !energy.is_none();   // EventFeatures energy (the three-channel classes read it)
        InF we, de, en;
        InU8 fl;
        if (energies && !channel_energy && !p.three.empty()) {
          throw std::invalid_argument("a model with three-channel classes needs each event's energy [n, 4] too");
        }
        if (channel_energy) {
          en = nb::cast<InF>(energy);
          if (en.ndim() != 2 || en.shape(0) != r || en.shape(1) != ic::kChannels) {
            throw std::invalid_argument("energy must be float32 [n, 4]");
          }
        }
        if (energies) {
          we = nb::cast<InF>(window_energy);
          de = nb::cast<InF>(diff_energy);
          fl = nb::cast<InU8>(flags);
          if (we.ndim() != 3 || we.shape(0) != r || we.shape(1) != ic::kChannels ||
              we.shape(2) != ic::kEnergyWindows || de.ndim() != 3 || de.shape(0) != r ||
              de.shape(1) != ic::kChannels || de.shape(2) != ic::kDiffOrders || fl.ndim() != 2 ||
              fl.shape(0) != r || fl.shape(1) != ic::kChannels) {
            throw std::invalid_argument("window_energy [n,4,5], diff_energy [n,4,3] float32 and flags [n,4] uint8");
          }
        }
        float* out = new float[4 * (r ? r : 1)];
        std::unique_ptr<ic::EventResult> ev(new ic::EventResult());
        ev->status = ic::kOk;
        ev->phys.status = ic::kOk;
        for (size_t k = 0; k < r; ++k) {
          std::memcpy(ev->vector, vector.data() + k * ic::kNumFeatures, sizeof(ev->vector));
          ev->phys.x_mm = phys_xy.data()[2 * k];
          ev->phys.y_mm = phys_xy.data()[2 * k + 1];
          if (energies) {
            for (int c = 0; c < ic::kChannels; ++c) {
              ic::ChannelFeatures& ch = ev->features.ch[c];
              std::memcpy(ch.window_energy, we.data() + (k * ic::kChannels + c) * ic::kEnergyWindows,
                          sizeof(ch.window_energy));
              std::memcpy(ch.diff_energy, de.data() + (k * ic::kChannels + c) * ic::kDiffOrders,
                          sizeof(ch.diff_energy));
              ch.flags = fl.data()[k * ic::kChannels + c];
            }
          }
          if (channel_energy) {
            for (int c = 0; c < ic::kChannels; ++c) ev->features.ch[c].energy = en.data()[k * ic::kChannels + c];
          }
          float x = NAN, y = NAN;
          uint8_t c = 0;
          const bool ok = p.predict(*ev, &x, &y, &c);
          out[4 * k] = x;
          out[4 * k + 1] = y;
          out[4 * k + 2] = static_cast<float>(c);
          out[4 * k + 3] = ok ? 1.0f : 0.0f;
        }
        nb::capsule owner(out, [](void* q) noexcept { delete[] static_cast<float*>(q); });
        size_t shape[2] = {r, 4};
        return nb::ndarray<nb::numpy, float>(out, 2, shape, owner);
      }, "vector"_a, "phys_xy"_a, "window_energy"_a = nb::none(), "diff_energy"_a = nb::none(),
      "flags"_a = nb::none(), "energy"_a = nb::none(),
      "Predictions [n, 4]: x_mm, y_mm, energy_class, ran (1/0), from the firmware's forest walker. A twin model "
      "also needs each event's window_energy [n,4,5], diff_energy [n,4,3] and flags [n,4] (featurize's raw); a "
      "model with three-channel classes given flags also needs energy [n,4].");

  nb::class_<PyApp>(m, "App")
      .def(nb::init<nb::dict, nb::object>(), "config"_a = nb::dict(), "models"_a = nb::none())
      .def("feed", &PyApp::feed, "frames"_a, "buffer"_a = 256, "accept"_a = nb::none(),
           "Feeds interleaved frames int16 [n, 4] in DMA-sized buffers, servicing the transmit queue between "
           "them as the board's loop() does; returns the serial bytes the host took (at most `accept`).")
      .def("add_overruns", &PyApp::add_overruns, "n"_a, "Acquisition buffers lost (the board's DMA ring).")
      .def("pull", &PyApp::pull, "max_bytes"_a, "At most max_bytes of the queued serial bytes (the host reads).")
      .def("rx", &PyApp::rx, "data"_a, "Bytes from the host (commands); returns the serial bytes.")
      .def("take_ble", &PyApp::take_ble)
      .def_prop_ro("capture_frames", &PyApp::capture_frames)
      .def_prop_ro("pretrigger_frames", &PyApp::pretrigger_frames)
      .def_prop_ro("events", &PyApp::events)
      .def_prop_ro("fs_hz", &PyApp::fs_hz)
      .def_prop_ro("core_config", &PyApp::core_config)
      .def_prop_ro("localiser_config", &PyApp::localiser_config)
      .def_prop_ro("rx_stats", &PyApp::rx_stats);
}
