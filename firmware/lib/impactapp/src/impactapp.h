// impactapp: the portable firmware application. Samples in, protocol bytes out.
//
// The board (firmware/src) implements Hal and calls App::on_samples() with each EasyDMA buffer of
// interleaved 4-channel frames, and App::on_rx() with the bytes received on USB serial (or the BLE config
// characteristic). Everything here also runs natively: the emulator (impactsense emulate) and the qemu
// test image drive the same class. No heap anywhere; all buffers are members of App (static on the board).
//
// Memory (defaults; bytes):
//   ring_      kMaxPretrigger x 4 int16          =  2,048  pre-trigger frames
//   capture_   4 x kMaxCapture int16              = 16,384  channel-major capture (the core's input)
//   tx_        impactlink::kMaxFrame              =  1,034  one outgoing frame
//   decoder    impactlink::kMaxFrame + stats      ~  1,070  command decoder
//   ev_        impactcore::EventResult            ~    420
//   total App                                     ~ 21 KB of the nRF52840's 256 KB RAM
// The board adds 2 x kDmaFrames x 4 int16 EasyDMA buffers (firmware/src/main.cpp).
//
// Timing at 4 x 50 kHz: a capture is processed inside on_samples() when its last frame arrives; the
// budget is 64,000 instructions (1 ms at 64 MHz) for features + localiser + models + encoding, measured by
// benchmarks/bench_firmware_cost.py under qemu. The SAADC keeps filling the other DMA half meanwhile
// (kDmaFrames = 256 frames = 5.12 ms at 50 kHz), so one event's processing never loses samples.
#pragma once

#include <stddef.h>
#include <stdint.h>

#include "forest.h"
#include "impactcore.h"
#include "impactlink.h"
#include "twin.h"
#include "txqueue.h"

