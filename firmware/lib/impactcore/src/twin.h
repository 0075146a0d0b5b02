// The twin's energy fingerprint: how hard the plate was hit, from the per-channel energies of an event
// compared with what the calibrated twin (sim/) predicts at and around the impact position.
//
// Why (docs/findings.md, "Energy class"): a sensor's arrival energy carries a site factor of the impact
// position -- the direct wave interfering with its reflections from the nearest edges -- that swings by
// +-10-20 % within a few millimetres near the edges. It is finer than any measured training grid, but the
// twin reproduces it (r = 0.9 between measured and simulated site factors at the true positions). So the
// host simulates a drop from a reference height at every point of a regular grid (the site map, built
// once per calibration), and the event's 16 log-energies (4 channels x arrival, Delta^1..3) are matched
// against the map's entries near the model's position: each grid point j gives the least-squares shift
// D_j of log10 height that best explains the event (per-feature slope s_k = d feature / d log10 h,
// weight w_k = 1 / variance of the twin's error), and a misfit; the estimate is the average of D_j with
// weights exp(-misfit_j / T - d_j^2 / (2 sigma^2)) (d_j: distance of the grid point from the position).
// Everything is per event and fixed-size: at most kMaxTwinPoints grid points, no heap, no libm log.
#pragma once

#include <stdint.h>

#include "impactcore.h"

