// The twin's energy fingerprint (twin.h).
#include "twin.h"

#include <math.h>
#include <string.h>

#if defined(__GNUC__)
#define IC_NOINLINE __attribute__((noinline))
#else
#define IC_NOINLINE
#endif

namespace impactcore {

namespace {
constexpr float kLog10Of2 = 0.301029996f;
constexpr uint8_t kUnusable = kFlagClipped | kFlagDead | kFlagNoOnset;

// One twin feature's per-event constants, interleaved so the grid loop reads them in one pass, and
// scaled by sqrt(weight): a grid point's residual is then u = r - s q (one multiply-subtract), the
// misfit's sum w (r - s q)^2 is sum u^2 and the normal equation's sum w slope (r - s q) is sum sigma u.
struct Term {
  float r;      // sqrt(w) (event feature - offset - map base) (0 when not usable)
  float s;      // sqrt(w) map scale (0 when not usable)
  float sigma;  // sqrt(w) slope (0 when not usable)
};

#define IC_INLINE inline __attribute__((always_inline))

// A match's window: the grid indices i0..i1, j0..j1 (multiples of stride) within cutoff_mm of the position
// (x_mm, y_mm), which is first pulled to the map's nearest edge (a model's output can stray off the map).
struct Window {
  int i0, i1, j0, j1;
  float x_mm, y_mm;
};

// False when the window is empty or holds more than kMaxTwinPoints points.
IC_INLINE bool grid_window(const SiteMap& map, float x_mm, float y_mm, float cutoff_mm, int stride, Window* w) {
  const float x_hi = map.x0_mm + static_cast<float>(map.nx - 1) * map.step_mm;
  const float y_hi = map.y0_mm + static_cast<float>(map.ny - 1) * map.step_mm;
  x_mm = x_mm < map.x0_mm ? map.x0_mm : (x_mm > x_hi ? x_hi : x_mm);
  y_mm = y_mm < map.y0_mm ? map.y0_mm : (y_mm > y_hi ? y_hi : y_mm);
  const float inv_step = 1.0f / map.step_mm;
  int i0 = ceil_to_int((x_mm - cutoff_mm - map.x0_mm) * inv_step);
  int i1 = floor_to_int((x_mm + cutoff_mm - map.x0_mm) * inv_step);
  int j0 = ceil_to_int((y_mm - cutoff_mm - map.y0_mm) * inv_step);
  int j1 = floor_to_int((y_mm + cutoff_mm - map.y0_mm) * inv_step);
  if (i0 < 0) i0 = 0;
  if (j0 < 0) j0 = 0;
  if (i1 > map.nx - 1) i1 = map.nx - 1;
  if (j1 > map.ny - 1) j1 = map.ny - 1;
  i0 = (i0 + stride - 1) / stride * stride;  // the strided grid: indices that are multiples of stride
  j0 = (j0 + stride - 1) / stride * stride;
  *w = Window{i0, i1, j0, j1, x_mm, y_mm};
  return !(i0 > i1 || j0 > j1 || ((i1 - i0) / stride + 1) * ((j1 - j0) / stride + 1) > kMaxTwinPoints);
}

// A match's visited points: per point its log weight, height shift, y and squared distance from the
// position; per grid row the number of visited points (x is the row's: the estimate sums the weights per
// row, then x once).
struct Visited {
  float logw[kMaxTwinPoints], shift[kMaxTwinPoints], py[kMaxTwinPoints], dist2[kMaxTwinPoints];
  uint16_t row_n[kMaxTwinPoints];
  int n = 0;
  float best_logw = -INFINITY, best_misfit = INFINITY;