namespace impactapp {

constexpr int kMaxPretrigger = 256;   // frames
constexpr int kMaxCapture = 2048;     // frames (<= impactcore::kMaxSamples)
constexpr uint32_t kMaxRateHz = 50000;  // SAADC: 200 ksps in all over 4 channels
constexpr uint32_t kMinRateHz = 5000;
constexpr float kScanStepUs = 5.0f;     // SAADC TACQ 3 us + conversion <= 2 us per channel in a scan
constexpr int kRawChunk = 256;          // samples per raw-capture frame
constexpr size_t kTxQueueBytes = 4096;  // serial transmit queue (frames are dropped, never waited for)

// Board services the app needs.
class Hal {
 public:
  virtual ~Hal() {}
  // USB serial: write() must take n <= writable() bytes without blocking (App::service() never offers more).
  virtual void write(const uint8_t* data, size_t n) = 0;
  virtual size_t writable() { return static_cast<size_t>(-1); }
  // Writes what the port takes now, at most n bytes, without blocking; returns how many. The default writes
  // min(n, writable()) with write(); a board whose port reports no free space ahead overrides it.
  virtual size_t write_some(const uint8_t* data, size_t n) {
    const size_t w = writable();
    if (n > w) n = w;
    if (n > 0) write(data, n);
    return n;
  }
  // A free-running CPU cycle counter (the board's DWT CYCCNT) and its rate; 0 Hz: none (status reports 0).
  virtual uint32_t cycles() { return 0; }
  virtual uint32_t cycles_hz() { return 0; }
  virtual void notify(const uint8_t* payload, size_t n) { (void)payload; (void)n; }  // BLE report
  virtual bool apply_rate(uint32_t fs_hz) { (void)fs_hz; return true; }  // retime the sampling TIMER
};

// A model input index equal to kTwinInput (one past the core's feature vector) reads the twin's estimate
// of log10(drop height / mm) (twin.h: twin_features + twin_estimate at the position the x/y forests give).
// Only the energy classifier may read it; `impactsense export` writes it for models trained with a site map.
constexpr uint8_t kTwinInput = static_cast<uint8_t>(impactcore::kNumFeatures);
static_assert(impactcore::kNumFeatures < 255, "kTwinInput must fit a u8 input index");

// What evaluates a forest for its gathered inputs (the mean of its trees): forest_mean over its node tables,
// or the m2cgen export's code for it (impactsense_models_m2c.c, one function per tree; the tables unused).
typedef float (*ForestEvaluator)(const ForestTables& tables, const float* inputs);

// One forest and the indices of the impactcore feature-vector entries it reads (model_card.json's
// location_features / energy_features), in the order the forest was trained on.
struct ModelSpec {
  ForestTables forest;
  const uint8_t* inputs;
  int32_t n_inputs;
  ForestEvaluator evaluate = forest_mean;  // the node-table walk, or the m2cgen code (exported_m2cgen_models)
};

// The twin's site map and how the rig's events relate to it (the model card's "twin").
struct TwinSpec {
  impactcore::SiteMap map;
  impactcore::TwinConfig cfg;
  // The reported position's 1-sigma radial uncertainty, sqrt(E r^2) of its distance r from the truth,
  // calibrated on the training drops (host twin.calibrated_uncertainty):
  // (uncertainty_offset_mm + uncertainty_scale * spread_mm) * sqrt(max(1, misfit / uncertainty_misfit_ref));
  // misfit_ref 0: no inflation. The defaults report the raw spread.
  float uncertainty_offset_mm = 0.0f;
  float uncertainty_scale = 1.0f;
  float uncertainty_misfit_ref = 0.0f;
  // The height estimate's edge term (host twin_edge.py): log10 h -= edge_log10_bias * max(0, 1 - d /
  // edge_ramp_mm), d the reported position's distance to the nearest edge of the plate_x_mm x plate_y_mm
  // plate; edge_ramp_mm 0: none.
  float edge_log10_bias = 0.0f;
  float edge_ramp_mm = 0.0f;
  float plate_x_mm = 0.0f;
  float plate_y_mm = 0.0f;
};

// The calibrated uncertainty (TwinSpec) of a twin estimate t (status kOk).
float twin_uncertainty_mm(const impactcore::TwinEstimate& t, const TwinSpec& spec);

// The edge term (TwinSpec) the twin's log10 height estimate at the reported (x_mm, y_mm) loses; 0 without one.
float twin_edge_term(float x_mm, float y_mm, const TwinSpec& spec);

// The models: the core's per-event result in, position and energy class out. False when they cannot run
// (a feature is missing, e.g. a channel without onset).
class Models {
 public:
  virtual ~Models() {}
  virtual bool predict(const impactcore::EventResult& ev, float* x_mm, float* y_mm,
                       uint8_t* energy_class) const = 0;
  // predict(), and the 1-sigma radial uncertainty (mm) of the position when the models have their own
  // (left unchanged otherwise: the report keeps the physics localiser's).
  virtual bool predict_with_uncertainty(const impactcore::EventResult& ev, float* x_mm, float* y_mm,
                                        uint8_t* energy_class, float* uncertainty_mm) const {
    (void)uncertainty_mm;
    return predict(ev, x_mm, y_mm, energy_class);
  }
  // predict_with_uncertainty() knowing the localiser's geometry, so that models matching the twin can leave
  // a dead or inconsistent channel out (impactcore::twin_match); *left_out is that channel (-1: none).
  // flagged: the channel the channel check flags on this event (App: impactcore::channel_check_flag over the
  // check's scores, channel_check()), -1 none; models with three-channel classes then report the three-sensor path
  // without it (core: the event's core configuration, for impactcore::three_sensor_position).
  // reason (not nullptr): when they cannot run (false), why: an impactcore::Status code (the event's own status,
  // or one of the app's, kErrChannelsMissing .. kErrNotFinite); left alone when they run.
  virtual bool predict_event(const impactcore::EventResult& ev, const impactcore::LocaliserConfig& loc, float* x_mm,
                             float* y_mm, uint8_t* energy_class, float* uncertainty_mm, int8_t* left_out,
                             int flagged = -1, const impactcore::CoreConfig* core = nullptr,
                             int32_t* reason = nullptr) const {
    (void)loc;
    (void)flagged;
    (void)core;
    *left_out = -1;
    const bool ok = predict_with_uncertainty(ev, x_mm, y_mm, energy_class, uncertainty_mm);
    if (!ok && reason != nullptr) *reason = ev.status != impactcore::kOk ? ev.status : static_cast<int32_t>(impactcore::kErrNotFinite);
    return ok;
  }
  // The channel check the models carry (a model without a twin; the card's "channel_check"), or nullptr.
  virtual const impactcore::ChannelCheck* channel_check() const { return nullptr; }
};

// Models as forests (forest.h's node tables, or the m2cgen form's code: ModelSpec::evaluate; the logic around
// them is the same): a regressor per coordinate (of the correction to the physics
// localiser's position when residual_xy, as `impactsense train` fits them) and a binary classifier. With a
// twin (copied), twin_estimate() runs at the forests' position: the reported x, y are its matched position
// (the site map's grid points weighted by how well they explain the event's energies) and an energy
// classifier input kTwinInput reads its log10 height; the models then do not run (false) when the estimate
// fails (no usable channel, no map point near).
class TableModels : public Models {
 public:
  // three_channel (a model without a twin; nullptr: none): per channel c the energy class of a drop whose
  // channel c has no onset (dead, or left out by the core's channel_left_out), evaluated on
  // impactcore::three_channel_inputs (its inputs field unused); such a drop is reported at the physics
  // localiser's three-sensor position with c left out (the host's models.ImpactModel.predict).
  // check (with three_channel; copied): the channel check, whose flagged channel predict_event's three-sensor path
  // leaves out.
  // three_position (with three_channel; nullptr: none): [2 * kChannels] per channel c the pair (x at 2c, y at
  // 2c + 1) correcting the three-sensor position of a drop without c (boosted trees on
  // impactcore::three_position_inputs, their inputs field unused; a pair of 0 trees: none for that channel).
  TableModels(const ModelSpec& x, const ModelSpec& y, const ModelSpec& energy, bool residual_xy,
              const TwinSpec* twin = nullptr, const ModelSpec* three_channel = nullptr,
              const impactcore::ChannelCheck* check = nullptr, const ModelSpec* three_position = nullptr)
      : x_(x), y_(y), e_(energy), residual_(residual_xy), has_twin_(twin != nullptr),
        same_xy_inputs_(x.n_inputs == y.n_inputs && x.inputs != nullptr && y.inputs != nullptr &&
                        memcmp(x.inputs, y.inputs, static_cast<size_t>(x.n_inputs)) == 0),
        three_(three_channel), has_check_(check != nullptr && three_channel != nullptr && twin == nullptr),
        three_xy_(three_channel != nullptr && twin == nullptr ? three_position : nullptr) {
    if (twin != nullptr) twin_ = *twin;
    if (has_check_) check_ = *check;
  }
  bool predict(const impactcore::EventResult& ev, float* x_mm, float* y_mm, uint8_t* cls) const override;
  // With a twin the uncertainty is its matched position's calibrated 1-sigma (twin_uncertainty_mm).
  bool predict_with_uncertainty(const impactcore::EventResult& ev, float* x_mm, float* y_mm, uint8_t* cls,
                                float* uncertainty_mm) const override;
  // With a twin: impactcore::twin_match, i.e. when the forests cannot run because one channel has no onset,
  // the physics localiser's three-sensor position starts the twin on the other three channels; a channel
  // whose energies the twin cannot explain is left out (the host's models.ImpactModel.predict is the same).
  // Without a twin, a channel the check flags (flagged >= 0) on an event the forests could place: the physics
  // position without it (impactcore::three_sensor_position) and its three-channel class, the channel in *left_out
  // (the host's models.ImpactModel.predict, three_sensor_path); the forests do not run, unless the check's
  // four_channel_mask keeps the four channels' position on that channel (the host's flagged_position.py): then the
  // forests' position with the three-channel class, the channel in *left_out.
  bool predict_event(const impactcore::EventResult& ev, const impactcore::LocaliserConfig& loc, float* x_mm,
                     float* y_mm, uint8_t* cls, float* uncertainty_mm, int8_t* left_out, int flagged = -1,
                     const impactcore::CoreConfig* core = nullptr, int32_t* reason = nullptr) const override;
  const impactcore::ChannelCheck* channel_check() const override { return has_check_ ? &check_ : nullptr; }
  bool has_twin() const { return has_twin_; }
 private:
  bool predict_impl(const impactcore::EventResult& ev, const impactcore::LocaliserConfig* loc, float* x_mm,
                    float* y_mm, uint8_t* cls, float* uncertainty_mm, int8_t* left_out, int flagged = -1,
                    const impactcore::CoreConfig* core = nullptr, int32_t* reason = nullptr) const;
  bool three_sensor_path(const impactcore::EventResult& ev, const impactcore::LocaliserConfig& loc,
                         const impactcore::CoreConfig& core, int flagged, float* x_mm, float* y_mm, uint8_t* cls,
                         float* uncertainty_mm) const;
  // The three-sensor position (x, y) of a drop without channel c corrected by c's pair (three_xy_), if it has one
  // and its inputs are finite.
  void correct_three(const impactcore::EventResult& ev, int c, float* x_mm, float* y_mm) const;
  ModelSpec x_, y_, e_;
  bool residual_;
  bool has_twin_;
  bool same_xy_inputs_;  // the y forest reads the x forest's inputs (as `impactsense train` makes them): gathered once
  TwinSpec twin_{};
  const ModelSpec* three_;  // [impactcore::kChannels] or nullptr
  bool has_check_;
  impactcore::ChannelCheck check_{};
  const ModelSpec* three_xy_;  // [2 * impactcore::kChannels] or nullptr
};

// The board's acquisition as the core sees it: the rate, the SAADC scan order's capture delays (channel c
// is converted c * kScanStepUs after channel 0, so its sample k shows the wave that late: its onsets read
// early by that much, a capture delay of -c * kScanStepUs) and the ADC rails.
impactcore::CoreConfig board_acquisition(uint32_t fs_hz, int adc_min = 0, int adc_max = 4095);

// A model card's core configuration (trained at card.fs_hz) as the board runs it at fs_hz: sample counts
// scaled, the board's acquisition (impactcore::for_acquisition). The emulator calls this too.
inline impactcore::CoreConfig board_core_config(const impactcore::CoreConfig& card, uint32_t fs_hz,
                                                int adc_min = 0, int adc_max = 4095) {
  return impactcore::for_acquisition(card, board_acquisition(fs_hz, adc_min, adc_max));
}

struct AppConfig {
  uint32_t fs_hz = 50000;            // per channel
  float pretrigger_us = 1920.0f;     // 96 frames at 50 kHz
  float capture_us = 20480.0f;       // 1024 frames at 50 kHz (the ringing has decayed, n2 < 10 ms)
  float holdoff_us = 40000.0f;       // after a trigger, ignore the plate this long
  float quiet_us = 2000.0f;          // re-arm after all channels stayed below rearm_counts this long
  float threshold_counts = 60.0f;
  float rearm_counts = 20.0f;
  uint32_t status_period_ms = 1000;  // a status frame this often (sample clock); 0: none
  impactcore::CoreConfig core;       // the model card's; configure() sets the acquisition's fields (fs_hz,
                                     // capture_delay_us: board_acquisition)
  impactcore::LocaliserConfig loc;   // geometry, group velocity, Eq. 35 tolerances
  bool dump_raw = false;
};

class App {
 public:
  enum State { kWarmup, kListening, kCapturing };

