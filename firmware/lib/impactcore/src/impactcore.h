// impactcore: the portable signal core of impactsense.
//
// One implementation, compiled for the board (Cortex-M4F, float32, no heap) and bound to Python for the
// host. Everything the trainer computes from a recording and everything the firmware computes from a
// capture goes through these functions.
//
// Data path: raw ADC capture (int16 counts, channel-major) -> baseline removal -> per-channel onset (ToA)
// -> ToA order, DToA, Eq. 35 acceptance -> energy features -> feature vector -> models.
//
// Units are in the names: _us microseconds, _mm millimetres, _hz hertz; samples are plain ints/floats.
#pragma once

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#if defined(__ARM_FEATURE_SIMD32)
#include <arm_acle.h>
#endif

namespace impactcore {

constexpr int kChannels = 4;
constexpr int kPairs = 6;            // sensor pairs (0,1) (0,2) (0,3) (1,2) (1,3) (2,3)
constexpr int kMaxSamples = 8192;    // longest capture per channel the core accepts
constexpr int kEnergyWindows = 5;    // windows between ToA and n2 (docs/method.md, Fig. 8 of the seed)
constexpr int kDiffOrders = 3;       // difference energies sum (Delta^k x)^2, k = 1..3, from ToA to n2
constexpr int kMaxAicWindow = 512;   // samples in the AIC refinement window (stack scratch)

// The pair order used for every DToA vector: DToA_ij = ToA_i - ToA_j.
extern const uint8_t kPairI[kPairs];
extern const uint8_t kPairJ[kPairs];

// Status codes, once: X(code, enumerator, key, text). 1..15 the core's (a function's result); 16.. the app's
// (impactapp): why the models gave no position and class for an event the core processed. A report that is not
// valid carries one of them (impactlink's report `reason`); the host reads key and text through the binding
// (_core.STATUS_KEYS, status_name), so this list is the only copy. Codes are wire values: never renumber one.
#define IMPACTCORE_STATUS(X)                                                                                 \
  X(0, kOk, "ok", "ok")                                                                                      \
  X(1, kErrNullInput, "null_input", "null input")                                                            \
  X(2, kErrTooManySamples, "too_many_samples", "capture longer than kMaxSamples")                            \
  X(3, kErrTooFewSamples, "too_few_samples", "capture shorter than the baseline segment")                    \
  X(4, kErrBadConfig, "bad_config", "invalid configuration")                                                 \
  X(5, kErrNoTrigger, "no_trigger", "no channel crossed the onset threshold")                                  \
  X(6, kErrSingular, "singular", "degenerate geometry")                                                      \
  X(16, kErrNoModels, "no_models", "no models loaded")                                                       \
  X(17, kErrChannelsMissing, "channels_missing",                                                             \
    "two or more channels without an onset (dead, silent or left out): too few for the models")              \
  X(18, kErrChannelMissing, "channel_missing",                                                               \
    "a channel without an onset (dead, silent or left out) and no three-channel path in the models")         \
  X(19, kErrLocaliser, "localiser_failed", "the physics localiser could not place the drop")                 \
  X(20, kErrClipped, "clipped", "every channel with an onset clipped: no energies for the twin")             \
  X(21, kErrTwinNoMatch, "twin_no_match", "the twin's site map has no match for the drop's energies")        \
  X(22, kErrNotFinite, "not_finite", "a model input is not finite")

#define IMPACTCORE_STATUS_ENUM(code, name, key, text) name = code,
enum Status : int32_t { IMPACTCORE_STATUS(IMPACTCORE_STATUS_ENUM) };
#undef IMPACTCORE_STATUS_ENUM
const char* status_name(int32_t status);  // the text ("unknown status" for a code not listed)
const char* status_key(int32_t status);   // the key ("unknown")

// Flags per channel (bit field).
enum ChannelFlag : uint8_t {
  kFlagClipped = 1u << 0,   // a sample at/after the onset reached the ADC rail
  kFlagDead = 1u << 1,      // no signal above the noise floor (or a flat line)
  kFlagNoOnset = 1u << 2,   // the channel never crossed its onset threshold
  kFlagAicFallback = 1u << 3,  // AIC refinement failed; threshold pick kept
  kFlagHum = 1u << 4,       // a mains hum was fitted and removed (ChannelFeatures.hum_counts)
  kFlagGlitch = 1u << 5,    // a 1-2 sample spike was found and left out (baseline, onset or energies)
  kFlagInconsistent = 1u << 6,  // the models left it out: its energies disagree with the other channels'
                                // (a debonded or cracked disc; the host's twin check, models.py)
};

// --- configuration: every field, its type, default and board role, declared once ---
//
// IMPACTCORE_CONFIG_FIELDS(X) and IMPACTCORE_LOCALISER_FIELDS(X) list the fields of CoreConfig and
// LocaliserConfig as X(kind, type, name, default, role). The structs below, the Python binding
// (host/bindings/core_bindings.cpp: attributes and the field tables CORE_CONFIG_FIELDS /
// LOCALISER_CONFIG_FIELDS) and, through them, the host's SignalConfig, model cards and the C the exporter
// writes for the board (impactsense_signal_config, copied by impactapp::exported_config) all expand these
// lists: adding a field is one line here.
//   kind    ONE (a scalar) or PER_CHANNEL (kChannels values; default is a parenthesised list)
//   type    float or int
//   role    how the board takes the field from a model card trained at another sample rate:
//           RATE       the sample rate itself (the card's is the training rate; the board runs its own)
//           ACQUISITION set by the acquisition that made the samples (ADC rails, capture delays), not by
//                      the card
//           SAMPLES    a sample count at the training rate, scaled to the board's rate
//           COPY       taken as is
#define IMPACTCORE_CONFIG_FIELDS(X)                                                                      \
  X(ONE, float, fs_hz, 100000.0f, RATE)  /* per-channel sample rate */                                 \
  X(PER_CHANNEL, float, rig_delay_us, (0.0f, 0.0f, 0.0f, 0.0f), COPY) /* what the rig does: a channel \
    whose wave shows d us late (sensor, wiring) has d > 0; removed from the ToA */                        \
  X(PER_CHANNEL, float, capture_delay_us, (0.0f, 0.0f, 0.0f, 0.0f), ACQUISITION) /* what the           \
    acquisition does (the board's SAADC reads channel c c x 5 us late: -5c); removed from the ToA too */  \
  X(PER_CHANNEL, float, channel_gain, (1.0f, 1.0f, 1.0f, 1.0f), COPY) /* sensor/front-end gain g:       \
    amplitudes / g, energies / g^2, onset threshold x g */                                               \
  X(PER_CHANNEL, float, bond_corner_hz, (0.0f, 0.0f, 0.0f, 0.0f), COPY) /* a debonded disc's one-pole  \
    low-pass (corner fc, gain g), undone before picking: the channel through (1 + jf/fc) / (g (1 + jf/f2)) \
    (bond_inverse.cpp); 0: off (the samples as captured, bit for bit) */                                \
  X(PER_CHANNEL, float, bond_gain, (1.0f, 1.0f, 1.0f, 1.0f), COPY) /* ... g (> 0; the channel_gain is then 1) */ \
  X(PER_CHANNEL, float, bond_limit_hz, (0.0f, 0.0f, 0.0f, 0.0f), COPY) /* ... f2 > fc: the inverse's lift stops \
    there (the noise it amplifies) */                                                                   \
  X(ONE, int, baseline_samples, 64, COPY)  /* samples at the capture start for baseline and noise */   \
  X(ONE, float, onset_threshold_counts, 10.0f, COPY)  /* |x| above baseline: a channel's arrival */     \
  X(ONE, float, onset_noise_factor, 5.0f, COPY)  /* ... or this many noise RMS, whichever is larger */  \
  X(ONE, int, aic_before, 60, SAMPLES)  /* AIC window: samples before the threshold crossing */          \
  X(ONE, int, aic_after, 12, SAMPLES)  /* ... and after it */                                           \
  X(ONE, float, aic_blend, 0.35f, COPY)  /* 0: ToA = threshold crossing; 1: sub-sample AIC onset */    \
  X(ONE, int, adc_min, 0, ACQUISITION)  /* rails for clipping detection (counts) */                     \
  X(ONE, int, adc_max, 4095, ACQUISITION)                                                               \
  X(ONE, int, sample_offset, 0, ACQUISITION)  /* counts the host took off every sample to fit int16 (a  \
    16-bit logger re-centred by half its range; adc_min/adc_max are after it); 0 on the board */        \
  X(ONE, int, record_start, 0, ACQUISITION)  /* samples of a logger's record longer than kMaxSamples   \
    the host left out before the capture (its window near the first arrival); 0 on the board */          \
  X(ONE, float, dead_rms_counts, 3.0f, COPY)  /* post-onset RMS below this: the channel is dead */      \
  X(ONE, float, hum_min_counts, 4.0f, COPY)  /* a mains hum is modelled from this amplitude (and twice  \
    the noise floor, four standard errors of the fit) */                                                  \
  X(ONE, float, n2_fraction, 0.99f, COPY)  /* n2: cumulative energy reaches this fraction */            \
  X(ONE, float, diff_window_us, 2500.0f, COPY)  /* difference energies: ToA .. min(n2, ToA + this);     \
    0 = up to n2 */                                                                                       \
  X(ONE, float, band_pick_hz, 0.0f, COPY)  /* band pick (band_onset) at this frequency; 0: off */         \
  X(ONE, float, band_pick_fraction, 0.1f, COPY)  /* ... where its envelope reaches this of its peak */    \
  X(ONE, float, band_window_us, 600.0f, COPY)  /* ... peak sought up to this after the first onset */     \
  X(ONE, float, band_noise_counts, 0.0f, COPY)  /* ... floor: kBandNoiseFactor x this noise rms (the     \
    training drops'; kBandEnvFactor x the envelope's noise if higher); 0: x the channel's noise_rms */    \
  X(PER_CHANNEL, int, channel_left_out, (0, 0, 0, 0), COPY)  /* 1: the channel is not used (a change the  \
    models cannot absorb, e.g. a debonded disc): no onset, as a dead channel (three-sensor models) */

#define IMPACTCORE_LOCALISER_FIELDS(X)                                                                   \
  X(ONE, float, velocity_mm_per_us, 0.93f, COPY)  /* fitted group velocity of the picked arrival */     \
  X(ONE, float, sigma_us, 2.0f, COPY)  /* ToA uncertainty for the covariance */                         \
  X(ONE, float, huber_us, 4.0f, COPY)  /* robust-loss threshold */                                      \
  X(PER_CHANNEL, float, sensor_x_mm, (30.0f, 290.0f, 290.0f, 30.0f), COPY)                               \
  X(PER_CHANNEL, float, sensor_y_mm, (33.0f, 33.0f, 284.0f, 284.0f), COPY)                               \
  X(ONE, float, plate_x_mm, 320.0f, COPY)                                                               \
  X(ONE, float, plate_y_mm, 317.0f, COPY)                                                               \
  X(ONE, float, accept_tol_us, 5.0f, COPY)  /* acceptance rule: tolerance on ToA */                     \
  X(ONE, float, accept_margin_mm, 10.0f, COPY)  /* ... only pairs whose distances differ this much */     \
  X(ONE, float, travel_metric_xx, 1.0f, COPY)  /* travel time = sqrt(d^T Q d) / v: Q of an anisotropic */  \
  X(ONE, float, travel_metric_xy, 0.0f, COPY)  /* plate (elliptical wavefronts; identity = isotropic,  */  \
  X(ONE, float, travel_metric_yy, 1.0f, COPY)  /* bit for bit the Euclidean localiser)                 */  \
  X(ONE, float, dispersion_exponent, 0.0f, COPY)  /* a channel's slowness x (f / dispersion_ref_hz)^-this,*/ \
  X(ONE, float, dispersion_ref_hz, 25000.0f, COPY) /* f = fs / pick_period (0: one velocity, bit for bit) */ \
  X(ONE, int, localiser_starts, 1, COPY)  /* screened starts the localiser refines (1 .. kMaxStarts) */  \
  X(ONE, int, posterior_grid, 0, COPY)  /* > 1: the position is the posterior mean over this many x this  */ \
    /* many points around the fit (localise_tdoa); 0: the Huber fit itself, bit for bit */                  \
  X(ONE, float, band_velocity_mm_per_us, 0.0f, COPY)  /* the band picks' own travel model; > 0 (and   */ \
  X(PER_CHANNEL, float, band_delay_us, (0.0f, 0.0f, 0.0f, 0.0f), COPY) /* band_pick_hz > 0): the   */ \
  X(ONE, float, band_metric_xx, 1.0f, COPY)  /* physics position is the mean of the threshold picks' */   \
  X(ONE, float, band_metric_xy, 0.0f, COPY)  /* and the band picks' (process_event)                   */   \
  X(ONE, float, band_metric_yy, 1.0f, COPY)                                                          \
  X(ONE, float, band_slowness_per_decade, 0.0f, COPY)  /* the band localiser's slowness 1 / v_band +   */ \
  X(ONE, float, band_log_energy_ref, 0.0f, COPY)  /* this x (log10 E - ref), E the channels' summed     */ \
    /* energy over fs (counts^2 s): louder drops' band picks travel faster; 0: one velocity, bit for bit */ \
  X(ONE, int, localiser_evaluation_cap, 0, COPY)  /* a start's normal-equation evaluations (1 .. 16): more  */ \
    /* starts within one start's bound on the board; 0: localise_tdoa's cap of 16, bit for bit          */

#define IMPACTCORE_UNPAREN(...) __VA_ARGS__
#define IMPACTCORE_DECLARE_ONE(type, name, def) type name = def;
#define IMPACTCORE_DECLARE_PER_CHANNEL(type, name, def) type name[kChannels] = {IMPACTCORE_UNPAREN def};
#define IMPACTCORE_DECLARE(kind, type, name, def, role) IMPACTCORE_DECLARE_##kind(type, name, def)

struct CoreConfig {
  IMPACTCORE_CONFIG_FIELDS(IMPACTCORE_DECLARE)
};

// The delay the core removes from channel c's ToA: the rig's plus the acquisition's.
inline float channel_delay_us(const CoreConfig& cfg, int c) { return cfg.rig_delay_us[c] + cfg.capture_delay_us[c]; }

// A model card's configuration (trained at card.fs_hz) as an acquisition at another rate runs it: the
// acquisition's RATE and ACQUISITION fields, the card's SAMPLES fields scaled by the rates' ratio (rounded),
// the card's COPY fields as they are. The one place a configuration changes rate (board, emulator).
inline CoreConfig for_acquisition(const CoreConfig& card, const CoreConfig& acquisition) {
  CoreConfig out = acquisition;
  const float scale = acquisition.fs_hz / card.fs_hz;
#define IMPACTCORE_TAKE_RATE(name)
#define IMPACTCORE_TAKE_ACQUISITION(name)
#define IMPACTCORE_TAKE_SAMPLES(name) out.name = static_cast<int>(card.name * scale + 0.5f);
#define IMPACTCORE_TAKE_COPY(name) memcpy(&out.name, &card.name, sizeof(out.name));
#define IMPACTCORE_TAKE(kind, type, name, def, role) IMPACTCORE_TAKE_##role(name)
  IMPACTCORE_CONFIG_FIELDS(IMPACTCORE_TAKE)
#undef IMPACTCORE_TAKE
#undef IMPACTCORE_TAKE_COPY
#undef IMPACTCORE_TAKE_SAMPLES
#undef IMPACTCORE_TAKE_ACQUISITION
#undef IMPACTCORE_TAKE_RATE
  return out;
}

struct ChannelFeatures {
  float baseline;          // counts
  float noise_rms;         // counts, from the baseline segment
  float toa_threshold;     // sub-sample threshold crossing (samples from capture start, delay not removed)
  float toa_aic;           // AIC onset (samples)
  float toa_us;            // final ToA in microseconds, channel delay removed
  float peak;              // max |x| after baseline removal, divided by the channel gain (counts)
  float first_peak;        // |x| of the first extremum after the onset, divided by the gain (counts)
  float pick_period;       // samples: period of the oscillation the onset caught (pick_period()); NaN if none
  float energy;            // sum of x^2 over the capture, divided by the gain squared (counts^2)
  float window_energy[kEnergyWindows];  // energy in five equal windows from ToA to n2
  float residual_ratio;    // window_energy[4] / energy
  // sum over [ToA, min(n2, ToA + diff_window_us)] of (Delta^k x)^2 for k = 1, 2, 3 (Delta x[i] = x[i] - x[i-1]), divided by the gain
  // squared (counts^2). By Parseval these are the spectral moments of the arrival, weighted by
  // (2 sin(pi f / fs))^(2k): they carry how much high-frequency energy the contact put in, which grows
  // faster with the impact speed than the total and is less coloured by the plate's modes at the site.
  // Less the white noise floor's expected share, C(2k, k) noise_rms^2 a sample (floored at 0).
  float diff_energy[kDiffOrders];
  int32_t n2;              // sample where the cumulative energy stops growing
  float hum_counts;        // amplitude of the fitted mains hum (counts; 0 when none was modelled)
  uint8_t flags;           // ChannelFlag bits
  float toa_band_us;       // band_onset in us, the capture delay removed (not the rig's); NaN: off or too weak
};

struct EventFeatures {
  ChannelFeatures ch[kChannels];
  float dtoa_us[kPairs];   // ToA_i - ToA_j in kPair order
  uint8_t order[kChannels];  // channel indices sorted by ToA (first arrival first)
  int32_t status;
};

// --- the bond inverse (bond_inverse.cpp): a debonded disc's one-pole low-pass undone before picking ---
// At most this many channels at once (one span's buffer each: kBondSpanMax int16).
constexpr int kMaxBondChannels = 1;
// The bonded channel is filtered and read only on its span [0, E) (docs/method.md "Bond inverse"):
// E = anchor + kBondReach x the difference window (diff_window_us, in samples) + aic_after (at least the band
// window band_window_us after the anchor when band_pick_hz > 0), the anchor the other channels' first threshold
// crossing; E at most n and kBondSpanMax (the buffer), and the whole kBondSpanMax when the difference window
// is off or no other channel has an onset.
constexpr int kBondReach = 2;
constexpr int kBondSpanMax = 2048;
// The span's end E for a capture of n samples whose other channels first cross the threshold at `anchor`
// (sample index; < 0: none has an onset).
int bond_span_end(const CoreConfig& cfg, int n, float anchor);
// True when channel c's bond inverse is on (bond_corner_hz > 0).
inline bool bond_inverse_on(const CoreConfig& cfg, int c) { return cfg.bond_corner_hz[c] > 0.0f; }
// kOk, or kErrBadConfig when an inverse's fields are out of range (corner, limit or gain not finite and
// positive, limit not above the corner, or more than kMaxBondChannels channels on).
int32_t check_bond_inverse(const CoreConfig& cfg);
// out[i] = x[0] + y[i], y the bilinear (Tustin, fs = cfg.fs_hz) discretisation of
// H(s) = (1 + s / wc) / (g (1 + s / w2)) applied to x[i] - x[0] (y[0] = 0), rounded to the nearest count (halves up) and
// held inside [adc_min, adc_max] (int16's range when adc_max <= adc_min). Single-precision, in a fixed
// order: host and board agree bit for bit.
void bond_inverse(const int16_t* x, int n, float fc_hz, float gain, float f2_hz, const CoreConfig& cfg,
                  int16_t* out);

// Per-channel feature extraction over one capture. `adc[c]` points at n samples of channel c.
// One integer pass per channel (block_prefix_sums); everything else reads those sums and touches only the
// few blocks it needs (see features.cpp). Stack: one prefix table (kMaxBlocks + 1 Sums, 8.2 KB) at a time.
// Design, cost and accuracy: firmware/lib/impactapp/README.md, "Per-event budget".
int32_t extract_features(const int16_t* const adc[kChannels], int n, const CoreConfig& cfg,
                         EventFeatures* out);

// --- exact block sums: the one pass over a channel ---
//
// Every energy the core reports is a sum over a range of samples of (x - b)^2, b the baseline. With the
// integer sums S1 = sum x and S2 = sum x^2 of the range, that is exact algebra:
//   n_b^2 * sum (x - b)^2 = n_b^2 S2 - 2 n_b B S1 + m B^2      (b = B / n_b, m samples in the range)
// evaluated in int64 (scaled_energy), so host and board agree bit for bit whatever the summation order.
// The capture is summed once, in blocks of kBlock samples; a range [a, b) costs the prefix difference plus
// at most kBlock - 1 samples at each end. To add a statistic (say sum (x[i] - x[i-1])^2 for a spectral
// moment): one field in Sums, one line in add_sample() and in the DSP kernel (sums.cpp), and it has
// exact range sums everywhere for free.
constexpr int kBlock = 16;
constexpr int kMaxBlocks = (kMaxSamples + kBlock - 1) / kBlock;
// The baseline segment length is bounded so the scaled energies fit int64 for any int16 input:
// n_b^2 S2 <= 2^16 * 2^13 * 2^30 = 2^59, 2 n_b B S1 <= 2^60, m B^2 <= 2^59.
constexpr int kMaxBaselineSamples = 256;

struct Sums {
  int64_t s2;  // sum x^2
  int32_t s1;  // sum x
};

// prefix[k] = sums over x[0 .. min(k kBlock, n)) for k = 0 .. ceil(n / kBlock); returns ceil(n / kBlock).
int block_prefix_sums(const int16_t* x, int n, Sums* prefix);
// Sums over x[0 .. i) from the prefix table of x[0 .. n) (0 <= i <= n): the nearer block boundary's sums
// plus or minus the samples in between (at most kBlock / 2).
Sums prefix_at_partial(const int16_t* x, const Sums* prefix, int n, int i);
inline Sums prefix_at(const int16_t* x, const Sums* prefix, int n, int i) {
  // On a block boundary the table holds the sums (i <= n): no call, no loop (the baseline's parts).
  return (i & (kBlock - 1)) == 0 ? prefix[i / kBlock] : prefix_at_partial(x, prefix, n, i);
}
// sum x[a .. b) (|sum| < 2^31: b - a <= 65536), two samples an instruction on the DSP extension.
int32_t range_sum(const int16_t* x, int a, int b);
// Smallest and largest sample of x[a .. b) (b > a): exact integers, two samples an instruction pair on
// the DSP extension (SSUB16 + SEL), a plain loop elsewhere.
void range_extremes(const int16_t* x, int a, int b, int32_t* lo, int32_t* hi);
#if defined(__ARM_FEATURE_SIMD32)
// A running max and min of int16 pairs: SSUB16 sets each half's GE flags where the (full-precision)
// difference is >= 0, SEL then takes that half from its first operand (unaligned word loads: the M4).
struct PairExtremes {
  int16x2_t mx, mn;
  __attribute__((always_inline)) explicit PairExtremes(const int16_t* p) {
    int32_t w;
    memcpy(&w, p, sizeof(w));
    mx = mn = w;
  }
  __attribute__((always_inline)) void add(const int16_t* p) {
    int32_t w;
    memcpy(&w, p, sizeof(w));
    __ssub16(w, mx);
    mx = __sel(w, mx);
    __ssub16(mn, w);
    mn = __sel(w, mn);
  }
  __attribute__((always_inline)) void get(int32_t* lo, int32_t* hi) const {
    const int32_t mx0 = static_cast<int16_t>(mx & 0xFFFF), mx1 = static_cast<int16_t>(mx >> 16);
    const int32_t mn0 = static_cast<int16_t>(mn & 0xFFFF), mn1 = static_cast<int16_t>(mn >> 16);
    *hi = mx0 > mx1 ? mx0 : mx1;
    *lo = mn0 < mn1 ? mn0 : mn1;
  }
};
#endif
// range_extremes of the kBlock samples at b, inline (unrolled, without the call and range set-up).
__attribute__((always_inline)) inline void block_extremes(const int16_t* b, int32_t* lo, int32_t* hi) {
#if defined(__ARM_FEATURE_SIMD32)
  PairExtremes e(b);
#pragma GCC unroll 8
  for (int j = 2; j < kBlock; j += 2) e.add(b + j);
  e.get(lo, hi);
#else
  range_extremes(b, 0, kBlock, lo, hi);
#endif
}
// n_b^2 * sum over a range of m samples of (x - sum_b / n_b)^2, exact (see above).
int64_t scaled_energy(const Sums& range, int m, int n_b, int32_t sum_b);

// sum over i in [a, b) of (Delta^k x[i])^2 for k = 1 .. kDiffOrders, exact in int64 (needs a >= kDiffOrders: the products reach back to x[a - 3]).
void difference_energies(const int16_t* x, int a, int b, int64_t out[kDiffOrders]);

// --- the baseline: level, noise floor and mains hum (baseline.cpp) ---
//
// A capture's baseline is a level plus, when the lab's mains couples in, a hum: b(i) = level + c0 +
// c1 cos(w i) + c2 sin(w i), i the sample index, w = 2 pi f_mains / fs with f_mains 50 or 60 Hz (whichever
// fits better). The level and the noise floor come from the baseline segment (the capture's first
// baseline_samples) in four parts, leaving out a part whose variance about its own mean stands out (a
// glitch there). The hum is fitted by weighted least squares to the means of groups of kHumGroupBlocks
// blocks over the whole capture, each weighted by 1 / (its variance about its mean + the noise floor^2):
// the plate's ringing has a zero mean and a large variance, so the quiet stretches before the arrival
// and the rung-down tail set the fit. It is used (hum = 1) only when its amplitude reaches hum_min_counts
// (a config field: counts of the reference logger, scaled by the host to the rig's ADC as the onset
// threshold is) and twice the noise floor, so a clean capture keeps the plain level.
constexpr float kMainsHz[2] = {50.0f, 60.0f};
constexpr int kHumGroupBlocks = 8;

struct Baseline {
  float level;        // counts: mean of the kept baseline parts
  float noise_rms;    // rms about that mean over the kept parts
  float within_rms;   // rms about each part's own mean (a hum's slope barely enters it)
  Sums kept;          // sums of the kept baseline samples ...
  int32_t kept_n;     // ... and how many
  int32_t glitch_parts;  // baseline parts left out (bit p: part p)
  float hum_hz;       // the better-fitting mains frequency (0: too few groups to fit)
  float hum_amp;      // sqrt(c1^2 + c2^2), counts
  float c0, c1, c2;   // the model above (c0: the hum fit's own offset from the level)
  float w;            // rad per sample
  uint8_t hum;        // the hum is modelled
};
// What the hum path needs of the sample rate alone (9 sin_cos a mains frequency), computed once per rate:
// set(fs) fills it, fit_baseline calls set when fs_hz differs (a fresh HumBasis{} has fs_hz 0).
// extract_features keeps one for the thread (the board: one), so events at one rate share it, and so do
// their hum channels: the block rotations and a block mean's gain the onset scan and the energies about
// the model step by (the same floats as a sin_cos of each argument per channel).
struct HumBasis {
  float fs_hz = 0.0f;
  float w[2] = {}, rot_c[2] = {}, rot_s[2] = {}, cg0[2] = {}, sg0[2] = {},
        gain[2] = {};  // per kMainsHz: rad/sample, a group's rotation, group 0's phase, a group mean's gain
  // per kMainsHz, a block's: rotation by w kBlock, by w (kBlock - 1), by w (kBlock - 1) / 2, and the mean of
  // a unit sinusoid over it (HumSteps, HumEnergy in features.cpp)
  float blk_rc[2] = {}, blk_rs[2] = {}, blk_lc[2] = {}, blk_ls[2] = {}, blk_mc[2] = {}, blk_ms[2] = {},
        blk_gain[2] = {};
  // 1 + the kMainsHz index of the event's mains (0: none yet; extract_features resets it each event; 0 keeps the
  // board's static basis out of initialised data): the first modelled hum whose fit tells 50 from 60 Hz sets it;
  // one mains feeds every channel, so a later channel fits that frequency alone
  int event_mains = 0;
  void set(float fs);
  // the kMainsHz index of a fitted hum's w (w[0] or w[1])
  int index(float w_hum) const { return w_hum == w[1] ? 1 : 0; }
};
// When a cheap bound on the fit rules the hum out (most clean captures), hum_hz, hum_amp, c0..c2 and w
// stay 0 (they are read only when hum = 1). basis->event_mains > 0: only that mains frequency is fitted;
// a modelled hum whose fit tells the two frequencies apart sets it when it is 0.
void fit_baseline(const int16_t* x, int n, const Sums* prefix, int baseline_samples, float fs_hz,
                  float hum_min_counts, HumBasis* basis, Baseline* out);
// The noise floor of a hum channel (hum = 1): the kept baseline parts' rms about each part's own straight
// line (a hum's slope at the part's phase taken out whatever the model's amplitude there), floored at
// 0.1 x within_rms^2. Reads the baseline segment's samples again (a hum channel only).
float hum_noise_rms(const int16_t* x, const Baseline& b, int baseline_samples);
// sin and cos of a (|error| < 1e-6; no libm).
void sin_cos(float a, float* s, float* c);
// The model's departure from the level at sample i: c0 + c1 cos(w i) + c2 sin(w i) (0 without hum).
inline float hum_at(const Baseline& b, float i) {
  if (!b.hum) return 0.0f;
  float s, c;
  sin_cos(b.w * i, &s, &c);
  return b.c0 + b.c1 * c + b.c2 * s;
}

// --- pickers: plain functions of a buffer (vallenae style) ---

// Mean and RMS deviation of x[0..n), from exact integer sums (0 < n <= kMaxBaselineSamples for exactness).
void baseline_stats(const int16_t* x, int n, float* mean, float* rms);
// The same from the sums of the n samples (what extract_features uses).
void baseline_from_sums(const Sums& s, int n, float* mean, float* rms);

// log2 of a positive normal float to float precision (exponent + atanh series on the mantissa; |error|
// <= 1.1e-6 up to 1e9, the rounding of the result): the AIC picker's
// log, no libm call (logf is ~80 instructions on the M4F, this ~20 inlined).
#if defined(__GNUC__)
__attribute__((always_inline))
#endif
inline float fast_log2(float v) {
  // v = 2^e m, m in [sqrt(1/2), sqrt(2)); ln m = 2 atanh(s) = 2 (s + s^3/3 + s^5/5 + s^7/7) + O(s^9),
  // s = (m - 1) / (m + 1), |s| <= 0.172: the truncation is below 5e-8 (in log2 units).
  // e = floor(log2(v / sqrt(1/2))) straight from the bits (0x3F3504F3 is sqrt(1/2)); m = v / 2^e.
  int32_t u;
  memcpy(&u, &v, sizeof(u));
  const int32_t e = (u - 0x3F3504F3) >> 23;
  u -= static_cast<int32_t>(static_cast<uint32_t>(e) << 23);
  float m;
  memcpy(&m, &u, sizeof(m));
  const float s = (m - 1.0f) / (m + 1.0f);
  const float s2 = s * s;
  const float p = 1.0f + s2 * (1.0f / 3.0f + s2 * (1.0f / 5.0f + s2 * (1.0f / 7.0f)));
  return static_cast<float>(e) + (2.0f / 0.693147181f) * s * p;
}

// exp(x) for x <= 0 (the twin's weights, the localiser's posterior mean), within 2 ulp of expf where it matters (x > -87; 0 below): 2^n 2^f with n the nearest
// integer to x log2(e) and a degree-6 polynomial for 2^f on [-1/2, 1/2] (Chebyshev interpolation). About a
// fifth of newlib's expf on the Cortex-M4F (no errno, no double). The rounding of x log2(e) moves exp(x) by
// at most ~|x| 6e-8 relative, i.e. by < 3e-8 of the largest weight (1) for any x: float rounding of the sums.
// Always inlined: under -Os GCC keeps one out-of-line copy once a unit has several callers (twin.cpp's
// matches), and the call costs more than the function's ~30 instructions save in flash per weight.
#if defined(__GNUC__)
__attribute__((always_inline))
#endif
inline float exp_nonpositive(float x) {
  if (!(x > -87.0f)) return 0.0f;
  const float t = x * 1.44269504f;
  const int n = static_cast<int>(t - 0.5f);  // round to nearest (t <= 0: truncation is toward zero)
  const float f = t - static_cast<float>(n);
  float p = 1.546144472e-4f;
  p = p * f + 1.340042818e-3f;
  p = p * f + 9.618056678e-3f;
  p = p * f + 5.550327227e-2f;
  p = p * f + 2.402265092e-1f;
  p = p * f + 6.931472067e-1f;
  p = p * f + 1.0f;
  const uint32_t bits = static_cast<uint32_t>(n + 127) << 23;  // 2^n, n >= -126
  float scale;
  memcpy(&scale, &bits, sizeof(scale));
  return p * scale;
}

// sqrt of a float >= 0: the FPU's VSQRT on the M4F (the same IEEE result; newlib's sqrtf adds an errno
// check and two calls).
inline float vsqrt_f32(float v) {
#if defined(__ARM_FP) && (__ARM_FP & 4) && defined(__thumb2__)
  float r;
  __asm__("vsqrt.f32 %0, %1" : "=t"(r) : "t"(v));
  return r;
#else
  return sqrtf(v);
#endif
}

// float(v) for an int64: VCVT from 32 bits when v fits them (the same round-to-nearest result), else
// libgcc's 64-bit conversion (~28 instructions on the M4F).
inline float int64_to_float(int64_t v) {
  if (v >= INT32_MIN && v <= INT32_MAX) return static_cast<float>(static_cast<int32_t>(v));
  return static_cast<float>(v);
}

// floorf(v) and ceilf(v) as int32 for |v| < 2^31 (no libm call): the truncation, corrected by one.
inline int32_t floor_to_int(float v) {
  const int32_t t = static_cast<int32_t>(v);
  return static_cast<float>(t) > v ? t - 1 : t;
}
inline int32_t ceil_to_int(float v) {
  const int32_t t = static_cast<int32_t>(v);
  return static_cast<float>(t) < v ? t + 1 : t;
}

// A crossing at sample i (|x[i] - b| >= thr, x[i - 1] below) is a transient, not an arrival, when the
// excursion is over within two samples and the kTransientQuiet samples after it stay below the
// threshold, and either it reached kGlitchRatio x the threshold (a glitch: a spike of any size) or those
// samples stay below half of it (a lone noise peak: an arrival that just reaches the threshold keeps its
// neighbours near it). An arrival's first lobe may be a one-sample blip, but its next lobes follow
// within a sample or two.
constexpr float kGlitchRatio = 2.0f;
constexpr int kTransientQuiet = 4;
bool is_transient(const int16_t* x, int n, int i, float b, float thr);

// First index i >= start with |x[i] - base| >= thr that is not a transient (is_transient; the scan goes on
// after one), refined to a sub-sample position by linear interpolation between i-1 and i. -1 if none.
float threshold_crossing(const int16_t* x, int n, float base, float thr, int start);
// That sub-sample position when i (>= 1) is the first index at or above the threshold.
float crossing_subsample(const int16_t* x, int i, float base, float thr);

// Akaike information criterion onset picker (Maeda 1985; Kurz et al. 2005) on x[begin..end):
// AIC(k) = k log var(x[begin..k)) + (n-k-1) log var(x[k..end)); returns the arg-min index (absolute),
// or -1 when the window is too short. Evaluated with fast_log2 (the arg-min and the parabola do not
// depend on the base of the log), one running pass, no scratch buffers.
int aic_pick(const int16_t* x, int begin, int end);

// The AIC onset refined to a sub-sample position by a parabola through the minimum and its neighbours,
// the minimum sought over k >= search_from only (the whole window still sets the variances; k before
// search_from cost no logarithms): the arg-min over [search_from, end) of the full-window AIC.
float aic_pick_subsample(const int16_t* x, int begin, int end, int search_from);

// The period (samples) of the oscillation a threshold crossing at `cross` caught: zero crossings of x - base
// (linear sub-sample), from the last one at or before `cross` over the next three (three half periods, x 2/3).
// On a dispersive plate (flexural waves: higher frequencies run faster) the cycle the threshold catches
// arrives with its frequency's group velocity, so the localiser can scale each channel's slowness by it
// (dispersion_exponent). The crossings are sought within kPeriodSearch samples either side of the crossing
// (the search spans 1.5 periods and the lead, so it reads periods up to ~kPeriodSearch / 1.5 samples). A low band
// on a slow logger needs more (a thick wooden plate's 2.7 kHz picks at 48 kHz: 18 samples a period): where they
// are not all within kPeriodSearch, the search goes on to kPeriodSearchWide and keeps the read only when its
// three half periods agree (the longest <= kPeriodHalfRatio x the shortest): one cycle, not the caught half cycle
// followed by a signal that stays on one side of the baseline for tens of samples (what a wider search finds on
// a fast plate). A read within kPeriodSearch is the one a kPeriodSearch search makes (the searches stop at the
// first crossings). wide false: kPeriodSearch only (the features pass it on a clipped channel: past the rail the
// waveform is the front end's recovery, not the plate's cycle; a 50 kHz capture of a clipped PMMA drop reads a
// slow swing whose halves agree). NaN when no read is kept.
constexpr int kPeriodSearch = 32;
constexpr int kPeriodSearchWide = 64;
constexpr float kPeriodHalfRatio = 5.0f;
float pick_period(const int16_t* x, int n, float base, float cross, bool wide);

// Per-channel slowness factors (f_c / ref_hz)^-exponent, f_c = fs_hz / pick_period (1 where the period is
// unknown): what localise_tdoa's slowness_scale takes when dispersion_exponent is not 0.
void dispersion_scales(const EventFeatures& f, float fs_hz, float exponent, float ref_hz,
                       float out[kChannels]);

// --- acceptance rule (Eq. 35) ---

// True when ToA_i <= ToA_j + tol_us for every pair where sensor i is nearer the impact (x_mm, y_mm)
// than sensor j by at least margin_mm.
bool accept_eq35(const float toa_us[kChannels], const float sensor_x_mm[kChannels],
                 const float sensor_y_mm[kChannels], float x_mm, float y_mm, float tol_us,
                 float margin_mm, const float* travel_metric = nullptr);

// --- physics localiser: TDOA least squares ---

struct LocaliserResult {
  float x_mm, y_mm, t0_us;   // impact position and time
  float cov_xx, cov_xy, cov_yy;  // mm^2, from sigma_us and the Jacobian at the solution
  float rms_residual_us;     // rms of ToA residuals at the solution
  int32_t iterations;        // Gauss-Newton iterations
  int32_t evaluations;       // normal-equation evaluations (iterations + step halvings + 1): the cost
  int32_t status;
};

// A LocaliserResult with every field 0, field by field: a `= {}` of the struct is a memset call under -Os
// (newlib-nano's byte loop, ~150 instructions for its 40 bytes; the event clears two).
inline void clear_result(LocaliserResult* r) {
  r->x_mm = r->y_mm = r->t0_us = 0.0f;
  r->cov_xx = r->cov_xy = r->cov_yy = 0.0f;
  r->rms_residual_us = 0.0f;
  r->iterations = r->evaluations = r->status = 0;
}

// Solves toa_i = t0 + |p - s_i|_Q / v for p = (x, y) and t0 by iteratively reweighted Gauss-Newton
// (Huber weights with threshold huber_us, so one late pick cannot drag the solution), from one start:
// the lowest Huber cost of a 4 x 4 grid of cell centres over the plate; at most 6 iterations and 16
// normal-equation evaluations a start (a bounded cost per event); p stays on the plate. Channels whose
// `use` flag is 0 are left out (at least 3 needed).
// velocity_mm_per_us is the group velocity; sigma_us the ToA uncertainty used for the covariance;
// travel_metric {Q_xx, Q_xy, Q_yy} (positive definite; nullptr or the identity: |d|_Q = |d|) makes the
// travel distance sqrt(d^T Q d): the elliptical wavefronts of an orthotropic plate. slowness_scale
// (per channel; nullptr: all 1) multiplies channel c's travel time (dispersion_scales). starts (1 ..
// kMaxStarts): how many of the lowest-cost screening points are refined (the lowest Huber cost wins); out
// beyond the sensors' hull the Huber valley from the best-screened point can miss the answer.
// posterior_grid (> 1; kMaxPosteriorGrid at most): x, y are then the mean of the position's posterior, exp(-H /
// sigma_us^2) with H the Huber cost (t0 at its optimum), over posterior_grid x posterior_grid points evenly
// spaced on the fit's +-kPosteriorSpan standard deviations in x and y, the part of that box on the plate (the
// prior: the impact is on the plate). Out beyond the sensors' hull the Huber fit's valley is long and flat and
// the fit lands anywhere along it (on a laminate's near-edge drops outwards of the impact on average); the
// mean over the part of it on the plate scatters much less (docs/findings.md "The posterior mean"). The
// covariance, t0 and the residuals stay the fit's. Cost: posterior_grid^2 Huber costs (a host option:
// board/cost.py counts it). 0 or 1: the fit itself, bit for bit.
// max_evaluations (1 .. 16; 0: 16, the cap of every run): fewer normal-equation evaluations a start, the three-sensor
// position of a channel the channel check flags (kFlaggedEvaluations).
constexpr int kMaxStarts = 4;
constexpr int kMaxPosteriorGrid = 31;
constexpr float kPosteriorSpan = 3.0f;
LocaliserResult localise_tdoa(const float toa_us[kChannels], const uint8_t use[kChannels],
                              const float sensor_x_mm[kChannels], const float sensor_y_mm[kChannels],
                              float velocity_mm_per_us, float sigma_us, float plate_x_mm,
                              float plate_y_mm, float huber_us = 4.0f,
                              const float* travel_metric = nullptr,
                              const float* slowness_scale = nullptr, int starts = 1, int posterior_grid = 0,
                              int max_evaluations = 0);


// --- the whole per-event path: features -> physics localiser -> Eq. 35 -> model feature vector ---

struct LocaliserConfig {
  IMPACTCORE_LOCALISER_FIELDS(IMPACTCORE_DECLARE)
};

// The band localiser's velocity for an event: band_velocity_mm_per_us, its slowness moved by
// band_slowness_per_decade x (log10(sum_c energy_c / fs_hz) - band_log_energy_ref) when that slope is not 0;
// a dead (kFlagDead) or left-out (channel_left_out) channel's energy taken as the mean of the others'.
float band_velocity_for(const EventFeatures& f, const CoreConfig& cfg, const LocaliserConfig& loc);
// log10(sum_c energy[c] / fs_hz) of one event's four channel energies (what band_velocity_for reads; training
// fits the line on the same number): false (and *log_e untouched) when the sum or fs_hz is not positive.
bool summed_log_energy(const float energy[kChannels], float fs_hz, float* log_e);
// summed_log_energy as band_velocity_for reads it: a dead (kFlagDead in flags) or left-out channel's energy taken
// as the mean of the read channels' (with every channel read, summed_log_energy of energy itself).
bool band_log_energy(const float energy[kChannels], const uint8_t flags[kChannels],
                     const int channel_left_out[kChannels], float fs_hz, float* log_e);

// The model feature vector, in this order (names in kFeatureNames):
//   dtoa_us[6] (pair order), rel_toa_us[4] (ToA - earliest ToA), phys_x_mm, phys_y_mm,
//   log_energy_rel[4] (log10 E_c - mean_c log10 E_c), log_energy_mean, log_first_peak[4],
//   residual_ratio[4], phys_rms_us,
//   log_arrival_energy_sum (log10 of the energy from ToA to n2 summed over channels),
//   log_diff{1,2,3}_energy_sum (log10 of diff_energy[k] summed over channels).
constexpr int kNumFeatures = 6 + 4 + 2 + 4 + 1 + 4 + 4 + 1 + 1 + kDiffOrders;
extern const char* const kFeatureNames[kNumFeatures];

// The energy class's inputs of a drop without channel `left_out` (a dead channel, or one the model leaves out:
// channel_left_out), the other three channels' share of the vector's energies: log10 of their summed arrival
// energy, of their summed difference energies (Delta^1..3), their mean log10 energy, then the physics position
// (the host's height_class.LINEAR_CLASS_FEATURES, its three-channel class; the board's the same).
constexpr int kThreeChannelInputs = 1 + kDiffOrders + 1 + 2;
void three_channel_inputs(const EventFeatures& f, float phys_x_mm, float phys_y_mm, int left_out,
                          float out[kThreeChannelInputs]);

// The three-sensor position correction's inputs of a drop without channel `left_out` (a model without a site
// map; host three_channel_position.three_channel_position_inputs, the board's TableModels): the three-sensor
// position (x, y), the three arrival time differences among the other channels (kPair order), their log10
// energies relative to the three's own mean and their log10 first peaks, all read from the feature vector v
// (none of them reads `left_out`).
constexpr int kThreePositionInputs = 2 + 3 + 3 + 3;
void three_position_inputs(const float* v, float x_mm, float y_mm, int left_out, float out[kThreePositionInputs]);

// --- the channel check (channelcheck.cpp): one channel against the other three ---
//
// A model without a site map has no twin to say that a channel's energies disagree with the others' (a partly
// debonded disc: a gain loss and a low-pass); this does, label-free (docs/findings.md "A debonded channel on a
// model without a twin"). For each channel c of a drop with an onset on every channel:
//   level_c = log10 E_c - mean over the other three of log10 E_k (E the arrival energy),
//   tilt_c  = (log10 D3_c - log10 E_c) - the same mean over the other three (D3 the third-difference energy:
//             a gain cancels in it, a low-pass does not),
// each less a cubic in a position (scaled to -1..1 over the plate; kCheckTerms terms x^i y^j, i + j <= 3, in the
// order i = 0..3, j = 0..3-i) fitted on the training drops and the residuals' median, over their robust sd:
// z_level, z_tilt. The score is max(min(-z_level, -z_tilt), kCheckLevelAlone x -z_level): large when the channel
// is both weaker and duller than the other three say it should be, or far weaker whatever its spectrum.
// An event flags a channel when its score is the event's largest and above event_score, or (run rule) when the
// median of its finite scores over the last run_events events (this one included) exceeds run_score and this
// event scores it; the run rule needs at least (run_events + 1) / 2 events seen.
constexpr int kCheckTerms = 10;
constexpr int kMaxCheckEvents = 32;        // run_events at most
constexpr float kCheckLevelAlone = 1.0f / 3.0f;
struct ChannelCheckFit {
  float coef[kCheckTerms];
  float median;
  float scale;   // > 0
};
struct ChannelCheck {
  ChannelCheckFit level[kChannels];
  ChannelCheckFit tilt[kChannels];
  float plate_x_mm = 1.0f, plate_y_mm = 1.0f;
  float event_score = 5.0f, run_score = 3.0f;
  int32_t run_events = 8;
  // bit c set: a drop flagged on channel c keeps the four channels' position (the model's choice; the core does not
  // read it: impactapp's TableModels, the host's flagged_position.py)
  int32_t four_channel_mask = 0;
};
// The cubic's terms at a position.
void channel_check_terms(float x_mm, float y_mm, float plate_x_mm, float plate_y_mm, float out[kCheckTerms]);
// level and tilt of the four channels (log10; energies and D3 floored at 1e-30).
void channel_check_ratios(const float energy[kChannels], const float diff3[kChannels], float level[kChannels],
                          float tilt[kChannels]);
// The four scores of one drop (NaN: not checked) with channel c's cubic read at xy_mm[2c], xy_mm[2c + 1]: NaN for
// every channel when a channel has no onset or is dead (flags), for channel c when its position is not finite.
void channel_check_scores(const float energy[kChannels], const float diff3[kChannels], const uint8_t flags[kChannels],
                          const float xy_mm[2 * kChannels], const ChannelCheck& check, float out[kChannels]);
// The channel the newest event flags (-1: none) from the scores of the last `rows` events, oldest first
// (window[4 r + c]; the newest last; rows <= kMaxCheckEvents, only the last run_events read).
int channel_check_flag(const float* window, int rows, const ChannelCheck& check);

// --- the band pick (bandpick.cpp) ---
//
// A pick that does not hang on which cycle of a weak, fast precursor a threshold catches (stiff plates,
// docs/findings.md "Picks in one band"): x demodulated at f0 = cfg.band_pick_hz (x cos, x sin by a
// rotating phasor), each part low-passed by kBandPoles one-pole stages at f0 / kBandCutoffDivisor, the
// envelope |I + jQ|; the pick is the first sample of [anchor - kBandBeforeUs, anchor + band_window_us)
// where the envelope reaches band_pick_fraction of its peak there (linear between samples), or
// the floor if that is higher: kBandNoiseFactor x cfg.band_noise_counts (the noise the model was trained at,
// so that added noise does not move the pick) or kBandEnvFactor x the envelope's own noise rms at this
// capture's noise_rms if that is higher (white noise through the cascade); with band_noise_counts 0,
// kBandNoiseFactor x noise_rms. The filter's delay is the same on every channel. NaN: off (band_pick_hz
// <= 0 or >= kBandMaxRate x fs), a peak below twice the floor, a bad window.
// Cost: (window + settling) samples x ~30 float operations per channel (~150 samples at 100 kHz).
constexpr int kBandPoles = 4;
constexpr float kBandCutoffDivisor = 6.0f;
constexpr float kBandBeforeUs = 300.0f;
constexpr float kBandNoiseFactor = 3.0f;
constexpr float kBandEnvFactor = 4.0f;   // Rayleigh: P(envelope > 4 x its rms) = exp(-16) a sample
constexpr float kBandMaxRate = 0.45f;
constexpr int kBandMaxWindow = 512;   // samples of the envelope kept (the window is cut there)
// Returns the pick in samples from the capture start.
float band_onset(const int16_t* x, int n, float baseline, float noise_rms, int anchor, const CoreConfig& cfg);

struct EventResult {
  EventFeatures features;
  LocaliserResult phys;          // with the band picks' travel model: the mean of the two positions
  LocaliserResult band;          // the band picks' own position (status kErrBadConfig when not run)
  uint8_t accepted;              // Eq. 35 at the physics position
  float vector[kNumFeatures];    // model inputs; NaN where a channel has no onset
  float slowness_scale[kChannels];  // the localiser's per-channel travel-time factors (dispersion_scales;
                                    // 1 without dispersion)
  int32_t status;
};

int32_t process_event(const int16_t* const adc[kChannels], int n, const CoreConfig& cfg,
                      const LocaliserConfig& loc, EventResult* out);

// The features' per-event work the board's cost depends on, counted by the host's build only (the binding's CMake
// defines IMPACTCORE_WORK_COUNTS; the board's build does not, so its code and cost are unchanged):
// benchmarks/bench_signal_work.py fits their rates on qemu's per-drop cost (a measurement; the export's estimate does
// not read them). work_counts() is the calling thread's, zeroed by
// reset_work_counts() (the binding: before each event).
#define IMPACTCORE_WORK_FIELDS(X)                                                                        \
  X(peak_blocks)    /* blocks the peak scan reads (scan_peak), every channel and pass */              \
  X(hum_fits)       /* baseline fits that go past the no-hum test to the normal equations */          \
  X(hum_channels)   /* channel passes whose hum is modelled (the hum crossing, energy and peak) */     \
  X(spike_hunts)    /* find_inside_spike calls (a hunt in an arrival window) */                       \
  X(channel_passes) /* channel_features calls (a hunt's find redoes its channel) */                  \
  X(transients)     /* crossings passed over as a transient */                                        \
  X(reach_tests)    /* blocks the peak scan tests against the peak so far (inside its groups) */       \
  X(crossing_blocks) /* blocks the onset crossing reads sample by sample */                            \
  X(aic_picks)      /* AIC sub-sample picks */                                                         \
  X(partial_prefix) /* prefix sums taken inside a block (prefix_at_partial) */
#define IMPACTCORE_WORK_DECLARE(name) int32_t name = 0;
struct WorkCounts {
  IMPACTCORE_WORK_FIELDS(IMPACTCORE_WORK_DECLARE)
};
#undef IMPACTCORE_WORK_DECLARE
#if defined(IMPACTCORE_WORK_COUNTS)
WorkCounts& work_counts();
void reset_work_counts();
#define IC_WORK(field, n) (::impactcore::work_counts().field += (n))
#else
#define IC_WORK(field, n) ((void)0)
#endif

// process_event's localisation of an event's picks: *phys the threshold picks' position (dispersion: slowness_scale),
// *band the band picks' own (status kErrBadConfig when not run: band picks off, phys failed, fewer than three band
// picks); channels without an onset (or dead) are not read, nor channel `without` (0..3; -1: none).
// max_evaluations: localise_tdoa's (0: its cap).
void localise_event(const EventFeatures& f, const CoreConfig& cfg, const LocaliserConfig& loc, int without,
                    const float slowness_scale[kChannels], LocaliserResult* phys, LocaliserResult* band,
                    int max_evaluations = 0);
// process_event's physics position: the mean of the threshold picks' and the band picks' when both placed the drop.
void average_band(LocaliserResult* phys, const LocaliserResult& band);
// The physics position of an event without channel `without`: the three-sensor path of a channel the channel check
// flags (the host's edge_travel.three_sensor_positions with max_evaluations kFlaggedEvaluations runs the same
// localiser on the same picks). Each run is the screening and at most kFlaggedEvaluations normal-equation
// evaluations (not 16): what a flagged event spends on top of its four-channel run stays within the event budget, and
// the capped runs place the debonded drops of the measured rigs as well as the uncapped ones or better
// (docs/findings.md "Session 18: checkcost").
constexpr int kFlaggedEvaluations = 6;
LocaliserResult three_sensor_position(const EventResult& ev, const CoreConfig& cfg, const LocaliserConfig& loc,
                                      int without);

// --- streaming trigger (the only stateful part) ---

// Threshold trigger with hysteresis and hold-off on the per-frame max over channels of |x - baseline|.
// Feed it frames of kChannels samples; it reports when a capture should start and where the pre-trigger
// begins. The board keeps a ring buffer of `pretrigger` frames; the host runs it over a recording.
// Made for a real lab: the baseline is a fast tracker (baseline_alpha ~ 1/8 frame: it follows mains hum
// and drifting offsets, a 2-5 kHz arrival passes), a channel's threshold is the larger of
// threshold_counts and noise_factor x its tracked noise rms (the quiet frames' rms about the baseline,
// noise_alpha), and the trigger fires only when fire_frames of a channel's last kTriggerHistory frames were
// above its threshold: a glitch of one or two samples never fires it (nor two on different channels), an
// arrival's oscillation does.
constexpr int kTriggerHistory = 16;
struct TriggerConfig {
  float threshold_counts = 60;   // arm -> fire when any channel's |x - baseline| exceeds this ...
  float noise_factor = 8;        // ... or this many of its tracked noise rms, whichever is larger
  int fire_frames = 3;           // frames above the threshold among the last kTriggerHistory to fire
  float rearm_counts = 20;       // hysteresis: re-arm only after all channels stay below this ...
  int rearm_quiet_frames = 200;  // ... for this many frames
  int holdoff_frames = 2000;     // after firing, ignore everything for this many frames
  int pretrigger_frames = 256;   // frames kept before the firing frame
  float baseline_alpha = 1.0f / 8.0f;     // exponential baseline tracker (every frame but the firing one)
  float noise_alpha = 1.0f / 8192.0f;     // tracker of the noise variance (quiet armed frames)
};

class Trigger {
 public:
  explicit Trigger(const TriggerConfig& cfg, float initial_baseline = 2048.0f);
  // Each channel's own starting baseline (the board: the mean of its last pre-trigger frames, so a hum or
  // a channel's offset does not fire it when it arms).
  Trigger(const TriggerConfig& cfg, const float initial_baseline[kChannels]);
  // Returns true on the frame that fires.
  bool feed(const int16_t frame[kChannels]);
  bool armed() const { return state_ == kArmed; }
  long frames_seen() const { return frames_; }
  long fired_at() const { return fired_at_; }
  float baseline(int c) const { return baseline_[c]; }
  float noise_rms(int c) const;
  // The threshold in force (the largest of the channels'): what the status frame reports.
  float threshold() const;

 private:
  enum State { kArmed, kHoldoff, kWaitQuiet };
  TriggerConfig cfg_;
  State state_ = kArmed;
  float baseline_[kChannels];
  float noise_var_[kChannels];
  float thr_[kChannels];
  uint32_t above_[kChannels];    // bit k: frame (now - k) was above the channel's threshold
  long frames_ = 0;
  long fired_at_ = -1;
  int counter_ = 0;
  // Armed and quiet (every |dev| below its threshold), the baseline step's clamp is the identity even with
  // the thresholds the noise update has just set, when noise_factor >= 2.5 and 0 <= noise_alpha <= 0.5
  // (Trigger::feed): that frame then steps without it.
  bool quiet_step_unclamped_ = false;
  void track_baseline(const float dev[kChannels]);  // dev: the frame minus the baseline
};

// Scans a whole recording (channel-major) with a fresh Trigger; returns the firing frame or -1.
long find_trigger(const int16_t* const adc[kChannels], int n, const TriggerConfig& cfg);

}  // namespace impactcore
