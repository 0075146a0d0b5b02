// Physics localiser: time-difference-of-arrival least squares, robust and bounded to the plate.
// Per iteration: four distances (one VSQRT each on the M4F), a symmetric 3x3 normal matrix, one LDL^T solve.
#include <math.h>

#include "impactcore.h"

namespace impactcore {
namespace {

// sqrt(dx^2 + dy^2): IEEE square root, the FPU instruction on the M4F (hypotf and a libm sqrtf call cost
// ~40 and ~25 instructions there; no overflow to guard against at plate scale).
inline float dist(float dx, float dy) {
  const float q = dx * dx + dy * dy;
#if defined(__ARM_FP) && (__ARM_FP & 4) && defined(__thumb2__)
  float r;
  __asm__("vsqrt.f32 %0, %1" : "=t"(r) : "t"(q));
  return r;
#else
  return sqrtf(q);
#endif
}

float clampf(float v, float lo, float hi) { return v < lo ? lo : (v > hi ? hi : v); }

// Solves a x = b for a symmetric positive definite 3x3 a, given as its upper triangle
// (a00 a01 a02 a11 a12 a22), by LDL^T. False when a pivot is not positive (singular / indefinite).
bool solve_spd3(const float a[6], const float b[3], float x[3]) {
  const float d0 = a[0];
  if (!(d0 > 1e-12f)) return false;
  const float l10 = a[1] / d0;
  const float l20 = a[2] / d0;
  const float d1 = a[3] - l10 * a[1];
  if (!(d1 > 1e-12f)) return false;
  const float l21 = (a[4] - l20 * a[1]) / d1;
  const float d2 = a[5] - l20 * a[2] - l21 * l21 * d1;
  if (!(d2 > 1e-12f)) return false;
  const float y1 = b[1] - l10 * b[0];
  const float y2 = b[2] - l20 * b[0] - l21 * y1;
  x[2] = y2 / d2;
  x[1] = y1 / d1 - l21 * x[2];
  x[0] = b[0] / d0 - l10 * x[1] - l20 * x[2];
  return true;
}

// The used channels, gathered: toa and sensor position of channel idx[k] at k.
struct Problem {
  float toa[kChannels];
  float sx[kChannels];
  float sy[kChannels];
  int m;
  float v;
  float inv_v;
  float inv_vk[kChannels];  // per used channel: inv_v x its slowness scale (inv_v itself without one)
  float huber;
  int max_evaluations;   // a start's normal-equation evaluations (kMaxEvaluations, or fewer when asked)
  float lx, ly;
  bool iso;              // no travel metric: plain distances (bit for bit the isotropic localiser)
  float qxx, qxy, qyy;   // travel metric (impactcore.h travel_metric_*)
};

#if defined(__GNUC__)
#define IC_INLINE inline __attribute__((always_inline))
#else
#define IC_INLINE inline
#endif

// The functions below are templates on the problem's shape: M used channels (0: p.m, read at run time) and
// kIso (true: no travel metric; false: p.iso read at run time). localise_tdoa runs <4, true> for the
// usual event (four channels, isotropic plate: loops of a known length, unrolled, no metric tests), <4, false>
// for four channels on an anisotropic plate (a laminate's travel metric), <3, true> / <3, false> likewise for three
// (a channel without an onset, or the channel check's flagged channel left out) and <0, false> otherwise; all do
// the same float operations in the same order, so the same numbers.
template <int M>
IC_INLINE int used(const Problem& p) { return M > 0 ? M : p.m; }

// The travel distance sqrt(d^T Q d) of the offset (dx, dy) from a sensor (the Euclidean one when iso).
template <bool kIso>
IC_INLINE float travel(const Problem& p, float dx, float dy) {
  if (kIso || p.iso) return dist(dx, dy);
  const float q = p.qxx * dx * dx + 2.0f * p.qxy * dx * dy + p.qyy * dy * dy;
  return vsqrt_f32(q > 0.0f ? q : 0.0f);
}

// The ToA residuals r[k] = toa[k] - |(x, y) - sensor k| / v; returns their mean (the least-squares t0).
template <int M, bool kIso>
IC_INLINE float residuals(const Problem& p, float x, float y, float* r) {
  float mean = 0.0f;
  for (int k = 0; k < used<M>(p); ++k) {
    r[k] = p.toa[k] - travel<kIso>(p, x - p.sx[k], y - p.sy[k]) * p.inv_vk[k];
    mean += r[k];
  }
  return mean / static_cast<float>(used<M>(p));
}

// Huber cost of (x, y) with t0 at its weighted optimum; also returns that t0.
template <int M, bool kIso>
float huber_cost(const Problem& p, float x, float y, float* t0_out) {
  float r[kChannels];
  float t0 = residuals<M, kIso>(p, x, y, r);
  // Two reweighting passes for t0 (the median-like centre under Huber weights).
  for (int pass = 0; pass < 2; ++pass) {
    float sw = 0.0f, swr = 0.0f;
    for (int k = 0; k < used<M>(p); ++k) {
      const float e = fabsf(r[k] - t0);
      const float w = e <= p.huber ? 1.0f : p.huber / e;
      sw += w;
      swr += w * r[k];
    }
    t0 = swr / sw;
  }
  float cost = 0.0f;
  for (int k = 0; k < used<M>(p); ++k) {
    const float e = fabsf(r[k] - t0);
    cost += e <= p.huber ? 0.5f * e * e : p.huber * (e - 0.5f * p.huber);
  }
  *t0_out = t0;
  return cost;
}

// Sum of squared ToA residuals at (x, y) with t0 at its least-squares value (the residuals' mean).
template <int M, bool kIso>
IC_INLINE float l2_cost(const Problem& p, float x, float y) {
  float r[kChannels];
  const float mean = residuals<M, kIso>(p, x, y, r);
  float ss = 0.0f;
  for (int k = 0; k < used<M>(p); ++k) ss += (r[k] - mean) * (r[k] - mean);
  return ss;
}

// The Huber loss at (x, y, t0) and the IRLS normal equations there: a = J^T W J (upper triangle),
// g = J^T W e, W the Huber weights (w e = psi(e), so g is the loss's descent direction).
struct Normal {
  float a[6];
  float g[3];
  float cost;
};

// With M > 0 and kIso false the plate has a travel metric for certain (localise_tdoa runs <4, false> and
// <3, false> only then): the metric's constants are held in registers and the products qxx dx and qyy dy,
// which travel() and the Jacobian both take, are taken once. The same float operations on the same operands
// in the same order as travel<false> and the general form (2 qxy is exact), so the same numbers.
template <int M, bool kIso>
void normal_eqs(const Problem& p, float x, float y, float t0, Normal* ne) {
  constexpr bool kMetric = !kIso && M > 0;
  const float qxx = p.qxx, qxy = p.qxy, qyy = p.qyy, q2xy = 2.0f * p.qxy;
  const float huber = p.huber, half_huber = 0.5f * p.huber;
  float a0 = 0, a1 = 0, a2 = 0, a3 = 0, a4 = 0, a5 = 0, g0 = 0, g1 = 0, g2 = 0, cost = 0;
  for (int k = 0; k < used<M>(p); ++k) {
    const float dx = x - p.sx[k];
    const float dy = y - p.sy[k];
    float d, jxs, jys;  // jxs, jys: the Jacobian's numerators (times s below)
    if (kMetric) {
      const float ax = qxx * dx, cy = qyy * dy;
      const float q = ax * dx + q2xy * dx * dy + cy * dy;
      d = vsqrt_f32(q > 0.0f ? q : 0.0f);
      jxs = ax + qxy * dy;
      jys = qxy * dx + cy;
    } else {
      d = travel<kIso>(p, dx, dy);
      jxs = (kIso || p.iso) ? dx : p.qxx * dx + p.qxy * dy;
      jys = (kIso || p.iso) ? dy : p.qxy * dx + p.qyy * dy;
    }
    if (d < 1e-3f) d = 1e-3f;
    const float e = p.toa[k] - (t0 + d * p.inv_vk[k]);
    const float ae = fabsf(e);
    float w = 1.0f;
    if (ae <= huber) {
      cost += 0.5f * e * e;
    } else {
      w = huber / ae;
      cost += huber * (ae - half_huber);
    }
    const float s = p.inv_vk[k] / d;
    // d(model)/dx, d(model)/dy (Q d / |d|_Q / v; d / |d| / v when iso); d(model)/dt0 = 1
    const float jx = jxs * s;
    const float jy = jys * s;
    const float wjx = w * jx;
    const float wjy = w * jy;
    a0 += wjx * jx;
    a1 += wjx * jy;
    a2 += wjx;
    a3 += wjy * jy;
    a4 += wjy;
    a5 += w;
    g0 += wjx * e;
    g1 += wjy * e;
    g2 += w * e;
  }
  ne->a[0] = a0;
  ne->a[1] = a1;
  ne->a[2] = a2;
  ne->a[3] = a3;
  ne->a[4] = a4;
  ne->a[5] = a5;
  ne->g[0] = g0;
  ne->g[1] = g1;
  ne->g[2] = g2;
  ne->cost = cost;
}

// Gauss-Newton iterations from the screened start; a step that moves the position less than this ends them.
// At most kMaxIterations: the cost of an event is bounded, and the drops that would iterate longer are the
// poorly fitting ones, whose IRLS creeps along a flat Huber valley away from the impact: at the board rate
// the physics position's error falls as the cap falls (docs/findings.md, "The per-event cost"), at the
// rig's 100 kHz the picks fit and nearly every drop stops before the cap.
constexpr int kMaxIterations = 6;
// ... and at most kMaxEvaluations normal-equation evaluations a start (the two at the start included; the
// step halvings count): bounded by the iterations alone (2 + 7 kMaxIterations = 44) the localiser was the
// event's largest data-dependent cost on an anisotropic plate; the bundled drops stop before this cap, so
// their results are those without it (docs/findings.md, "The event budget's worst case").
constexpr int kMaxEvaluations = 16;
constexpr float kStepTolMm = 0.01f;
// Screening grid: the Huber cost at the centres of kGrid x kGrid cells over the plate.
constexpr int kGrid = 4;
constexpr float kCornerInset = 0.04f;  // of the plate size

// IRLS Gauss-Newton from (x, y) with step halving: a step that raises the Huber loss is halved (up to 6
// times), so the iteration cannot cycle (undamped IRLS can flip t0 back and forth between two Huber weight
// patterns); full steps, the usual case, are plain Gauss-Newton. Returns the Huber cost at the end (t0
// the Gauss-Newton one) and J^T W J there (upper triangle); *evals counts the normal-equation evaluations.
template <int M, bool kIso>
float refine(const Problem& p, float* x_io, float* y_io, float* t0_io, int* iters, int* evals, float jtj[6]) {
  const int limit = *evals + p.max_evaluations;
  float x = *x_io, y = *y_io, t0 = 0.0f;
  huber_cost<M, kIso>(p, x, y, &t0);
  Normal ne;
  normal_eqs<M, kIso>(p, x, y, t0, &ne);
  ++*evals;
  ++*evals;
  int it = 0;
  for (it = 0; it < kMaxIterations; ++it) {
    float a[6];
    for (int q = 0; q < 6; ++q) a[q] = ne.a[q];
    a[0] = a[0] * (1.0f + 1e-4f) + 1e-9f;
    a[3] = a[3] * (1.0f + 1e-4f) + 1e-9f;
    a[5] = a[5] * (1.0f + 1e-4f) + 1e-9f;
    float step[3];
    if (!solve_spd3(a, ne.g, step)) break;
    Normal trial;
    float nx = x, ny = y, nt0 = t0, moved = 0.0f;
    bool accepted = false;
    float lam = 1.0f;
    for (int h = 0; h < 7 && !accepted && *evals < limit; ++h, lam *= 0.5f) {
      nx = clampf(x + lam * step[0], 0.0f, p.lx);
      ny = clampf(y + lam * step[1], 0.0f, p.ly);
      nt0 = t0 + lam * step[2];
      moved = fabsf(nx - x) + fabsf(ny - y);
      normal_eqs<M, kIso>(p, nx, ny, nt0, &trial);
      ++*evals;
      accepted = trial.cost <= ne.cost || moved < kStepTolMm;
    }
    if (!accepted) break;  // no decrease along the step (a minimum to float precision) or no evaluation left
    x = nx;
    y = ny;
    t0 = nt0;
    ne = trial;
    if (moved < kStepTolMm) {
      ++it;
      break;
    }
  }
  for (int q = 0; q < 6; ++q) jtj[q] = ne.a[q];
  *x_io = x;
  *y_io = y;
  *t0_io = t0;
  *iters = it;
  return ne.cost;
}

// The screening's cost at a point: l2_cost<M, kIso>. For the usual four-channel isotropic problem, the same
// operations in the same order with the channels' constants held in registers over the 20 points.
template <int M, bool kIso>
struct ScreenCost {
  const Problem& p;
  explicit ScreenCost(const Problem& problem) : p(problem) {}
  IC_INLINE float operator()(float x, float y) const { return l2_cost<M, kIso>(p, x, y); }
};
// Four residuals' sum of squares about their mean, in l2_cost's order of operations.
IC_INLINE float centred_ss4(float r0, float r1, float r2, float r3) {
  const float mean = ((((0.0f + r0) + r1) + r2) + r3) / 4.0f;
  float ss = 0.0f;
  ss += (r0 - mean) * (r0 - mean);
  ss += (r1 - mean) * (r1 - mean);
  ss += (r2 - mean) * (r2 - mean);
  ss += (r3 - mean) * (r3 - mean);
  return ss;
}

template <>
struct ScreenCost<4, true> {
  float t0, t1, t2, t3, x0, x1, x2, x3, y0, y1, y2, y3, v0, v1, v2, v3;
  explicit ScreenCost(const Problem& p)
      : t0(p.toa[0]), t1(p.toa[1]), t2(p.toa[2]), t3(p.toa[3]), x0(p.sx[0]), x1(p.sx[1]), x2(p.sx[2]),
        x3(p.sx[3]), y0(p.sy[0]), y1(p.sy[1]), y2(p.sy[2]), y3(p.sy[3]), v0(p.inv_vk[0]), v1(p.inv_vk[1]),
        v2(p.inv_vk[2]), v3(p.inv_vk[3]) {}
  IC_INLINE float operator()(float x, float y) const {
    const float r0 = t0 - dist(x - x0, y - y0) * v0;
    const float r1 = t1 - dist(x - x1, y - y1) * v1;
    const float r2 = t2 - dist(x - x2, y - y2) * v2;
    const float r3 = t3 - dist(x - x3, y - y3) * v3;
    return centred_ss4(r0, r1, r2, r3);
  }
};

// The four-channel anisotropic problem (localise_tdoa runs <4, false> only with a travel metric, p.iso
// false): the same operations as l2_cost<4, false> in the same order, the metric and the channels'
// constants in registers over the 20 points.
template <>
struct ScreenCost<4, false> {
  float qxx, qxy2, qyy, t0, t1, t2, t3, x0, x1, x2, x3, y0, y1, y2, y3, v0, v1, v2, v3;
  explicit ScreenCost(const Problem& p)
      : qxx(p.qxx), qxy2(2.0f * p.qxy), qyy(p.qyy), t0(p.toa[0]), t1(p.toa[1]), t2(p.toa[2]), t3(p.toa[3]),
        x0(p.sx[0]), x1(p.sx[1]), x2(p.sx[2]), x3(p.sx[3]), y0(p.sy[0]), y1(p.sy[1]), y2(p.sy[2]),
        y3(p.sy[3]), v0(p.inv_vk[0]), v1(p.inv_vk[1]), v2(p.inv_vk[2]), v3(p.inv_vk[3]) {}
  IC_INLINE float metric(float dx, float dy) const {
    const float q = qxx * dx * dx + qxy2 * dx * dy + qyy * dy * dy;
    return vsqrt_f32(q > 0.0f ? q : 0.0f);
  }
  IC_INLINE float operator()(float x, float y) const {
    const float r0 = t0 - metric(x - x0, y - y0) * v0;
    const float r1 = t1 - metric(x - x1, y - y1) * v1;
    const float r2 = t2 - metric(x - x2, y - y2) * v2;
    const float r3 = t3 - metric(x - x3, y - y3) * v3;
    return centred_ss4(r0, r1, r2, r3);
  }
};

// Three residuals' sum of squares about their mean, in l2_cost's order of operations.
IC_INLINE float centred_ss3(float r0, float r1, float r2) {
  const float mean = (((0.0f + r0) + r1) + r2) / 3.0f;
  float ss = 0.0f;
  ss += (r0 - mean) * (r0 - mean);
  ss += (r1 - mean) * (r1 - mean);
  ss += (r2 - mean) * (r2 - mean);
  return ss;
}

// Three channels (one without an onset, or left out: the three-sensor position), as the four-channel forms above:
// localise_tdoa runs <3, true> without a travel metric, <3, false> with one.
template <>
struct ScreenCost<3, true> {
  float t0, t1, t2, x0, x1, x2, y0, y1, y2, v0, v1, v2;
  explicit ScreenCost(const Problem& p)
      : t0(p.toa[0]), t1(p.toa[1]), t2(p.toa[2]), x0(p.sx[0]), x1(p.sx[1]), x2(p.sx[2]), y0(p.sy[0]),
        y1(p.sy[1]), y2(p.sy[2]), v0(p.inv_vk[0]), v1(p.inv_vk[1]), v2(p.inv_vk[2]) {}
  IC_INLINE float operator()(float x, float y) const {
    const float r0 = t0 - dist(x - x0, y - y0) * v0;
    const float r1 = t1 - dist(x - x1, y - y1) * v1;
    const float r2 = t2 - dist(x - x2, y - y2) * v2;
    return centred_ss3(r0, r1, r2);
  }
};

template <>
struct ScreenCost<3, false> {
  float qxx, qxy2, qyy, t0, t1, t2, x0, x1, x2, y0, y1, y2, v0, v1, v2;
  explicit ScreenCost(const Problem& p)
      : qxx(p.qxx), qxy2(2.0f * p.qxy), qyy(p.qyy), t0(p.toa[0]), t1(p.toa[1]), t2(p.toa[2]), x0(p.sx[0]),
        x1(p.sx[1]), x2(p.sx[2]), y0(p.sy[0]), y1(p.sy[1]), y2(p.sy[2]), v0(p.inv_vk[0]), v1(p.inv_vk[1]),
        v2(p.inv_vk[2]) {}
  IC_INLINE float metric(float dx, float dy) const {
    const float q = qxx * dx * dx + qxy2 * dx * dy + qyy * dy * dy;
    return vsqrt_f32(q > 0.0f ? q : 0.0f);
  }
  IC_INLINE float operator()(float x, float y) const {
    const float r0 = t0 - metric(x - x0, y - y0) * v0;
    const float r1 = t1 - metric(x - x1, y - y1) * v1;
    const float r2 = t2 - metric(x - x2, y - y2) * v2;
    return centred_ss3(r0, r1, r2);
  }
};

// The screening and the refinement from the best screened start(s) (localise_tdoa): the position, t0,
// J^T W J there, the iterations and evaluations, and the sum of squared ToA residuals at the end.
struct Solution {
  float x, y, t0, ss;
  int iterations, evaluations;
};
template <int M, bool kIso>
Solution solve(const Problem& p, int starts, float plate_x_mm, float plate_y_mm, float jtj[6]) {
  const int n_starts = starts < 1 ? 1 : (starts > kMaxStarts ? kMaxStarts : starts);
  float cand_x[kMaxStarts], cand_y[kMaxStarts], cand_cost[kMaxStarts];
  for (int s = 0; s < kMaxStarts; ++s) {
    cand_x[s] = 0.5f * plate_x_mm;
    cand_y[s] = 0.5f * plate_y_mm;
    cand_cost[s] = INFINITY;
  }
  // The cell centres, then the plate's corners inset by kCornerInset (out beyond a sensor the cost valley
  // from a cell centre is flat: without these, noisy picks there could end at the sensor).
  const ScreenCost<M, kIso> l2_cost_at(p);
  for (int q = 0; q < kGrid * kGrid + 4; ++q) {
    float fx, fy;
    if (q < kGrid * kGrid) {
      fx = (static_cast<float>(q / kGrid) + 0.5f) / kGrid;
      fy = (static_cast<float>(q % kGrid) + 0.5f) / kGrid;
    } else {
      fx = (q - kGrid * kGrid) & 1 ? 1.0f - kCornerInset : kCornerInset;
      fy = (q - kGrid * kGrid) & 2 ? 1.0f - kCornerInset : kCornerInset;
    }
    const float gx = fx * plate_x_mm, gy = fy * plate_y_mm;
    const float c = l2_cost_at(gx, gy);
    if (c < cand_cost[n_starts - 1]) {
      int j = n_starts - 1;
      while (j > 0 && c < cand_cost[j - 1]) {
        cand_x[j] = cand_x[j - 1];
        cand_y[j] = cand_y[j - 1];
        cand_cost[j] = cand_cost[j - 1];
        --j;
      }
      cand_x[j] = gx;
      cand_y[j] = gy;
      cand_cost[j] = c;
    }
  }
  float x = cand_x[0], y = cand_y[0], t0 = 0.0f;
  int iterations = 0, evaluations = 0;
  float best = refine<M, kIso>(p, &x, &y, &t0, &iterations, &evaluations, jtj);
  for (int s = 1; s < n_starts && cand_cost[s] < INFINITY; ++s) {
    float sx = cand_x[s], sy = cand_y[s], st0 = 0.0f, sj[6];
    int it = 0;
    const float cost = refine<M, kIso>(p, &sx, &sy, &st0, &it, &evaluations, sj);
    if (cost < best) {
      best = cost;
      x = sx;
      y = sy;
      t0 = st0;
      iterations = it;
      for (int q = 0; q < 6; ++q) jtj[q] = sj[q];
    }
  }
  float ss = 0.0f;
  for (int k = 0; k < used<M>(p); ++k) {
    const float e = p.toa[k] - (t0 + travel<kIso>(p, x - p.sx[k], y - p.sy[k]) * p.inv_vk[k]);
    ss += e * e;
  }
  return Solution{x, y, t0, ss, iterations, evaluations};
}

// The posterior mean of the position (localise_tdoa's posterior_grid): exp(-H / sigma^2) over an n x n grid on
// the fit's +-kPosteriorSpan sd box clipped to the plate, H the Huber cost with t0 at its optimum. The weights
// are accumulated against the lowest cost so far (rescaled when it falls), so nothing is stored. res keeps
// the fit's position when the covariance is not finite or no weight is positive.
void posterior_mean(const Problem& p, int n, float sigma_us, LocaliserResult* res) {
  if (n > kMaxPosteriorGrid) n = kMaxPosteriorGrid;
  const float sx = sqrtf(res->cov_xx), sy = sqrtf(res->cov_yy);
  if (!(sx > 0.0f) || !(sy > 0.0f) || !(sx < INFINITY) || !(sy < INFINITY) || !(sigma_us > 0.0f)) return;
  const float x0 = clampf(res->x_mm - kPosteriorSpan * sx, 0.0f, p.lx);
  const float x1 = clampf(res->x_mm + kPosteriorSpan * sx, 0.0f, p.lx);
  const float y0 = clampf(res->y_mm - kPosteriorSpan * sy, 0.0f, p.ly);
  const float y1 = clampf(res->y_mm + kPosteriorSpan * sy, 0.0f, p.ly);
  const float inv_s2 = 1.0f / (sigma_us * sigma_us);
  const float step_x = (x1 - x0) / static_cast<float>(n - 1), step_y = (y1 - y0) / static_cast<float>(n - 1);
  float lowest = INFINITY, sw = 0.0f, swx = 0.0f, swy = 0.0f;
  for (int i = 0; i < n; ++i) {
    const float gx = x0 + step_x * static_cast<float>(i);
    for (int j = 0; j < n; ++j) {
      const float gy = y0 + step_y * static_cast<float>(j);
      float t0;
      const float cost = huber_cost<0, false>(p, gx, gy, &t0);
      if (!(cost == cost)) continue;
      if (cost < lowest) {
        const float rescale = lowest < INFINITY ? exp_nonpositive((cost - lowest) * inv_s2) : 0.0f;
        sw *= rescale;
        swx *= rescale;
        swy *= rescale;
        lowest = cost;
      }
      const float w = exp_nonpositive((lowest - cost) * inv_s2);
      sw += w;
      swx += w * gx;
      swy += w * gy;
    }
  }
  if (!(sw > 0.0f)) return;
  res->x_mm = swx / sw;
  res->y_mm = swy / sw;
}

}  // namespace

LocaliserResult localise_tdoa(const float toa_us[kChannels], const uint8_t use[kChannels],
                              const float sensor_x_mm[kChannels], const float sensor_y_mm[kChannels],
                              float velocity_mm_per_us, float sigma_us, float plate_x_mm,
                              float plate_y_mm, float huber_us, const float* travel_metric,
                              const float* slowness_scale, int starts, int posterior_grid, int max_evaluations) {
  LocaliserResult res;
  clear_result(&res);
  res.status = kOk;
  Problem p;
  p.iso = travel_metric == nullptr ||
          (travel_metric[0] == 1.0f && travel_metric[1] == 0.0f && travel_metric[2] == 1.0f);
  p.qxx = travel_metric ? travel_metric[0] : 1.0f;
  p.qxy = travel_metric ? travel_metric[1] : 0.0f;
  p.qyy = travel_metric ? travel_metric[2] : 1.0f;
  p.m = 0;
  p.v = velocity_mm_per_us;
  p.inv_v = 1.0f / velocity_mm_per_us;
  p.huber = huber_us > 0.0f ? huber_us : 1e-3f;
  p.max_evaluations = max_evaluations > 0 && max_evaluations < kMaxEvaluations ? max_evaluations : kMaxEvaluations;
  p.lx = plate_x_mm;
  p.ly = plate_y_mm;
  for (int c = 0; c < kChannels; ++c) {
    if (use[c] && toa_us[c] == toa_us[c]) {
      p.toa[p.m] = toa_us[c];
      p.sx[p.m] = sensor_x_mm[c];
      p.sy[p.m] = sensor_y_mm[c];
      p.inv_vk[p.m] = slowness_scale ? p.inv_v * slowness_scale[c] : p.inv_v;
      ++p.m;
    }
  }
  const bool metric_ok = p.qxx > 0.0f && p.qyy > 0.0f && p.qxx * p.qyy > p.qxy * p.qxy;
  if (p.m < 3 || !metric_ok || !(velocity_mm_per_us > 0.0f) || !(plate_x_mm > 0.0f) || !(plate_y_mm > 0.0f)) {
    res.status = p.m < 3 && metric_ok ? kErrTooFewSamples : kErrBadConfig;
    res.x_mm = res.y_mm = res.t0_us = NAN;
    res.cov_xx = res.cov_xy = res.cov_yy = NAN;
    res.rms_residual_us = NAN;
    return res;
  }
  // One start, screened by the sum of squared ToA residuals (t0 their mean; ~60 instructions a point):
  // the kGrid x kGrid cell centres and four inset corners. It finds the basin the former six starts (the
  // closed-form range-difference solution, the centre, four quadrant centres, each run to convergence, the
  // lowest Huber cost kept) found, and where they disagree it does better (docs/findings.md). Cost: 20
  // screens and at most 1 + 7 kMaxIterations normal-equation evaluations, instead of up to six Gauss-Newton
  // runs of 25 iterations.
  // The `starts` lowest-cost screening points (kept in order, ties in screening order) are each refined
  // and the lowest Huber cost wins; starts = 1 is the single start above, bit for bit.
  float jtj[6];
  const float lx = plate_x_mm, ly = plate_y_mm;
  const Solution sol =
      p.m == 4   ? (p.iso ? solve<4, true>(p, starts, lx, ly, jtj) : solve<4, false>(p, starts, lx, ly, jtj))
      : p.m == 3 ? (p.iso ? solve<3, true>(p, starts, lx, ly, jtj) : solve<3, false>(p, starts, lx, ly, jtj))
                 : solve<0, false>(p, starts, lx, ly, jtj);
  const float x = sol.x, y = sol.y, t0 = sol.t0, ss = sol.ss;
  const int iterations = sol.iterations, evaluations = sol.evaluations;
  res.x_mm = x;
  res.y_mm = y;
  res.t0_us = t0;
  res.rms_residual_us = vsqrt_f32(ss / static_cast<float>(p.m));
  res.iterations = iterations;
  res.evaluations = evaluations;
  // Covariance of (x, y): sigma^2 times the (x, y) block of (J^T W J)^-1.
  float cov[2][2] = {{NAN, NAN}, {NAN, NAN}};
  for (int col = 0; col < 2; ++col) {
    const float e[3] = {col == 0 ? 1.0f : 0.0f, col == 1 ? 1.0f : 0.0f, 0.0f};
    float inv_col[3];
    if (solve_spd3(jtj, e, inv_col)) {
      cov[0][col] = inv_col[0];
      cov[1][col] = inv_col[1];
    }
  }
  const float s2 = sigma_us * sigma_us;
  res.cov_xx = s2 * cov[0][0];
  res.cov_xy = s2 * 0.5f * (cov[0][1] + cov[1][0]);
  res.cov_yy = s2 * cov[1][1];
  if (posterior_grid > 1) posterior_mean(p, posterior_grid, sigma_us, &res);
  return res;
}

}  // namespace impactcore