  App(Hal& hal, const Models* models, const AppConfig& cfg = AppConfig());
  // Applies cfg (derived frame counts, core fs and scan delays). False if out of range (kept old).
  bool configure(const AppConfig& cfg);
  const AppConfig& config() const { return cfg_; }

  // Interleaved frames: data[4*i + c] is channel c of frame i (the SAADC scan order).
  void on_samples(const int16_t* data, int n_frames);
  // Bytes from the host: commands.
  void on_rx(const uint8_t* data, size_t n);
  // Outside acquisition (the board's loop(), when no buffer waits): emits the pending raw dump as far as the
  // transmit queue has room, and hands queued bytes to Hal::write within Hal::writable(). True while it made
  // progress (call again).
  bool service();
  // Acquisition buffers the board lost (its DMA ring overran): counted in the status frame.
  void add_overruns(uint32_t n) { overruns_ += n; }

  // Processes the capture in capture_ now (called by on_samples; public for the tests and the bench).
  void process_capture();

  State state() const { return state_; }
  uint32_t events() const { return seq_; }
  uint32_t overruns() const { return overruns_; }
  // The trigger threshold in use (counts): the largest channel's noise-tracked threshold once armed
  // (impactcore::Trigger::threshold, at least the configured threshold_counts), the configured one before.
  float trigger_threshold() const { return state_ == kWarmup ? cfg_.threshold_counts : trigger_.threshold(); }
  const impactlink::Status& status() const { return status_; }  // the last status frame sent
  uint32_t event_cycles_max() const { return event_cycles_max_; }
  uint32_t idle_cycles_max() const { return idle_cycles_max_; }  // since the last status frame
  int capture_frames() const { return capture_frames_; }
  int pretrigger_frames() const { return pre_frames_; }
  const int16_t* capture(int c) const { return capture_[c]; }
  const impactcore::EventResult& last_result() const { return ev_; }
  const impactlink::Report& last_report() const { return report_; }
  const impactlink::DecoderStats& rx_stats() const { return rx_.stats(); }

