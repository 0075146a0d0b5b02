// The baseline of a channel: a level and a noise floor from the quiet start of the capture that a glitch
// cannot move, and a mains-hum model fitted to the whole capture (impactcore.h, "baseline").
//
// Cost: a few group sums read from the prefix table (no pass over the samples): the baseline segment in
// four parts, the capture in groups of kHumGroupBlocks blocks; the 50 and 60 Hz fits only where a bound on
// what they could explain (the groups' weighted spread) does not already rule a hum out.
#include <math.h>
#include <stdint.h>
#include <string.h>
#if defined(__ARM_FEATURE_DSP) && defined(__ARM_FEATURE_SIMD32) && !defined(__linux__)
#include <arm_acle.h>
#endif

#include "impactcore.h"

namespace impactcore {

void sin_cos(float a, float* s, float* c) {
  // a reduced to [-pi, pi], then to [-pi/2, pi/2] by sin(pi - a) = sin a, cos(pi - a) = -cos a; odd and
  // even Taylor series to a^11 and a^12: |error| < 1e-6 there.
  constexpr float kPi = 3.14159265f, kTwoPi = 6.28318531f;
  const float turns = a * (1.0f / kTwoPi);
  a -= kTwoPi * static_cast<float>(floor_to_int(turns + 0.5f));
  float sign_c = 1.0f;
  if (a > 0.5f * kPi) {
    a = kPi - a;
    sign_c = -1.0f;
  } else if (a < -0.5f * kPi) {
    a = -kPi - a;
    sign_c = -1.0f;
  }
  const float a2 = a * a;
  *s = a * (1.0f - a2 / 6.0f * (1.0f - a2 / 20.0f * (1.0f - a2 / 42.0f * (1.0f - a2 / 72.0f * (1.0f - a2 / 110.0f)))));
  *c = sign_c * (1.0f - a2 / 2.0f * (1.0f - a2 / 12.0f * (1.0f - a2 / 30.0f * (1.0f - a2 / 56.0f * (1.0f - a2 / 90.0f * (1.0f - a2 / 132.0f))))));
}

namespace {

// sum (x - c)^2 over a range, exact, as float (c an integer near the level).
float centred_s2(const Sums& s, int m, int32_t c) {
  return int64_to_float(s.s2 - 2 * static_cast<int64_t>(c) * s.s1 + static_cast<int64_t>(m) * c * c);
}

// Weighted least squares of y_g = c0 + c1 D cos(w t_g) + c2 D sin(w t_g) over the groups (D: a group's
// mean of a unit sinusoid). Returns the weighted residual sum of squares; coef[3] the solution.
struct HumFit {
  float a[6] = {0, 0, 0, 0, 0, 0};  // normal matrix (00, 01, 02, 11, 12, 22)
  float r[3] = {0, 0, 0};
  float yy = 0.0f;
  void add(float w, float y, float c, float s) {
    const float wc = w * c, ws = w * s;
    a[0] += w;
    a[1] += wc;
    a[2] += ws;
    a[3] += wc * c;
    a[4] += wc * s;
    a[5] += ws * s;
    r[0] += w * y;
    r[1] += wc * y;
    r[2] += ws * y;
    yy += w * y * y;
  }
  // Cramer's rule on the symmetric 3 x 3 system; false when singular.
  bool solve(float coef[3], float* rss, float* var12) const {
    const float m00 = a[3] * a[5] - a[4] * a[4], m01 = a[2] * a[4] - a[1] * a[5], m02 = a[1] * a[4] - a[2] * a[3];
    const float det = a[0] * m00 + a[1] * m01 + a[2] * m02;
    if (!(fabsf(det) > 1e-12f * (a[0] * a[3] * a[5] + 1e-30f))) return false;
    const float m11 = a[0] * a[5] - a[2] * a[2], m12 = a[1] * a[2] - a[0] * a[4], m22 = a[0] * a[3] - a[1] * a[1];
    const float inv = 1.0f / det;
    coef[0] = (m00 * r[0] + m01 * r[1] + m02 * r[2]) * inv;
    coef[1] = (m01 * r[0] + m11 * r[1] + m12 * r[2]) * inv;
    coef[2] = (m02 * r[0] + m12 * r[1] + m22 * r[2]) * inv;
    *rss = yy - (coef[0] * r[0] + coef[1] * r[1] + coef[2] * r[2]);
    *var12 = (m11 + m22) * inv;  // trace of the (c1, c2) block of the inverse normal matrix
    return true;
  }
};

// The baseline segment in kBaselineParts parts; a part whose variance about its own mean exceeds
// kGlitchVarianceRatio x the quietest part's (+ 1 count^2) holds a glitch (or the onset) and is left out.
constexpr int kBaselineParts = 4;
constexpr float kGlitchVarianceRatio = 16.0f;

void robust_level(const int16_t* x, const Sums* prefix, int n, int nb, Baseline* out) {
  Sums part[kBaselineParts];
  int len[kBaselineParts];
  float var[kBaselineParts];
  float vmin = INFINITY;
  // The parts' boundaries' prefix sums once each (a part ends where the next begins).
  Sums at = prefix_at(x, prefix, n, 0);
  for (int p = 0; p < kBaselineParts; ++p) {
    const int a = nb * p / kBaselineParts, b = nb * (p + 1) / kBaselineParts;
    const Sums next = prefix_at(x, prefix, n, b);
    part[p] = Sums{next.s2 - at.s2, next.s1 - at.s1};
    at = next;
    len[p] = b - a;
    const int32_t c = len[p] > 0 ? part[p].s1 / len[p] : 0;
    var[p] = len[p] > 0 ? centred_s2(part[p], len[p], c) / static_cast<float>(len[p]) : 0.0f;
    const float mc = len[p] > 0 ? static_cast<float>(part[p].s1 - c * len[p]) / static_cast<float>(len[p]) : 0.0f;
    var[p] -= mc * mc;
    if (var[p] < vmin) vmin = var[p];
  }
  Sums kept = {0, 0};
  int m = 0;
  float within = 0.0f;
  out->glitch_parts = 0;
  for (int p = 0; p < kBaselineParts; ++p) {
    if (var[p] > kGlitchVarianceRatio * vmin + 1.0f) {
      out->glitch_parts |= 1 << p;
      continue;
    }
    kept.s1 += part[p].s1;
    kept.s2 += part[p].s2;
    m += len[p];
    within += var[p] * static_cast<float>(len[p]);
  }
  out->kept = kept;
  out->kept_n = m;
  baseline_from_sums(kept, m, &out->level, &out->noise_rms);
  out->within_rms = m > kBaselineParts ? vsqrt_f32(within / static_cast<float>(m - kBaselineParts)) : out->noise_rms;
}

}  // namespace

namespace {
// sum over i in [a, e) of (2 i - (a + e - 1)) x[i], the part's first moment about its centre (the same int32 sum
// either way; on the M4F two samples a SMLAD: the weights of a pair packed as two int16, stepped by 4 each).
int32_t centred_moment(const int16_t* x, int a, int e) {
  int32_t sxt = 0;
  int i = a;
#if defined(__ARM_FEATURE_DSP) && defined(__ARM_FEATURE_SIMD32) && !defined(__linux__)
  if (e - a < 32768) {
    const int32_t w0 = 2 * a - (a + e - 1);  // weight of x[a]; |w| < 2^15
    uint32_t w = (static_cast<uint32_t>(static_cast<uint16_t>(w0 + 2)) << 16) | static_cast<uint16_t>(w0);
    for (; i + 1 < e; i += 2) {
      uint32_t pair;
      memcpy(&pair, x + i, sizeof(pair));  // x[i] low, x[i + 1] high (little-endian)
      sxt = __smlad(pair, w, sxt);
      w = __sadd16(w, 0x00040004u);  // both weights + 4, each in its own halfword (|w| < 2^15: no wrap)
    }
  }
#endif
  for (; i < e; ++i) sxt += (2 * i - (a + e - 1)) * static_cast<int32_t>(x[i]);
  return sxt;
}
}  // namespace

float hum_noise_rms(const int16_t* x, const Baseline& b, int nb) {
  // robust_level: within_rms^2 (m - kBaselineParts) = sum over the kept parts of their squares about their
  // means. Each part's line takes Sxt^2 / Stt of that out, t = 2 i - (a + e - 1) (integers), Stt =
  // L (L^2 - 1) / 3, so sigma^2 = (that sum - sum Sxt^2 / Stt) / (m - 2 parts): one multiply-add a sample.
  float explained = 0.0f;
  int m = 0, parts = 0;
  for (int p = 0; p < kBaselineParts; ++p) {
    if (b.glitch_parts & (1 << p)) continue;
    const int a = nb * p / kBaselineParts, e = nb * (p + 1) / kBaselineParts, len = e - a;
    const int32_t sxt = centred_moment(x, a, e);
    const float l = static_cast<float>(len), st = static_cast<float>(sxt);
    if (len > 1) explained += st * st / (l * (l * l - 1.0f) / 3.0f);
    m += len;
    ++parts;
  }
  const float v = b.within_rms * b.within_rms;
  if (m - 2 * parts < 2 || m <= kBaselineParts) return b.within_rms;
  const float noise = (v * static_cast<float>(m - kBaselineParts) - explained) / static_cast<float>(m - 2 * parts);
  return vsqrt_f32(noise > 0.1f * v ? noise : 0.1f * v);
}

void HumBasis::set(float fs) {
  constexpr int kGroup = kHumGroupBlocks * kBlock;
  fs_hz = fs;
  for (int f = 0; f < 2; ++f) {
    w[f] = 6.28318531f * kMainsHz[f] / fs;
    sin_cos(w[f] * static_cast<float>(kGroup), &rot_s[f], &rot_c[f]);
    sin_cos(w[f] * 0.5f * static_cast<float>(kGroup - 1), &sg0[f], &cg0[f]);  // phase at group 0's centre
    float sh, ch;
    sin_cos(0.5f * w[f], &sh, &ch);
    float sl, cl;
    sin_cos(0.5f * w[f] * static_cast<float>(kGroup), &sl, &cl);
    gain[f] = sh > 0.0f ? sl / (static_cast<float>(kGroup) * sh) : 1.0f;  // D: the group mean of a unit sinusoid
    // a block's (the arguments as the hum channel's per-channel sin_cos took them: the same floats)
    const float wf = w[f];
    sin_cos(wf * static_cast<float>(kBlock), &blk_rs[f], &blk_rc[f]);
    sin_cos(wf * static_cast<float>(kBlock - 1), &blk_ls[f], &blk_lc[f]);
    sin_cos(wf * 0.5f * static_cast<float>(kBlock - 1), &blk_ms[f], &blk_mc[f]);
    float bh, bch, bl, bcl;
    sin_cos(0.5f * wf, &bh, &bch);
    sin_cos(0.5f * wf * kBlock, &bl, &bcl);
    blk_gain[f] = bh > 0.0f ? bl / (kBlock * bh) : 1.0f;
  }
}

// A channel's fit names the event's mains frequency when its residual is at most this x the other's.
constexpr float kPickMargin = 0.5f;

void fit_baseline(const int16_t* x, int n, const Sums* prefix, int nb, float fs_hz, float hum_min_counts,
                  HumBasis* basis, Baseline* out) {
  robust_level(x, prefix, n, nb, out);
  out->hum = 0;
  out->hum_hz = 0.0f;
  out->hum_amp = 0.0f;
  out->c0 = out->c1 = out->c2 = 0.0f;
  out->w = 0.0f;
  constexpr int kGroup = kHumGroupBlocks * kBlock;
  const int groups = n / kGroup;
  if (groups < 4 || !(fs_hz > 0.0f)) return;
  const int32_t lc = floor_to_int(out->level + 0.5f);
  const float v0 = out->within_rms * out->within_rms + 1.0f;
  const float inv_len = 1.0f / static_cast<float>(kGroup);
  // The groups' means about the level (y) and weights, then a test that rules the hum out without the
  // fit: the fit's weighted sum of squares explained by the sinusoid (ESS) is at most T, the weighted
  // sum of squares of y about its weighted mean (the fit has a constant), and with M the (c1, c2) block's
  // Schur complement, amp^2 <= ESS / lambda_min(M) <= ESS trace(M^-1) = ESS var12 (exact arithmetic). A
  // modelled hum needs amp^2 >= 16 var12 max(rss / dof, inv_len) below, hence ESS >= 16 inv_len: a T
  // below three quarters of that has no hum (the quarter covers the float rounding of both sides, which
  // matters only for a near-singular fit). Most clean board captures stop here: no normal equations.
  constexpr int kMaxGroups = kMaxBlocks / kHumGroupBlocks + 1;
  float ys[kMaxGroups], wts[kMaxGroups];
  float sw = 0.0f, swy = 0.0f;
  for (int g = 0; g < groups; ++g) {
    const int k0 = g * kHumGroupBlocks, k1 = k0 + kHumGroupBlocks;
    const Sums s = {prefix[k1].s2 - prefix[k0].s2, prefix[k1].s1 - prefix[k0].s1};
    const float mean = static_cast<float>(s.s1 - lc * kGroup) * inv_len;  // about the integer level
    const float var = centred_s2(s, kGroup, lc) * inv_len - mean * mean;
    wts[g] = 1.0f / ((var > 0.0f ? var : 0.0f) + v0);
    ys[g] = mean + static_cast<float>(lc) - out->level;
    sw += wts[g];
    swy += wts[g] * ys[g];
  }
  const float ybar = swy / sw;
  float spread = 0.0f;  // T
  for (int g = 0; g < groups; ++g) {
    const float d = ys[g] - ybar;
    spread += wts[g] * d * d;
  }
  if (spread < 0.75f * 16.0f * inv_len) return;
  IC_WORK(hum_fits, 1);
  // The sinusoids' values at the groups' centres, by rotation from group 0's phase (both mains frequencies
  // until a channel of the event names the event's, then that one alone). One frequency at a time (the groups
  // in the same order: the same sums), so the sums and the rotation stay in registers.
  if (basis->fs_hz != fs_hz) basis->set(fs_hz);
  HumFit fit[2];
  const int f_first = basis->event_mains == 2 ? 1 : 0, f_end = basis->event_mains == 1 ? 1 : 2;
  for (int f = f_first; f < f_end; ++f) {
    const float rot_c = basis->rot_c[f], rot_s = basis->rot_s[f], gain = basis->gain[f];
    float cg = basis->cg0[f], sg = basis->sg0[f];
    HumFit acc;
    for (int g = 0; g < groups; ++g) {
      acc.add(wts[g], ys[g], gain * cg, gain * sg);
      const float c = cg * rot_c - sg * rot_s;
      sg = sg * rot_c + cg * rot_s;
      cg = c;
    }
    fit[f] = acc;
  }
  const float* w = basis->w;
  float other_rss = INFINITY;  // the other frequency's (when both were fitted and solved)
  float best_rss = INFINITY, coef[3], best[3] = {0, 0, 0}, best_var = 0.0f;
  int pick = -1;
  for (int f = f_first; f < f_end; ++f) {
    float rss, var12;
    if (!fit[f].solve(coef, &rss, &var12)) continue;
    if (!(rss < best_rss)) {
      other_rss = rss;
    } else {
      other_rss = best_rss;
      best_rss = rss;
      // The coefficients' variance: the inverse normal matrix times the residual's scale per degree of
      // freedom, at least a group mean's noise (its samples' variance / kGroup, what the weights expect):
      // a leak of the plate's own signal into the group means widens it.
      const float dof_scale = groups > 3 ? rss / static_cast<float>(groups - 3) : INFINITY;
      best_var = var12 * (dof_scale > inv_len ? dof_scale : inv_len);
      pick = f;
      best[0] = coef[0];
      best[1] = coef[1];
      best[2] = coef[2];
    }
  }
  if (pick < 0) return;
  out->hum_hz = kMainsHz[pick];
  out->hum_amp = vsqrt_f32(best[1] * best[1] + best[2] * best[2]);
  out->c0 = best[0];
  out->c1 = best[1];
  out->c2 = best[2];
  out->w = w[pick];
  // A hum is modelled when it stands out of what a quiet capture's fit gives: hum_min_counts, twice the
  // noise floor (the plate's own low modes stay below this), and four standard errors of the fit.
  const float floor_counts = 2.0f * out->within_rms;
  out->hum = (out->hum_amp >= hum_min_counts && out->hum_amp >= floor_counts &&
              out->hum_amp * out->hum_amp >= 16.0f * best_var) ? 1 : 0;
  // The event's mains frequency: the first modelled hum whose fit tells the two apart (its residual at most
  // kPickMargin x the other frequency's: a wrong pick's lies near 1, docs/findings.md "Session 29: boardhum3").
  if (out->hum && basis->event_mains == 0 && best_rss <= kPickMargin * other_rss) basis->event_mains = 1 + pick;
}

}  // namespace impactcore