namespace impactcore {

constexpr int kTwinPerChannel = 1 + kDiffOrders;                 // arrival energy, Delta^1..3 energies
constexpr int kTwinFeatures = kChannels * kTwinPerChannel;       // 16, channel-major
constexpr int kMaxTwinPoints = 256;                              // grid points one estimate may visit
constexpr uint8_t kSiteMapMissing = 255;                         // q value of grid points with no drop

// The site map: grid point (i, j) at (x0_mm + i step_mm, y0_mm + j step_mm), i < nx, j < ny, row i * ny + j;
// feature k of a point = base[k] + scale[k] * q[(i * ny + j) * kTwinFeatures + k] (uint8, 255 = no drop
// there: the point lies on a sensor disc).
struct SiteMap {
  int32_t nx, ny;
  float x0_mm, y0_mm, step_mm;
  float base[kTwinFeatures];
  float scale[kTwinFeatures];
  const uint8_t* q;
};

// How the rig's events relate to the map (fitted by the host on drops of known height and position).
struct TwinConfig {
  float offset[kTwinFeatures];  // event feature - map feature at the reference height (gains, spectral tilt)
  float slope[kTwinFeatures];   // d feature / d log10(height)
  float weight[kTwinFeatures];  // 1 / variance of the event-minus-map residual
  float ref_log10_height_mm;    // the map's drop height
  float prior_mm = 7.0f;        // sigma of the model position's error
  float cutoff_mm = 15.0f;      // grid points farther than this from the position are not visited
  float temperature = 0.5f;     // misfit scale T of the weights
  float coarse_cutoff_mm = 0.0f;  // > 0: first a match over every other grid point within this distance
                                 // (prior widened by coarse_cutoff_mm / cutoff_mm), then the match around
                                 // its estimate (a start far from the impact: the board's 50 kHz picks)
  int32_t weak_channel = -1;    // >= 0: a channel known to be partly debonded (`retrain`): see twin_match
};

struct TwinEstimate {
  int32_t status;               // kOk, kErrBadConfig, kErrNullInput, or kErrTooFewSamples (< 1 usable channel)
  float log10_height_mm;        // the estimate (NaN unless kOk)
  float x_mm, y_mm;             // weighted mean of the visited grid points
  float spread_mm;              // 1-sigma radial spread of x, y: sqrt(weighted variance of the visited
                                // points about the mean + step^2/6, the grid's quantisation in 2 axes)
  float misfit;                 // smallest weighted misfit among them (per usable feature)
  int32_t n_points;             // grid points visited
};

// The event's 16 features: log10(1 + energy) of each channel's arrival (ToA .. n2) and Delta^1..3
// energies; returns the bit mask of usable features (a channel that clipped, is dead or has no onset
// gives none).
uint16_t twin_features(const EventFeatures& ev, float out[kTwinFeatures]);

TwinEstimate twin_estimate(const float features[kTwinFeatures], uint16_t usable, float x_mm, float y_mm,
                           const SiteMap& map, const TwinConfig& cfg);

// --- the twin's match of an event, with one channel left out when it must be (host and board alike) ---
//
// An event's reported position and height come from twin_estimate around a starting position; twin_match
// picks the start and the channels:
//  - the forests' position (x_mm, y_mm) when they ran; when they could not (x_mm or y_mm NaN: a channel
//    without an onset leaves the feature vector incomplete) and exactly one channel has no onset or is
//    dead, the physics localiser's three-sensor position (ev.phys), matched on the other three channels
//    (their usable mask; left_out = that channel, reason kTwinDeadChannel);
//  - a channel whose energies the twin cannot explain with the others' (a debonded or cracked disc): when
//    the match's misfit exceeds kBadMisfitRef x the training's reference misfit, each channel c in turn is
//    left out, the physics localiser on the other channels with an onset gives the start and the twin
//    matches their energies; the first channel whose leaving out lowers the misfit kBadMisfitGain-fold (and
//    below every earlier try) is the candidate. It is kept (reason kTwinInconsistent) only if the four
//    channels' energies, matched again around the candidate's three-channel answer, still misfit beyond
//    kBadMisfitRef x the reference; otherwise its pick, not its disc, was wrong (an early onset on noise or
//    hum moves the forests' start far from the impact) and that four-channel match is reported, no channel
//    left out. Clean drops have a misfit ~1 x the reference; a disc at x0.4 gain behind a 4 kHz low-pass
//    ~500 x, ~1.5 x without it.
// With a channel left out, the match is done again centred on its own answer (the three-sensor start is a
// few mm off, and the twin's prior pulls toward the start); the recheck's four-channel misfit comes from the
// same pass.
//  - a weak channel (cfg.weak_channel: a disc the diagnosis found partly debonded, the models retrained with
//    its low-pass and gain): when the four-channel match is consistent, the reported position is the mean of
//    it and the three-channel match without that channel (the physics three-sensor start, recentred); the
//    height stays the four-channel one; left_out = that channel, reason kTwinWeakChannel (the report flags
//    it). Its onset and energies are the least certain: the two matches' errors are partly independent.
// loc nullptr: no channel is left out for a misfit (the dead-channel start still applies). The board's
// TableModels and the host's models.ImpactModel.predict (through twin_match_batch) both call this.
constexpr float kBadMisfitRef = 20.0f;
constexpr float kBadMisfitGain = 10.0f;
constexpr float kMinMisfitRef = 0.1f;  // the reference misfit used when the card has none (or less)

enum TwinReason : int32_t { kTwinAllChannels = 0, kTwinDeadChannel = 1, kTwinInconsistent = 2, kTwinWeakChannel = 3 };

// How twin_match searches for the inconsistent channel: kTwinSearchFull tries every channel with an onset in
// channel order (a later one replaces the candidate only when kBadMisfitGain-fold lower again); kTwinSearchCued
// (the default, host and board) tries them in the order of their leave-one-out misfit at the four-channel
// answer's nearest grid point, lowest first, stops at the first that beats the bound, and tries at most
// kTwinCuedCandidates; only the first when its cue is kBadMisfitGain-fold below every other's, and that one,
// when its three picks' start does not beat the bound, from the four-channel answer too (docs/method.md
// "The twin's channel check").
enum TwinSearch : int32_t { kTwinSearchCued = 0, kTwinSearchFull = 1 };
constexpr int kTwinCuedCandidates = kChannels;  // 2 missed early picks (a pick, not energies, is wrong there)
struct TwinMatch {
  TwinEstimate est;     // status kOk: the reported position and height
  int32_t left_out;     // the channel not matched (-1: none)
  int32_t reason;       // TwinReason
};

TwinMatch twin_match(const EventResult& ev, float x_mm, float y_mm, const LocaliserConfig* loc,
                     const SiteMap& map, const TwinConfig& cfg, float misfit_ref,
                     int32_t search = kTwinSearchCued);

}  // namespace impactcore