  IC_INLINE void add(float misfit, float shift_j, float gy, float d2, float inv_t, float inv_2s2) {
    const float lw = -misfit * inv_t - d2 * inv_2s2;
    logw[n] = lw;
    shift[n] = shift_j;
    py[n] = gy;
    dist2[n] = d2;
    if (lw > best_logw) best_logw = lw;
    if (misfit < best_misfit) best_misfit = misfit;
    ++n;
  }
};

// Calls point(q, gy, d2) for every grid point of the window within the cutoff (cut2 its square) that the map
// holds, row by row (x ascending, then y), and records each row's number of visited points in v.
template <typename Point>
IC_INLINE void visit_window(const Window& w, int stride, const SiteMap& map, float cut2, Visited& v, Point&& point) {
  for (int i = w.i0; i <= w.i1; i += stride) {
    const float gx = map.x0_mm + static_cast<float>(i) * map.step_mm;
    const int row_start = v.n;
    for (int j = w.j0; j <= w.j1; j += stride) {
      const float gy = map.y0_mm + static_cast<float>(j) * map.step_mm;
      const float d2 = (gx - w.x_mm) * (gx - w.x_mm) + (gy - w.y_mm) * (gy - w.y_mm);
      if (d2 > cut2) continue;
      const uint8_t* q = map.q + (static_cast<int32_t>(i) * map.ny + j) * kTwinFeatures;
      if (q[0] == kSiteMapMissing) continue;
      point(q, gy, d2);
    }
    v.row_n[(i - w.i0) / stride] = static_cast<uint16_t>(v.n - row_start);
  }
}

// The weighted means of the visited points (height, x, y), and the weighted mean squared distance from the
// position (the spread).
IC_INLINE TwinEstimate weighted_estimate(const Visited& v, const Window& w, int stride, const SiteMap& map,
                                         const TwinConfig& cfg) {
  TwinEstimate r{kOk, NAN, NAN, NAN, NAN, NAN, 0};
  r.n_points = v.n;
  if (v.n == 0) {
    r.status = kErrTooFewSamples;
    return r;
  }
  float sw = 0.0f, sd = 0.0f, sx = 0.0f, sy = 0.0f, sr = 0.0f;
  int m = 0;
  for (int i = w.i0; i <= w.i1; i += stride) {
    const float gx = map.x0_mm + static_cast<float>(i) * map.step_mm;
    float row_w = 0.0f;
    for (const int end = m + v.row_n[(i - w.i0) / stride]; m < end; ++m) {
      const float p = exp_nonpositive(v.logw[m] - v.best_logw);
      row_w += p;
      sd += p * v.shift[m];
      sy += p * v.py[m];
      sr += p * v.dist2[m];
    }
    sw += row_w;
    sx += row_w * gx;
  }
  const float inv_sw = 1.0f / sw;
  r.log10_height_mm = cfg.ref_log10_height_mm + sd * inv_sw;
  r.x_mm = sx * inv_sw;
  r.y_mm = sy * inv_sw;
  // Weighted variance about the mean = mean squared distance from the position - the mean's own squared
  // distance from it; plus the grid's quantisation, step^2 / 12 per axis (a single dominant point is not
  // an exact position).
  const float ex = r.x_mm - w.x_mm, ey = r.y_mm - w.y_mm;
  float var = sr * inv_sw - (ex * ex + ey * ey);
  if (var < 0.0f) var = 0.0f;
  r.spread_mm = vsqrt_f32(var + map.step_mm * map.step_mm * (1.0f / 6.0f));
  r.misfit = v.best_misfit;
  return r;
}

// One match: the grid points whose indices are multiples of `stride` within cutoff_mm of (x_mm, y_mm), each
// weighted by its misfit and a Gaussian prior of sigma prior_mm on its distance from the position.
// kSkip >= 0: that channel's terms are all zero (not usable) and its features are not read: the same sums
// (adding a zero term changes none), a quarter fewer multiply-adds a point (a three-channel match);
// kSkip < 0: every channel (the clean path).
template <int kSkip>
TwinEstimate match_skip(const Term term[kTwinFeatures], float a, int n_used, float x_mm, float y_mm, const SiteMap& map,
                   const TwinConfig& cfg, int stride, float cutoff_mm, float prior_mm) {
  Window w;
  if (!grid_window(map, x_mm, y_mm, cutoff_mm, stride, &w)) {
    TwinEstimate r{kErrBadConfig, NAN, NAN, NAN, NAN, NAN, 0};
    return r;
  }
  const float inv_a = 1.0f / a;
  const float inv_n = 1.0f / static_cast<float>(n_used);
  const float inv_t = 1.0f / cfg.temperature;
  const float inv_2s2 = 0.5f / (prior_mm * prior_mm);
  const float cut2 = cutoff_mm * cutoff_mm;
  Visited v;
  visit_window(w, stride, map, cut2, v, [&](const uint8_t* q, float gy, float d2) {
    // D = sum sigma u / A; misfit = (sum u^2 - A D^2) / n (unused features have u = sigma = 0).
    // The sums start from the first feature's terms (0 + t would only turn a -0 into +0, which the
    // shift and misfit below do not tell apart).
    constexpr int kFirst = kSkip == 0 ? kTwinPerChannel : 0;
    const float u0 = term[kFirst].r - term[kFirst].s * static_cast<float>(q[kFirst]);
    float b = term[kFirst].sigma * u0, c = u0 * u0;
#pragma GCC unroll 16
    for (int k = kFirst + 1; k < kTwinFeatures; ++k) {
      if (k / kTwinPerChannel == kSkip) continue;
      const Term& t = term[k];
      const float u = t.r - t.s * static_cast<float>(q[k]);
      b += t.sigma * u;
      c += u * u;
    }
    const float shift_j = b * inv_a;
    float misfit = (c - a * shift_j * shift_j) * inv_n;
    if (misfit < 0.0f) misfit = 0.0f;
    v.add(misfit, shift_j, gy, d2, inv_t, inv_2s2);
  });
  return weighted_estimate(v, w, stride, map, cfg);
}

// One channel's features added to the sums b += sigma u, c += u^2 (u = r - s q); with b2, c2: to both pairs.
IC_INLINE void add_channel(const Term* t, const uint8_t* q, float* b, float* c) {
#pragma GCC unroll 4
  for (int k = 0; k < kTwinPerChannel; ++k) {
    const float u = t[k].r - t[k].s * static_cast<float>(q[k]);
    *b += t[k].sigma * u;
    *c += u * u;
  }
}
IC_INLINE void add_channel(const Term* t, const uint8_t* q, float* b, float* c, float* b2, float* c2) {
#pragma GCC unroll 4
  for (int k = 0; k < kTwinPerChannel; ++k) {
    const float u = t[k].r - t[k].s * static_cast<float>(q[k]);
    *b += t[k].sigma * u;
    *c += u * u;
    *b2 += t[k].sigma * u;
    *c2 += u * u;
  }
}

// The inconsistent channel's recentring and the four-channel recheck in one pass: both are fine matches
// centred on the candidate's three-channel answer (x_mm, y_mm), so they visit the same grid points. Per point
// the four channels' residuals u = r - s q (term: the four-channel terms, a4 / n4 theirs) give the recheck's
// sums over every feature and the recentring's over the features of every channel but `skip` (the kept
// channels' terms are the four-channel ones: the same make_terms but for the left-out channel's zeros; a3 / n3
// the three-channel estimate's). Returns match_skip<skip>'s three-channel estimate (the recentring, the same
// sums in the same order) and in *misfit4 the smallest four-channel misfit over the points, match_skip<-1>'s
// misfit (the recheck's verdict): one pass instead of two. Both sums start from 0 and add the features in
// channel order, so up to the left-out channel they are the same numbers: the three-channel sums are copied
// from the four-channel ones there, and only the channels after it are added to both (no branch a feature).
IC_NOINLINE TwinEstimate match_recheck(const Term term[kTwinFeatures], int skip, float a3, int n3, float a4, int n4,
                                       float x_mm, float y_mm, const SiteMap& map, const TwinConfig& cfg,
                                       float* misfit4) {
  *misfit4 = INFINITY;
  Window w;
  if (!grid_window(map, x_mm, y_mm, cfg.cutoff_mm, 1, &w)) {
    TwinEstimate r{kErrBadConfig, NAN, NAN, NAN, NAN, NAN, 0};
    return r;
  }
  const float inv_a = 1.0f / a3, inv_a4 = 1.0f / a4;
  const float inv_n = 1.0f / static_cast<float>(n3), inv_n4 = 1.0f / static_cast<float>(n4);
  const float inv_t = 1.0f / cfg.temperature;
  const float inv_2s2 = 0.5f / (cfg.prior_mm * cfg.prior_mm);
  const float cut2 = cfg.cutoff_mm * cfg.cutoff_mm;
  const int ks = skip * kTwinPerChannel;
  Visited v;
  float best4 = INFINITY;
  visit_window(w, 1, map, cut2, v, [&](const uint8_t* q, float gy, float d2) {
    float b4 = 0.0f, c4 = 0.0f;  // from 0: see match_skip (a -0 is not told apart)
    int k = 0;
    for (; k < ks; k += kTwinPerChannel) add_channel(term + k, q + k, &b4, &c4);
    float b = b4, c = c4;  // the channels before skip: the same sums
    add_channel(term + k, q + k, &b4, &c4);
    for (k += kTwinPerChannel; k < kTwinFeatures; k += kTwinPerChannel) add_channel(term + k, q + k, &b4, &c4, &b, &c);
    const float shift4 = b4 * inv_a4;
    float m4 = (c4 - a4 * shift4 * shift4) * inv_n4;
    if (m4 < 0.0f) m4 = 0.0f;
    if (m4 < best4) best4 = m4;
    const float shift_j = b * inv_a;
    float misfit = (c - a3 * shift_j * shift_j) * inv_n;
    if (misfit < 0.0f) misfit = 0.0f;
    v.add(misfit, shift_j, gy, d2, inv_t, inv_2s2);
  });
  *misfit4 = best4;
  return weighted_estimate(v, w, 1, map, cfg);
}

// The per-event constants, and the normal equation's denominator A = sum w slope^2 = sum sigma^2.
void make_terms(const float features[kTwinFeatures], uint16_t usable, const SiteMap& map, const TwinConfig& cfg,
                Term term[kTwinFeatures], float* a_out, int* n_used_out) {
  float a = 0.0f;
  int n_used = 0;
  for (int k = 0; k < kTwinFeatures; ++k) {
    const bool use = (usable >> k) & 1u;
    const float sw = use && cfg.weight[k] > 0.0f ? vsqrt_f32(cfg.weight[k]) : 0.0f;
    Term& t = term[k];
    t.r = use ? sw * ((features[k] - cfg.offset[k]) - map.base[k]) : 0.0f;
    t.s = sw * map.scale[k];
    t.sigma = sw * cfg.slope[k];
    a += t.sigma * t.sigma;
    n_used += use ? 1 : 0;
  }
  *a_out = a;
  *n_used_out = n_used;
}

// match<kSkip> for the event's terms: a channel none of whose features is usable is skipped.
IC_NOINLINE TwinEstimate match_terms(const Term term[kTwinFeatures], uint16_t usable, float a, int n_used, float x_mm,
                         float y_mm, const SiteMap& map, const TwinConfig& cfg, int stride, float cutoff_mm,
                         float prior_mm) {
  constexpr uint16_t kChannelBits = (1u << kTwinPerChannel) - 1u;
  int skip = -1;
  for (int c = kChannels - 1; c >= 0; --c) {
    if (((usable >> (c * kTwinPerChannel)) & kChannelBits) == 0) skip = c;
  }
  static_assert(kChannels == 4, "match_terms dispatches four channels");
  switch (skip) {
    case 0: return match_skip<0>(term, a, n_used, x_mm, y_mm, map, cfg, stride, cutoff_mm, prior_mm);
    case 1: return match_skip<1>(term, a, n_used, x_mm, y_mm, map, cfg, stride, cutoff_mm, prior_mm);
    case 2: return match_skip<2>(term, a, n_used, x_mm, y_mm, map, cfg, stride, cutoff_mm, prior_mm);
    case 3: return match_skip<3>(term, a, n_used, x_mm, y_mm, map, cfg, stride, cutoff_mm, prior_mm);
    default: return match_skip<-1>(term, a, n_used, x_mm, y_mm, map, cfg, stride, cutoff_mm, prior_mm);
  }
}
}  // namespace

uint16_t twin_features(const EventFeatures& ev, float out[kTwinFeatures]) {
  uint16_t usable = 0;
  for (int c = 0; c < kChannels; ++c) {
    const ChannelFeatures& f = ev.ch[c];
    float arrival = 0.0f;
    for (int w = 0; w < kEnergyWindows; ++w) arrival += f.window_energy[w];
    float* o = out + c * kTwinPerChannel;
    o[0] = kLog10Of2 * fast_log2(arrival + 1.0f);
    for (int k = 0; k < kDiffOrders; ++k) o[1 + k] = kLog10Of2 * fast_log2(f.diff_energy[k] + 1.0f);
    if ((f.flags & kUnusable) == 0) usable |= static_cast<uint16_t>(((1u << kTwinPerChannel) - 1u) << (c * kTwinPerChannel));
  }
  return usable;
}

namespace {
// An estimate's per-event constants (make_terms), kept for the recentring with the same mask (ok: valid).
struct Terms {
  Term t[kTwinFeatures];
  float a;
  int n_used;
  bool ok;
};

// twin_estimate for twin_match's flagged paths: a channel with no usable feature is skipped (match_terms),
// and the coarse pass's cutoff is given (0: none; the recentring's fine_estimate; twin_estimate: the
// config's). keep (not null): gets the terms.
IC_NOINLINE TwinEstimate estimate(const float features[kTwinFeatures], uint16_t usable, float x_mm, float y_mm,
                      const SiteMap& map, const TwinConfig& cfg, float coarse_cutoff_mm, Terms* keep = nullptr) {
  TwinEstimate r{kOk, NAN, NAN, NAN, NAN, NAN, 0};
  Terms local;
  Terms& k = keep ? *keep : local;
  k.ok = false;
  if (features == nullptr || map.q == nullptr) {
    r.status = kErrNullInput;
    return r;
  }
  if (map.nx < 1 || map.ny < 1 || !(map.step_mm > 0.0f) || !(cfg.prior_mm > 0.0f) || !(cfg.cutoff_mm > 0.0f) ||
      !(cfg.temperature > 0.0f) || !(cfg.coarse_cutoff_mm >= 0.0f) || !(x_mm == x_mm) || !(y_mm == y_mm)) {
    r.status = kErrBadConfig;
    return r;
  }
  const Term* term = k.t;
  float a = 0.0f;
  int n_used = 0;
  make_terms(features, usable, map, cfg, k.t, &a, &n_used);
  if (n_used < kTwinPerChannel || !(a > 0.0f)) {
    r.status = kErrTooFewSamples;
    return r;
  }
  k.a = a;
  k.n_used = n_used;
  k.ok = true;
  if (coarse_cutoff_mm > 0.0f) {
    // Coarse to fine: every other grid point within coarse_cutoff_mm (as many points as the fine window, over
    // four times its area, the prior widened alike), then the match around that estimate.
    const TwinEstimate c = match_terms(term, usable, a, n_used, x_mm, y_mm, map, cfg, 2, coarse_cutoff_mm,
                                       cfg.prior_mm * coarse_cutoff_mm / cfg.cutoff_mm);
    if (c.status == kOk) {
      x_mm = c.x_mm;
      y_mm = c.y_mm;
    }
    TwinEstimate f = match_terms(term, usable, a, n_used, x_mm, y_mm, map, cfg, 1, cfg.cutoff_mm, cfg.prior_mm);
    f.n_points += c.n_points;
    return f;
  }
  return match_terms(term, usable, a, n_used, x_mm, y_mm, map, cfg, 1, cfg.cutoff_mm, cfg.prior_mm);
}
}  // namespace


TwinEstimate twin_estimate(const float features[kTwinFeatures], uint16_t usable, float x_mm, float y_mm,
                           const SiteMap& map, const TwinConfig& cfg) {
  return estimate(features, usable, x_mm, y_mm, map, cfg, cfg.coarse_cutoff_mm);
}


namespace {
// A three-channel match starts from the physics localiser's three-sensor position, whose error (~5 mm on
// the bundled rig) is comparable to the twin's position prior (prior_mm): the prior pulls the match
// toward that start. A second match centred on the first one's answer halves that pull (bench_faults,
// docs/findings.md "A faulty lab"). Kept when it succeeds.
void recentre(const float feats[kTwinFeatures], uint16_t mask, const SiteMap& map, const TwinConfig& cfg,
              TwinEstimate* est) {
  const TwinEstimate again = twin_estimate(feats, mask, est->x_mm, est->y_mm, map, cfg);
  if (again.status == kOk && again.log10_height_mm == again.log10_height_mm) *est = again;
}

// The same match without its coarse pass: a start that is already a match's answer is near the impact, and
// the coarse pass (for a start far from it) only costs a second match. The dead channel's and the
// inconsistent channel's recentring, and the four-channel recheck at the three-channel answer.
IC_NOINLINE TwinEstimate fine_estimate(const float feats[kTwinFeatures], uint16_t mask, float x_mm, float y_mm,
                           const SiteMap& map, const TwinConfig& cfg) {
  return estimate(feats, mask, x_mm, y_mm, map, cfg, 0.0f);
}

IC_NOINLINE void recentre_fine(const float feats[kTwinFeatures], uint16_t mask, const SiteMap& map, const TwinConfig& cfg,
                   TwinEstimate* est) {
  const TwinEstimate again = fine_estimate(feats, mask, est->x_mm, est->y_mm, map, cfg);
  if (again.status == kOk && again.log10_height_mm == again.log10_height_mm) *est = again;
}

// recentre_fine from the terms the estimate with the same mask kept (the same match; no second make_terms).
IC_NOINLINE void recentre_kept(const Terms& k, uint16_t mask, const SiteMap& map, const TwinConfig& cfg,
                               TwinEstimate* est) {
  if (!k.ok || !(est->x_mm == est->x_mm) || !(est->y_mm == est->y_mm)) return;
  const TwinEstimate again =
      match_terms(k.t, mask, k.a, k.n_used, est->x_mm, est->y_mm, map, cfg, 1, cfg.cutoff_mm, cfg.prior_mm);
  if (again.status == kOk && again.log10_height_mm == again.log10_height_mm) *est = again;
}

// The channel check's order (kTwinSearchCued): at the site-map point nearest (x_mm, y_mm), each channel's
// leave-one-out misfit -- the four-channel residuals with that channel's taken out and the height shift
// fitted again -- ascending; a channel with an onset but no usable energy, or no drop at that point, keeps
// its place after the others (channel order). Returns how many of them twin_match tries: those with an onset,
// or only the first when every one of them has a cue and the first's is kBadMisfitGain-fold below the
// second's (the energies single that channel out; a wrong pick, which the later candidates are for, leaves
// the cue without such a margin: docs/method.md "The twin's channel check").
IC_NOINLINE int cued_order(const float feats[kTwinFeatures], uint16_t usable, const uint8_t has_onset[kChannels], float x_mm,
               float y_mm, const SiteMap& map, const TwinConfig& cfg, const Terms& made, int order[kChannels]) {
  float cue[kChannels];
  int n = 0;
  for (int c = 0; c < kChannels; ++c) {
    cue[c] = INFINITY;
    if (has_onset[c]) order[n++] = c;
  }
  const float x_hi = map.x0_mm + static_cast<float>(map.nx - 1) * map.step_mm;
  const float y_hi = map.y0_mm + static_cast<float>(map.ny - 1) * map.step_mm;
  x_mm = x_mm < map.x0_mm ? map.x0_mm : (x_mm > x_hi ? x_hi : x_mm);
  y_mm = y_mm < map.y0_mm ? map.y0_mm : (y_mm > y_hi ? y_hi : y_mm);
  const int i = floor_to_int((x_mm - map.x0_mm) / map.step_mm + 0.5f);
  const int j = floor_to_int((y_mm - map.y0_mm) / map.step_mm + 0.5f);
  const uint8_t* q = map.q + (static_cast<int32_t>(i < map.nx ? i : map.nx - 1) * map.ny + (j < map.ny ? j : map.ny - 1)) *
                                 kTwinFeatures;
  if (q[0] != kSiteMapMissing) {
    Term own[kTwinFeatures];
    float a = made.a;
    int n_used = made.n_used;
    if (!made.ok) make_terms(feats, usable, map, cfg, own, &a, &n_used);  // made: the same mask's, when kept
    const Term* term = made.ok ? made.t : own;
    float bc[kChannels] = {}, cc[kChannels] = {}, ac[kChannels] = {}, b = 0.0f, cs = 0.0f;
    int nc[kChannels] = {};
    for (int k = 0; k < kTwinFeatures; ++k) {
      const int ch = k / kTwinPerChannel;
      const float u = term[k].r - term[k].s * static_cast<float>(q[k]);
      bc[ch] += term[k].sigma * u;
      cc[ch] += u * u;
      ac[ch] += term[k].sigma * term[k].sigma;
      nc[ch] += (usable >> k) & 1u;
    }
    for (int c = 0; c < kChannels; ++c) {
      b += bc[c];
      cs += cc[c];
    }
    for (int c = 0; c < kChannels; ++c) {
      const float ar = a - ac[c];
      const int nr = n_used - nc[c];
      if (nc[c] == 0 || nr < kTwinPerChannel || !(ar > 0.0f)) continue;
      const float br = b - bc[c];
      const float m = (cs - cc[c] - br * br / ar) / static_cast<float>(nr);
      cue[c] = m > 0.0f ? m : 0.0f;
    }
  }
  for (int k = 1; k < n; ++k) {  // insertion sort, stable: equal cues keep channel order
    const int c = order[k];
    int m = k;
    for (; m > 0 && cue[order[m - 1]] > cue[c]; --m) order[m] = order[m - 1];
    order[m] = c;
  }
  // the channels without a cue sort last: every channel has one when the last has
  if (n > 1 && cue[order[n - 1]] < INFINITY && cue[order[1]] > kBadMisfitGain * cue[order[0]]) return 1;
  return n;
}
}  // namespace

TwinMatch twin_match(const EventResult& ev, float x_mm, float y_mm, const LocaliserConfig* loc,
                     const SiteMap& map, const TwinConfig& cfg, float misfit_ref, int32_t search) {
  TwinMatch out{{kErrTooFewSamples, NAN, NAN, NAN, NAN, NAN, 0}, -1, kTwinAllChannels};
  if (ev.status != kOk) {
    out.est.status = ev.status;
    return out;
  }
  float feats[kTwinFeatures];
  const uint16_t usable = twin_features(ev.features, feats);
  uint8_t has_onset[kChannels];
  int missing = 0, missing_channel = -1;
  for (int c = 0; c < kChannels; ++c) {
    has_onset[c] = (ev.features.ch[c].flags & (kFlagNoOnset | kFlagDead)) ? 0 : 1;
    if (!has_onset[c]) {
      ++missing;
      missing_channel = c;
    }
  }
  Terms kept;  // the first estimate's terms (the four channels', or the dead channel's other three; the same mask as usable)
  if (!(x_mm == x_mm) || !(y_mm == y_mm)) {
    if (missing != 1 || ev.phys.status != kOk) return out;
    out.left_out = missing_channel;
    out.reason = kTwinDeadChannel;
    out.est = estimate(feats, usable, ev.phys.x_mm, ev.phys.y_mm, map, cfg, cfg.coarse_cutoff_mm, &kept);
  } else {
    out.est = estimate(feats, usable, x_mm, y_mm, map, cfg, cfg.coarse_cutoff_mm, &kept);  // twin_estimate's
  }
  const float ref = misfit_ref > kMinMisfitRef ? misfit_ref : kMinMisfitRef;
  const float metric[3] = {loc ? loc->travel_metric_xx : 1.0f, loc ? loc->travel_metric_xy : 0.0f,
                           loc ? loc->travel_metric_yy : 1.0f};
  float toa[kChannels];
  for (int c = 0; c < kChannels; ++c) toa[c] = ev.features.ch[c].toa_us;
  if (loc == nullptr || out.est.status != kOk || !(out.est.misfit > kBadMisfitRef * ref)) {
    if (out.left_out >= 0) {
      recentre_kept(kept, usable, map, cfg, &out.est);
    } else if (loc != nullptr && out.est.status == kOk && cfg.weak_channel >= 0 && cfg.weak_channel < kChannels &&
               missing == 0) {
      const int w = cfg.weak_channel;
      uint8_t use[kChannels];
      for (int k = 0; k < kChannels; ++k) use[k] = k != w ? 1 : 0;
      const LocaliserResult p = localise_tdoa(toa, use, loc->sensor_x_mm, loc->sensor_y_mm, loc->velocity_mm_per_us,
                                              loc->sigma_us, loc->plate_x_mm, loc->plate_y_mm, loc->huber_us, metric,
                                              loc->dispersion_exponent != 0.0f ? ev.slowness_scale : nullptr,
                                              loc->localiser_starts);
      if (p.status == kOk) {
        const uint16_t mask =
            static_cast<uint16_t>(usable & ~(((1u << kTwinPerChannel) - 1u) << (w * kTwinPerChannel)));
        TwinEstimate t = twin_estimate(feats, mask, p.x_mm, p.y_mm, map, cfg);
        if (t.status == kOk && t.log10_height_mm == t.log10_height_mm) {
          recentre(feats, mask, map, cfg, &t);
          out.est.x_mm = 0.5f * (out.est.x_mm + t.x_mm);
          out.est.y_mm = 0.5f * (out.est.y_mm + t.y_mm);
          out.left_out = w;
          out.reason = kTwinWeakChannel;
        }
      }
    }
    return out;
  }
  float best = out.est.misfit;
  uint16_t best_mask = usable;
  // best_mask's terms when an estimate kept them (the dead channel's; the cued search's candidate: it stops
  // there); null: made again (the full search, where a later channel's estimate overwrites cand).
  const Terms* best_terms = out.left_out >= 0 ? &kept : nullptr;
  Terms cand;
  // The candidates: every channel with an onset in channel order (kTwinSearchFull), or in the cue's order,
  // stopping at the first that beats the bound and after kTwinCuedCandidates, or after the first when the cue
  // singles it out (kTwinSearchCued, cued_order).
  int order[kChannels];
  int n_order = 0;
  bool singled = false;
  if (search == kTwinSearchFull) {
    for (int c = 0; c < kChannels; ++c) {
      if (has_onset[c]) order[n_order++] = c;
    }
  } else {
    n_order = cued_order(feats, usable, has_onset, out.est.x_mm, out.est.y_mm, map, cfg, kept, order);
    if (n_order > kTwinCuedCandidates) n_order = kTwinCuedCandidates;
    singled = n_order == 1 && kChannels - missing > 1;  // the cue singled the channel out (cued_order)
  }
  const float four_x = out.est.x_mm, four_y = out.est.y_mm;  // the four-channel answer
  for (int o = 0; o < n_order; ++o) {
    const int c = order[o];
    uint8_t use[kChannels];
    for (int k = 0; k < kChannels; ++k) use[k] = k != c && has_onset[k] ? 1 : 0;
    const LocaliserResult p = localise_tdoa(toa, use, loc->sensor_x_mm, loc->sensor_y_mm, loc->velocity_mm_per_us,
                                            loc->sigma_us, loc->plate_x_mm, loc->plate_y_mm, loc->huber_us, metric,
                                            loc->dispersion_exponent != 0.0f ? ev.slowness_scale : nullptr,
                                            loc->localiser_starts);
    if (p.status != kOk) continue;
    const uint16_t mask = static_cast<uint16_t>(usable & ~(((1u << kTwinPerChannel) - 1u) << (c * kTwinPerChannel)));
    TwinEstimate t = estimate(feats, mask, p.x_mm, p.y_mm, map, cfg, cfg.coarse_cutoff_mm, &cand);
    // A channel the cue singled out whose three picks' start does not beat the gain (those picks can place
    // the drop far off, e.g. in a plate corner): matched again from the four-channel answer, where the cue
    // found its energies the inconsistent ones.
    if (singled && t.status == kOk && !(t.misfit * kBadMisfitGain < best) && four_x == four_x && four_y == four_y) {
      t = estimate(feats, mask, four_x, four_y, map, cfg, cfg.coarse_cutoff_mm, &cand);
    }
    if (t.status != kOk || !(t.log10_height_mm == t.log10_height_mm) || !(t.misfit * kBadMisfitGain < best)) {
      continue;
    }
    best = t.misfit;
    out.est = t;
    out.left_out = c;
    out.reason = kTwinInconsistent;
    best_mask = mask;
    best_terms = search != kTwinSearchFull ? &cand : nullptr;
    if (search != kTwinSearchFull) break;
  }
  if (out.left_out < 0) return out;
  // The pick, not the disc: a channel whose onset alone is wrong (an early pick on noise or hum) sends the
  // forests' start far from the impact, and every four-channel match there misfits; leaving that channel
  // out fixes the start, not its energies. So the four channels' energies are matched again around the
  // three-channel answer: within the same bound, they agree at that position and no channel is inconsistent
  // (reported as a four-channel match from that start); only a channel whose energies the twin still cannot
  // explain there is left out (docs/method.md, "The twin's channel check").
  // The recheck is a fine match around the answer (no coarse pass: the answer is the start); when the four
  // channels agree there, their whole match from that start is reported, as before.
  if (missing == 0 && best_terms != nullptr && best_terms->ok && out.est.x_mm == out.est.x_mm &&
      out.est.y_mm == out.est.y_mm) {
    // The recheck's verdict and the recentring in one pass (match_recheck): when the four channels still
    // misfit beyond the bound there, its three-channel estimate is the recentring's; otherwise the recheck
    // below (the four channels' whole match) as before.
    // kept: the four-channel estimate's terms (the recheck's mask)
    if (kept.ok && kept.n_used >= kTwinPerChannel && kept.a > 0.0f) {
      float misfit4 = INFINITY;
      const TwinEstimate again = match_recheck(kept.t, out.left_out, best_terms->a, best_terms->n_used, kept.a, kept.n_used,
                                               out.est.x_mm, out.est.y_mm, map, cfg, &misfit4);
      if (misfit4 > kBadMisfitRef * ref) {
        if (again.status == kOk && again.log10_height_mm == again.log10_height_mm) out.est = again;
        return out;
      }
    }
  }
  if (missing == 0) {
    const TwinEstimate all = fine_estimate(feats, usable, out.est.x_mm, out.est.y_mm, map, cfg);
    if (all.status == kOk && all.log10_height_mm == all.log10_height_mm && !(all.misfit > kBadMisfitRef * ref)) {
      const TwinEstimate whole = cfg.coarse_cutoff_mm > 0.0f
                                     ? twin_estimate(feats, usable, out.est.x_mm, out.est.y_mm, map, cfg)
                                     : all;
      out.est = whole.status == kOk && whole.log10_height_mm == whole.log10_height_mm ? whole : all;
      out.left_out = -1;
      out.reason = kTwinAllChannels;
      return out;
    }
  }
  if (best_terms != nullptr) {
    recentre_kept(*best_terms, best_mask, map, cfg, &out.est);
  } else {
    recentre_fine(feats, best_mask, map, cfg, &out.est);
  }
  return out;
}

}  // namespace impactcore