 private:
  void handle_command(const impactlink::Frame& f);
  void send_ack(uint8_t command, uint8_t status);
  void emit(size_t n);              // queues tx_[0..n) as one frame
  void send_report();
  void send_raw_chunk();            // the next raw chunk of the capture (raw_ch_ < 4)
  void finish_raw(bool dropped);    // the report held back by a raw dump goes out
  void send_status();
  void account_buffer(uint32_t cycles, int n_frames, bool had_event);
  void restart();

  Hal& hal_;
  const Models* models_;
  AppConfig cfg_;
  impactcore::TriggerConfig trig_cfg_;
  impactcore::Trigger trigger_;
  State state_ = kWarmup;
  int pre_frames_ = 96, capture_frames_ = 1024;
  int16_t ring_[kMaxPretrigger][4];
  int ring_pos_ = 0, ring_fill_ = 0;
  int16_t capture_[4][kMaxCapture];
  int cap_pos_ = 0;
  uint64_t frame_count_ = 0, trigger_frame_ = 0;
  uint32_t seq_ = 0, overruns_ = 0;
  // raw dump in progress (channel, offset) and the report it holds back
  bool raw_pending_ = false;
  int raw_ch_ = 0, raw_off_ = 0;
  uint16_t raw_dropped_ = 0;
  // status accounting
  uint64_t next_status_frame_ = 0;
  uint32_t buffers_ = 0, dropped_reports_ = 0;
  uint32_t event_cycles_last_ = 0, event_cycles_max_ = 0, event_cycles_in_buffer_ = 0;
  uint32_t idle_buffers_ = 0, idle_cycles_max_ = 0;
  uint64_t idle_cycles_sum_ = 0, idle_frames_sum_ = 0;
  impactlink::Status status_{};
  TxQueue<kTxQueueBytes> txq_;
  impactcore::EventResult ev_;
  // The channel check's scores of the last events (oldest first; impactcore::channel_check_flag's window).
  float check_scores_[impactcore::kMaxCheckEvents][impactcore::kChannels];
  int check_rows_ = 0;
  int check_event(int32_t status);  // pushes this event's scores; the channel the check flags (-1: none)
  impactlink::Report report_;
  uint8_t tx_[impactlink::kMaxFrame];
  impactlink::Decoder rx_;
  impactlink::Frame rx_frame_;
};

}  // namespace impactapp
