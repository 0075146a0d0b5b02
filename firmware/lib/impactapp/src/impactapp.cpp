// impactapp: capture state machine + signal core + models + protocol.
#include "impactapp.h"

#include <math.h>
#include <string.h>

namespace impactapp {

namespace ic = impactcore;
namespace il = impactlink;

namespace {

// The inputs of model m from the feature vector; kTwinInput reads `twin` (NaN: not available).
bool gather(const ModelSpec& m, const float* vector, float twin, float* out) {
  if (m.n_inputs > kMaxModelInputs) return false;
  for (int32_t k = 0; k < m.n_inputs; ++k) {
    const uint8_t i = m.inputs[k];
    if (i > kTwinInput) return false;
    const float v = i == kTwinInput ? twin : vector[i];
    if (!(v == v) || v - v != 0.0f) return false;  // NaN or inf: the event is not usable
    out[k] = v;
  }
  return true;
}

bool reads_twin(const ModelSpec& m) {
  for (int32_t k = 0; k < m.n_inputs; ++k) {
    if (m.inputs[k] == kTwinInput) return true;
  }
  return false;
}

// Why the models cannot place an event the forests could not (their position NaN) when the twin or the
// three-channel classes have not already failed on it themselves: two or more channels without an onset; one, and no
// three-channel path (three_path false) or no physics position to start it from; none, and the residual forests'
// physics position failed or an input is not finite. 0 when one channel is missing and the path could run.
int32_t missing_reason(const ic::EventResult& ev, bool residual, bool three_path) {
  int missing = 0;
  for (int c = 0; c < ic::kChannels; ++c) missing += (ev.features.ch[c].flags & (ic::kFlagNoOnset | ic::kFlagDead)) ? 1 : 0;
  if (missing >= 2) return ic::kErrChannelsMissing;
  if (missing == 1) {
    if (!three_path) return ic::kErrChannelMissing;
    return ev.phys.status != ic::kOk ? static_cast<int32_t>(ic::kErrLocaliser) : 0;
  }
  return residual && ev.phys.status != ic::kOk ? ic::kErrLocaliser : ic::kErrNotFinite;
}

// Why the twin's match failed on an event whose start it had: no channel it can read (every channel with an onset
// clipped), else no site-map point near enough.
int32_t twin_reason(const ic::EventResult& ev) {
  for (int c = 0; c < ic::kChannels; ++c) {
    if (!(ev.features.ch[c].flags & (ic::kFlagClipped | ic::kFlagDead | ic::kFlagNoOnset))) return ic::kErrTwinNoMatch;
  }
  return ic::kErrClipped;
}

}  // namespace

float twin_uncertainty_mm(const ic::TwinEstimate& t, const TwinSpec& spec) {
  float u = spec.uncertainty_offset_mm + spec.uncertainty_scale * t.spread_mm;
  if (spec.uncertainty_misfit_ref > 0.0f && t.misfit > spec.uncertainty_misfit_ref) {
    u *= ic::vsqrt_f32(t.misfit / spec.uncertainty_misfit_ref);  // the Birge ratio: energies fit worse than in training
  }
  return u;
}

float twin_edge_term(float x_mm, float y_mm, const TwinSpec& spec) {
  if (!(spec.edge_ramp_mm > 0.0f)) return 0.0f;
  float d = x_mm < spec.plate_x_mm - x_mm ? x_mm : spec.plate_x_mm - x_mm;
  d = y_mm < d ? y_mm : d;
  d = spec.plate_y_mm - y_mm < d ? spec.plate_y_mm - y_mm : d;
  const float ramp = 1.0f - d / spec.edge_ramp_mm;
  return ramp > 0.0f ? spec.edge_log10_bias * ramp : 0.0f;
}

bool TableModels::predict(const ic::EventResult& ev, float* x_mm, float* y_mm, uint8_t* cls) const {
  float uncertainty = 0.0f;
  return predict_with_uncertainty(ev, x_mm, y_mm, cls, &uncertainty);
}

bool TableModels::predict_with_uncertainty(const ic::EventResult& ev, float* x_mm, float* y_mm, uint8_t* cls,
                                           float* uncertainty_mm) const {
  int8_t left_out = -1;
  return predict_impl(ev, nullptr, x_mm, y_mm, cls, uncertainty_mm, &left_out);
}

bool TableModels::predict_event(const ic::EventResult& ev, const ic::LocaliserConfig& loc, float* x_mm, float* y_mm,
                                uint8_t* cls, float* uncertainty_mm, int8_t* left_out, int flagged,
                                const ic::CoreConfig* core, int32_t* reason) const {
  return predict_impl(ev, &loc, x_mm, y_mm, cls, uncertainty_mm, left_out, flagged, core, reason);
}

void TableModels::correct_three(const ic::EventResult& ev, int c, float* x_mm, float* y_mm) const {
  if (three_xy_ == nullptr || c < 0 || c >= ic::kChannels) return;
  const ModelSpec& mx = three_xy_[2 * c];
  const ModelSpec& my = three_xy_[2 * c + 1];
  if (mx.forest.n_trees <= 0 || my.forest.n_trees <= 0) return;
  float in[ic::kThreePositionInputs];
  ic::three_position_inputs(ev.vector, *x_mm, *y_mm, c, in);
  for (int k = 0; k < ic::kThreePositionInputs; ++k) {
    if (!(in[k] - in[k] == 0.0f)) return;  // NaN or inf: the plain position
  }
  const float dx = mx.evaluate(mx.forest, in);
  const float dy = my.evaluate(my.forest, in);
  *x_mm += dx;
  *y_mm += dy;
}

bool TableModels::three_sensor_path(const ic::EventResult& ev, const ic::LocaliserConfig& loc,
                                    const ic::CoreConfig& core, int flagged, float* x_mm, float* y_mm, uint8_t* cls,
                                    float* uncertainty_mm) const {
  const ic::LocaliserResult p = ic::three_sensor_position(ev, core, loc, flagged);
  if (p.status != ic::kOk) return false;
  float in[ic::kThreeChannelInputs];
  ic::three_channel_inputs(ev.features, p.x_mm, p.y_mm, flagged, in);
  *cls = three_[flagged].evaluate(three_[flagged].forest, in) > 0.5f ? 1 : 0;
  *x_mm = p.x_mm;
  *y_mm = p.y_mm;
  correct_three(ev, flagged, x_mm, y_mm);
  const float var = p.cov_xx + p.cov_yy;
  if (var >= 0.0f) *uncertainty_mm = sqrtf(var);
  return true;
}

bool TableModels::predict_impl(const ic::EventResult& ev, const ic::LocaliserConfig* loc, float* x_mm, float* y_mm,
                               uint8_t* cls, float* uncertainty_mm, int8_t* left_out, int flagged,
                               const ic::CoreConfig* core, int32_t* reason) const {
  float in[kMaxModelInputs];
  int32_t why_not = 0;  // scratch when the caller does not ask why
  int32_t* why = reason != nullptr ? reason : &why_not;
  *left_out = -1;
  if (ev.status != ic::kOk) {
    *why = ev.status;
    return false;
  }
  // The forests' position; NaN when they cannot run (a channel without an onset leaves the vector NaN).
  float x = NAN, y = NAN;
  const bool forests = !(residual_ && ev.phys.status != ic::kOk) && gather(x_, ev.vector, NAN, in);
  if (forests && has_check_ && flagged >= 0 && flagged < ic::kChannels && loc != nullptr && core != nullptr) {
    const float u0 = *uncertainty_mm;
    if (three_sensor_path(ev, *loc, *core, flagged, x_mm, y_mm, cls, uncertainty_mm)) {
      *left_out = static_cast<int8_t>(flagged);  // a channel the check flags: the three-sensor path
      if (!((check_.four_channel_mask >> flagged) & 1)) return true;
      // ... unless the model keeps the four channels' position on that channel (the host's flagged_position.py):
      // the forests' position, the three-channel class, the channel still named
      *uncertainty_mm = u0;
      const float dx = x_.evaluate(x_.forest, in);
      if (!same_xy_inputs_ && !gather(y_, ev.vector, NAN, in)) return false;
      const float dy = y_.evaluate(y_.forest, in);
      *x_mm = residual_ ? ev.phys.x_mm + dx : dx;
      *y_mm = residual_ ? ev.phys.y_mm + dy : dy;
      return true;
    }
  }
  if (forests) {
    const float dx = x_.evaluate(x_.forest, in);
    if (same_xy_inputs_ || gather(y_, ev.vector, NAN, in)) {
      const float dy = y_.evaluate(y_.forest, in);
      x = residual_ ? ev.phys.x_mm + dx : dx;
      y = residual_ ? ev.phys.y_mm + dy : dy;
    }
  }
  float twin = NAN, uncertainty = NAN;
  if (reads_twin(e_) && !has_twin_) {
    *why = ic::kErrBadConfig;  // an energy classifier reading a twin the models do not have
    return false;
  }
  if (has_twin_) {
    // The event's per-channel energies against the twin's site map around the forests' (x, y) (or the
    // three-sensor physics position; twin_match): how hard (log10 height, the energy forest's input
    // kTwinInput) and where (the matched grid points' weighted mean, reported instead of the forests'
    // position; host: models.ImpactModel.predict).
    const ic::TwinMatch m = ic::twin_match(ev, x, y, loc, twin_.map, twin_.cfg, twin_.uncertainty_misfit_ref);
    if (m.est.status != ic::kOk) {
      const int32_t r = x == x && y == y ? 0 : missing_reason(ev, residual_, true);
      *why = r != 0 ? r : twin_reason(ev);
      return false;
    }
    x = m.est.x_mm;
    y = m.est.y_mm;
    twin = m.est.log10_height_mm - twin_edge_term(x, y, twin_);
    uncertainty = twin_uncertainty_mm(m.est, twin_);
    *left_out = static_cast<int8_t>(m.left_out);
  } else if (!(x == x) || !(y == y)) {
    // One channel without an onset (dead, or left out: channel_left_out) and the three-channel classes: the
    // physics localiser's three-sensor position, the class from the other three channels' energies.
    int c = -1;
    for (int k = 0; k < ic::kChannels; ++k) {
      if (ev.features.ch[k].flags & ic::kFlagNoOnset) c = c < 0 ? k : ic::kChannels;
    }
    if (three_ == nullptr || c < 0 || c >= ic::kChannels || ev.phys.status != ic::kOk) {
      const int32_t r = missing_reason(ev, residual_, three_ != nullptr);
      // 0: a dead channel with an onset (no kFlagNoOnset), which the three-channel classes do not take
      *why = r != 0 ? r : static_cast<int32_t>(ic::kErrChannelMissing);
      return false;
    }
    ic::three_channel_inputs(ev.features, ev.phys.x_mm, ev.phys.y_mm, c, in);
    *cls = three_[c].evaluate(three_[c].forest, in) > 0.5f ? 1 : 0;
    *x_mm = ev.phys.x_mm;
    *y_mm = ev.phys.y_mm;
    correct_three(ev, c, x_mm, y_mm);
    *left_out = static_cast<int8_t>(c);
    return true;
  }
  if (!has_twin_) {
    // Forests trained with a channel left out (channel_left_out at training) run on a drop whose left-out
    // channel has no onset (a four-channel model's cannot: its vector is NaN there). The report names that
    // channel and the class is the three-channel one from the other three channels' energies: the channel's
    // own energy is not trusted (host: models.ImpactModel._left_out_class).
    int c = -1;
    for (int k = 0; k < ic::kChannels; ++k) {
      if (ev.features.ch[k].flags & ic::kFlagNoOnset) c = c < 0 ? k : ic::kChannels;
    }
    if (c >= 0 && c < ic::kChannels) {
      *left_out = static_cast<int8_t>(c);
      if (three_ != nullptr && ev.phys.status == ic::kOk) {
        ic::three_channel_inputs(ev.features, ev.phys.x_mm, ev.phys.y_mm, c, in);
        *cls = three_[c].evaluate(three_[c].forest, in) > 0.5f ? 1 : 0;
        *x_mm = x;
        *y_mm = y;
        return true;
      }
    }
  }
  if (!gather(e_, ev.vector, twin, in)) {
    *why = ic::kErrNotFinite;
    return false;
  }
  *cls = e_.evaluate(e_.forest, in) > 0.5f ? 1 : 0;
  *x_mm = x;
  *y_mm = y;
  if (has_twin_) *uncertainty_mm = uncertainty;
  return true;
}

App::App(Hal& hal, const Models* models, const AppConfig& cfg)
    : hal_(hal), models_(models), trigger_(ic::TriggerConfig()) {
  if (!configure(cfg)) configure(AppConfig());
}

ic::CoreConfig board_acquisition(uint32_t fs_hz, int adc_min, int adc_max) {
  ic::CoreConfig a;
  a.fs_hz = static_cast<float>(fs_hz);
  for (int c = 0; c < 4; ++c) a.capture_delay_us[c] = static_cast<float>(-c) * kScanStepUs;
  a.adc_min = adc_min;
  a.adc_max = adc_max;
  return a;
}

bool App::configure(const AppConfig& cfg) {
  if (cfg.fs_hz < kMinRateHz || cfg.fs_hz > kMaxRateHz) return false;
  const float fs = static_cast<float>(cfg.fs_hz);
  int pre = static_cast<int>(cfg.pretrigger_us * fs * 1e-6f + 0.5f);
  if (pre < cfg.core.baseline_samples + 16) pre = cfg.core.baseline_samples + 16;  // room for the baseline
  const int cap = static_cast<int>(cfg.capture_us * fs * 1e-6f + 0.5f);
  const int hold = static_cast<int>(cfg.holdoff_us * fs * 1e-6f + 0.5f);
  const int quiet = static_cast<int>(cfg.quiet_us * fs * 1e-6f + 0.5f);
  if (pre < cfg.core.baseline_samples || pre > kMaxPretrigger || cap <= pre + 16 || cap > kMaxCapture ||
      hold < cap - pre || quiet < 1 || !(cfg.threshold_counts > cfg.rearm_counts)) {
    return false;
  }
  cfg_ = cfg;
  const ic::CoreConfig acquisition = board_acquisition(cfg.fs_hz, cfg.core.adc_min, cfg.core.adc_max);
  cfg_.core.fs_hz = acquisition.fs_hz;
  for (int c = 0; c < 4; ++c) cfg_.core.capture_delay_us[c] = acquisition.capture_delay_us[c];
  pre_frames_ = pre;
  capture_frames_ = cap;
  trig_cfg_ = ic::TriggerConfig();
  trig_cfg_.threshold_counts = cfg.threshold_counts;
  trig_cfg_.rearm_counts = cfg.rearm_counts;
  trig_cfg_.holdoff_frames = hold;
  trig_cfg_.rearm_quiet_frames = quiet;
  trig_cfg_.pretrigger_frames = pre;
  restart();
  return true;
}

void App::restart() {
  state_ = kWarmup;
  check_rows_ = 0;
  ring_pos_ = 0;
  ring_fill_ = 0;
  cap_pos_ = 0;
}

void App::on_samples(const int16_t* data, int n_frames) {
  const uint32_t c0 = hal_.cycles();
  event_cycles_in_buffer_ = 0;
  bool had_event = false;
  // The frame counter and the ring's position live in registers across the buffer (nothing the loop calls
  // reads frame_count_; ~8 instructions a frame of the idle cost).
  const uint64_t first = frame_count_;
  frame_count_ = first + static_cast<uint64_t>(n_frames > 0 ? n_frames : 0);
  for (int i = 0; i < n_frames; ++i) {
    const int16_t* frame = data + 4 * i;
    const uint64_t now = first + static_cast<uint64_t>(i);
    if (state_ == kCapturing) {
      for (int c = 0; c < 4; ++c) capture_[c][cap_pos_] = frame[c];
      ++cap_pos_;
      trigger_.feed(frame);  // keeps counting its hold-off
      memcpy(ring_[ring_pos_], frame, sizeof(ring_[0]));  // the ring always holds the latest frames
      if (++ring_pos_ == pre_frames_) ring_pos_ = 0;
      if (cap_pos_ == capture_frames_) {
        const uint32_t e0 = hal_.cycles();
        process_capture();
        const uint32_t de = hal_.cycles() - e0;
        event_cycles_in_buffer_ += de;
        event_cycles_last_ = de;
        if (de > event_cycles_max_) event_cycles_max_ = de;
        had_event = true;
        state_ = kListening;
      }
      continue;
    }
    if (state_ == kListening && trigger_.feed(frame)) {
      if (raw_pending_) finish_raw(true);  // capture_ is about to be overwritten
      // Pre-trigger: the ring's frames, oldest first, then this frame.
      for (int k = 0; k < pre_frames_; ++k) {
        const int16_t* f = ring_[(ring_pos_ + k) % pre_frames_];
        for (int c = 0; c < 4; ++c) capture_[c][k] = f[c];
      }
      for (int c = 0; c < 4; ++c) capture_[c][pre_frames_] = frame[c];
      cap_pos_ = pre_frames_ + 1;
      trigger_frame_ = now;
      state_ = kCapturing;
      continue;
    }
    memcpy(ring_[ring_pos_], frame, sizeof(ring_[0]));
    if (++ring_pos_ == pre_frames_) ring_pos_ = 0;
    if (state_ == kWarmup && ++ring_fill_ == pre_frames_) {
      // Arm with each channel's mean of the last kArmFrames frames as its baseline (short enough that a
      // mains hum barely moves over it: the trigger then follows it).
      constexpr int kArmFrames = 8;
      float base[4] = {0.0f, 0.0f, 0.0f, 0.0f};
      const int m = pre_frames_ < kArmFrames ? pre_frames_ : kArmFrames;
      for (int j = 1; j <= m; ++j) {
        const int k = (ring_pos_ - j + pre_frames_) % pre_frames_;
        for (int c = 0; c < 4; ++c) base[c] += static_cast<float>(ring_[k][c]);
      }
      for (int c = 0; c < 4; ++c) base[c] /= static_cast<float>(m);
      trigger_ = ic::Trigger(trig_cfg_, base);
      state_ = kListening;
    }
  }
  account_buffer(hal_.cycles() - c0, n_frames, had_event);
}

// Status accounting of one buffer; a status frame when its period has passed.
void App::account_buffer(uint32_t cycles, int n_frames, bool had_event) {
  ++buffers_;
  if (!had_event) {
    ++idle_buffers_;
    idle_cycles_sum_ += cycles;
    idle_frames_sum_ += static_cast<uint64_t>(n_frames);
    if (cycles > idle_cycles_max_) idle_cycles_max_ = cycles;
  }
  if (cfg_.status_period_ms == 0 || frame_count_ < next_status_frame_) return;
  send_status();
  next_status_frame_ = frame_count_ + static_cast<uint64_t>(cfg_.status_period_ms) * cfg_.fs_hz / 1000u;
}

void App::send_status() {
  il::Status& s = status_;
  s.uptime_ms = static_cast<uint32_t>(frame_count_ * 1000u / cfg_.fs_hz);
  s.buffers = buffers_;
  s.overruns = overruns_;
  s.events = seq_;
  s.dropped_reports = dropped_reports_;
  s.dropped_bytes = txq_.dropped_bytes();
  s.event_cycles_last = event_cycles_last_;
  s.event_cycles_max = event_cycles_max_;
  s.buffer_cycles_max = idle_cycles_max_;
  const uint32_t hz = hal_.cycles_hz();
  s.idle_load_permille = 0xFFFFu;
  if (hz > 0 && idle_frames_sum_ > 0) {
    // busy cycles / (the buffers' duration in cycles), permille
    const uint64_t period = idle_frames_sum_ * hz / cfg_.fs_hz;
    const uint64_t pm = idle_cycles_sum_ * 1000u / (period > 0 ? period : 1);
    s.idle_load_permille = static_cast<uint16_t>(pm < 0xFFFEu ? pm : 0xFFFEu);
  }
  const float t = trigger_threshold();
  s.threshold_counts = t <= 0.0f ? 0 : (t >= 65535.0f ? 65535 : static_cast<uint16_t>(t + 0.5f));
  // The trigger's noise tracker has settled once armed for its time constant (1 / noise_alpha frames).
  const bool live = state_ != kWarmup && trigger_.frames_seen() * trig_cfg_.noise_alpha >= 1.0f;
  for (int c = 0; c < 4; ++c) {
    // Noise: the trigger's tracked noise rms (what its threshold follows), before it settled the last
    // event's baseline noise (none yet: unknown). Health: the last event's view of each channel (none yet: 0).
    s.health[c] = 0;
    s.noise_x10[c] = 0xFFFFu;
    const bool event = seq_ > 0;
    const ic::ChannelFeatures& ch = ev_.features.ch[c];
    const float noise = live ? trigger_.noise_rms(c) : (event ? ch.noise_rms : -1.0f);
    const float nx = noise * 10.0f + 0.5f;
    if (noise >= 0.0f) s.noise_x10[c] = static_cast<uint16_t>(nx < 65534.0f ? nx : 65534.0f);
    if (!event) continue;
    if (ch.flags & ic::kFlagDead) s.health[c] |= il::kHealthDead;
    if (ch.flags & ic::kFlagClipped) s.health[c] |= il::kHealthClipped;
    if (ch.flags & ic::kFlagNoOnset) s.health[c] |= il::kHealthNoOnset;
    if (ch.flags & ic::kFlagHum) s.health[c] |= il::kHealthHum;
    if (ch.flags & ic::kFlagGlitch) s.health[c] |= il::kHealthGlitch;
    if (report_.valid && report_.left_out == c && !(ch.flags & (ic::kFlagDead | ic::kFlagNoOnset))) {
      s.health[c] |= il::kHealthInconsistent;  // the models left it out for its energies (twin_match)
    }
  }
  s.raw_dropped = raw_dropped_;
  s.flags = static_cast<uint8_t>((cfg_.dump_raw ? il::kStatusDumpRaw : 0) | (hz > 0 ? il::kStatusCycleCounter : 0));
  idle_buffers_ = 0;
  idle_cycles_max_ = 0;
  idle_cycles_sum_ = 0;
  idle_frames_sum_ = 0;
  emit(il::encode_status(s, tx_, sizeof(tx_)));
}

void App::emit(size_t n) {
  if (n > 0) txq_.push(tx_, n);
}

bool App::service() {
  bool progress = false;
  while (raw_pending_) {
    if (raw_ch_ >= 4) {  // the whole capture is queued: its report follows, once it fits
      if (txq_.room() < il::kReportFrame) break;
      finish_raw(false);
      progress = true;
      break;
    }
    if (txq_.room() < il::kHeaderBytes + il::kRawHeader + 2u * kRawChunk + il::kCrcBytes) break;
    send_raw_chunk();
    progress = true;
  }
  const uint8_t* p;
  const size_t n = txq_.peek(&p);
  const size_t sent = n > 0 ? hal_.write_some(p, n) : 0;
  if (sent > 0) {
    txq_.consume(sent);
    progress = true;
  }
  return progress;
}

void App::process_capture() {
  const int16_t* chans[4] = {capture_[0], capture_[1], capture_[2], capture_[3]};
  const int32_t st = ic::process_event(chans, capture_frames_, cfg_.core, cfg_.loc, &ev_);
  il::Report& r = report_;
  // Every field zero but its defaults, field by field (`r = il::Report{}` is a memset call under -Os).
  r.x_mm = r.y_mm = 0.0f;
  r.energy_class = 0;
  r.accepted = r.valid = false;
  r.clipped = r.dead = 0;
  r.reason = 0;
  r.seq = seq_++;
  r.timestamp_ms = static_cast<uint32_t>((trigger_frame_ * 1000u) / cfg_.fs_hz);
  r.uncertainty_mm = -1.0f;
  r.left_out = -1;
  for (int c = 0; c < 4; ++c) r.order[c] = static_cast<uint8_t>(c);
  if (st == ic::kOk || st == ic::kErrNoTrigger) {
    for (int c = 0; c < 4; ++c) {
      const uint8_t fl = ev_.features.ch[c].flags;
      if (fl & ic::kFlagClipped) r.clipped |= static_cast<uint8_t>(1u << c);
      if (fl & (ic::kFlagDead | ic::kFlagNoOnset)) r.dead |= static_cast<uint8_t>(1u << c);
      r.order[c] = ev_.features.order[c];
    }
  }
  if (st == ic::kOk && ev_.phys.status == ic::kOk) {
    // The physics localiser: the position and uncertainty when the models cannot run, Eq. 35.
    r.x_mm = ev_.phys.x_mm;
    r.y_mm = ev_.phys.y_mm;
    r.accepted = ev_.accepted != 0;
    const float var = ev_.phys.cov_xx + ev_.phys.cov_yy;
    if (var >= 0.0f) r.uncertainty_mm = sqrtf(var);
  }
  const int flagged = check_event(st);
  if (st == ic::kOk && models_ != nullptr) {
    int32_t why = ic::kErrNotFinite;  // a Models that does not say why
    r.valid = models_->predict_event(ev_, cfg_.loc, &r.x_mm, &r.y_mm, &r.energy_class, &r.uncertainty_mm,
                                     &r.left_out, flagged, &cfg_.core, &why);
    if (!r.valid) {
      r.left_out = -1;
      r.reason = static_cast<uint8_t>(why > 0 && why < 256 ? why : static_cast<int32_t>(ic::kErrNotFinite));
    }
  } else {
    r.reason = static_cast<uint8_t>(st != ic::kOk ? st : static_cast<int32_t>(ic::kErrNoModels));  // the core's error, or no models
  }
  uint8_t ble[il::kBlePayload];
  const size_t nb = il::ble_payload(r, ble);
  hal_.notify(ble, nb);
  if (cfg_.dump_raw) {
    // The capture goes out as raw chunks first (service(), paced by the queue's room), then its report.
    if (raw_pending_) finish_raw(true);
    raw_pending_ = true;
    raw_ch_ = 0;
    raw_off_ = 0;
    return;
  }
  // The serial frame around the body packed for the notification (send_report() packs it again: the held-back case).
  const size_t n = il::encode_frame(il::kTypeReport, ble + 1, il::kReportBody, tx_, sizeof(tx_));
  if (!txq_.push(tx_, n)) ++dropped_reports_;
}

int App::check_event(int32_t status) {
  const ic::ChannelCheck* check = models_ != nullptr ? models_->channel_check() : nullptr;
  if (check == nullptr) return -1;
  int w = check->run_events < ic::kMaxCheckEvents ? check->run_events : ic::kMaxCheckEvents;
  if (w < 1) w = 1;
  if (check_rows_ >= w) {  // keep the last w - 1 events' scores, this one's after them
    memmove(check_scores_[0], check_scores_[check_rows_ - w + 1], sizeof(check_scores_[0]) * static_cast<size_t>(w - 1));
    check_rows_ = w - 1;
  }
  float* s = check_scores_[check_rows_++];
  for (int c = 0; c < ic::kChannels; ++c) s[c] = NAN;
  if (status == ic::kOk) {
    // every channel's cubic at the four-channel physics position as the core gives it (the host's channel_check,
    // version 2, reads process_batch's phys_xy_mm)
    float energy[ic::kChannels], diff3[ic::kChannels], xy[2 * ic::kChannels];
    uint8_t flags[ic::kChannels];
    for (int c = 0; c < ic::kChannels; ++c) {
      const ic::ChannelFeatures& ch = ev_.features.ch[c];
      energy[c] = ch.energy;
      diff3[c] = ch.diff_energy[ic::kDiffOrders - 1];
      flags[c] = ch.flags;
      xy[2 * c] = ev_.phys.x_mm;
      xy[2 * c + 1] = ev_.phys.y_mm;
    }
    ic::channel_check_scores(energy, diff3, flags, xy, *check, s);
  }
  return ic::channel_check_flag(check_scores_[0], check_rows_, *check);
}

void App::send_report() {
  const size_t n = il::encode_report(report_, tx_, sizeof(tx_));
  if (!txq_.push(tx_, n)) ++dropped_reports_;
}

void App::send_raw_chunk() {
  const int cnt = capture_frames_ - raw_off_ < kRawChunk ? capture_frames_ - raw_off_ : kRawChunk;
  emit(il::encode_raw(report_.seq, static_cast<uint8_t>(raw_ch_), static_cast<uint16_t>(capture_frames_),
                      static_cast<uint16_t>(raw_off_), capture_[raw_ch_] + raw_off_, static_cast<uint16_t>(cnt),
                      tx_, sizeof(tx_)));
  raw_off_ += cnt;
  if (raw_off_ >= capture_frames_) {
    raw_off_ = 0;
    ++raw_ch_;
  }
}

void App::finish_raw(bool dropped) {
  if (dropped && raw_dropped_ < 0xFFFFu) ++raw_dropped_;
  raw_pending_ = false;
  send_report();
}

void App::on_rx(const uint8_t* data, size_t n) {
  for (size_t i = 0; i < n; ++i) {
    if (!rx_.push(data[i], &rx_frame_)) continue;
    do handle_command(rx_frame_);
    while (rx_.poll(&rx_frame_));
  }
}

static uint32_t body_u32(const impactlink::Frame& f) {
  uint32_t v = 0;
  for (int i = f.len - 1; i >= 0; --i) v = (v << 8) | f.body[i];
  return v;
}

void App::handle_command(const il::Frame& f) {
  AppConfig next = cfg_;
  switch (f.type) {
    case il::kCmdSetThreshold:
      next.threshold_counts = static_cast<float>(body_u32(f));
      if (next.rearm_counts >= next.threshold_counts) next.rearm_counts = next.threshold_counts / 3.0f;
      send_ack(f.type, configure(next) ? 0 : 1);
      return;
    case il::kCmdSetRate: {
      next.fs_hz = body_u32(f);
      const bool ok = next.fs_hz >= kMinRateHz && next.fs_hz <= kMaxRateHz && hal_.apply_rate(next.fs_hz) &&
                      configure(next);
      send_ack(f.type, ok ? 0 : 1);
      return;
    }
    case il::kCmdDumpRaw:
      cfg_.dump_raw = body_u32(f) != 0;
      send_ack(f.type, 0);
      return;
    case il::kCmdGetConfig:
      send_ack(f.type, 0);
      return;
    default:
      send_ack(f.type, 2);  // reports/acks/raw are not commands
      return;
  }
}

void App::send_ack(uint8_t command, uint8_t status) {
  il::Ack a;
  a.command = command;
  a.status = status;
  a.fs_hz = cfg_.fs_hz;
  const float t = cfg_.threshold_counts;
  a.threshold_counts = t <= 0.0f ? 0 : (t >= 65535.0f ? 65535 : static_cast<uint16_t>(t + 0.5f));
  a.capture_frames = static_cast<uint16_t>(capture_frames_);
  a.dump_raw = cfg_.dump_raw ? 1 : 0;
  emit(il::encode_ack(a, tx_, sizeof(tx_)));
}

}  // namespace impactapp
