// Per-channel onset and energy features of one capture.
//
// Cost: one integer pass per channel (block_prefix_sums: exact S1, S2 per block of kBlock samples); every
// energy (total, five windows, n2's cumulative sum) is exact int64 algebra on those sums plus at most a
// block's worth of samples at each range end; the peak, the clipping test and the threshold crossing scan
// only the blocks whose energy can hold a large enough sample (a sample's (x - b)^2 never exceeds its
// block's energy), so the float per-sample work is a few blocks. See firmware/lib/impactapp/README.md.
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "impactcore.h"

namespace impactcore {
namespace {

const float kNaN = NAN;

// Index of the first local maximum of |x - base| at or after `from` (the first lobe of the arrival).
int first_extremum(const int16_t* x, int n, float base, int from) {
  if (from < 0) from = 0;
  float prev = -1.0f;
  for (int i = from; i < n; ++i) {
    const float a = fabsf(static_cast<float>(x[i]) - base);
    if (a < prev) return i - 1;
    prev = a;
  }
  return n - 1;
}

// Amplitude features in units of a unit-gain channel (ratios are gain free).
// sum over j of binomial(k, j)^2 = binomial(2k, k): the variance of Delta^k of unit white noise, k = 1..3.
constexpr float kNoiseDiffGain[kDiffOrders] = {2.0f, 6.0f, 20.0f};

void apply_gain(ChannelFeatures* f, float gain) {
  if (!(gain > 0.0f) || gain == 1.0f) return;
  const float inv = 1.0f / gain;
  const float inv2 = inv * inv;
  f->peak *= inv;
  f->first_peak *= inv;
  f->energy *= inv2;
  for (int w = 0; w < kEnergyWindows; ++w) f->window_energy[w] *= inv2;
  for (int k = 0; k < kDiffOrders; ++k) f->diff_energy[k] *= inv2;
}

#if defined(__GNUC__)
#define IC_INLINE inline __attribute__((always_inline))
#else
#define IC_INLINE inline
#endif

#if defined(__GNUC__)
#define IC_NOINLINE __attribute__((noinline))
#else
#define IC_NOINLINE
#endif

IC_NOINLINE float to_float(int64_t v) { return int64_to_float(v); }  // out of line: one copy

// floor(v) for v >= 0 as int64, saturating (no libgcc float -> int64 conversion, ~150 instructions on
// the M4F: floats >= 2^24 are integers, so the mantissa shifted by the exponent is exact).
int64_t to_int64(float v) {
  if (!(v >= 0.0f)) return 0;
  if (v < 2147483648.0f) return static_cast<int32_t>(v);
  if (v >= 9.2e18f) return INT64_MAX;
  uint32_t u;
  memcpy(&u, &v, sizeof(u));
  const int shift = static_cast<int>(u >> 23) - 127 - 23;
  return static_cast<int64_t>((u & 0x007FFFFFu) | 0x00800000u) << shift;
}

// to_int64(ceilf(v)) without libm: floats >= 2^31 are integers already.
int64_t ceil_to_int64(float v) {
  if (!(v > 0.0f)) return 0;
  return v < 2147483648.0f ? ceil_to_int(v) : to_int64(v);
}

// The energy bookkeeping of one channel: the prefix table and the scaled-energy form
// n_b^2 sum (x - b)^2 = c2 S2 - c1 S1 + m sb^2 (impactcore.h), exact in int64; to_energy gives counts^2.
struct Channel {
  const int16_t* x;
  int n;
  int nblk;
  int nb;          // baseline samples
  int32_t sb;      // their sum: b = sb / nb
  int64_t c2;      // nb^2
  int64_t c1;      // 2 nb sb
  int64_t sb2;     // sb^2
  float nb2;       // nb^2
  bool fits32;     // set_centre(): the uint32 sums about c are exact
  int32_t c;       // sb / nb rounded
  uint32_t uc, uc2;  // c, c^2 (mod 2^32)
  uint32_t nbsq;   // nb^2
  int32_t tnr, r2;  // 2 nb r, r^2 (r = nb c - sb)
  Sums prefix[kMaxBlocks + 1];

  void set_baseline(int n_b, int32_t sum_b) {
    nb = n_b;
    sb = sum_b;
    c2 = static_cast<int64_t>(n_b) * n_b;
    c1 = 2 * static_cast<int64_t>(n_b) * sum_b;
    sb2 = static_cast<int64_t>(sum_b) * sum_b;
    nb2 = int64_to_float(c2);  // nb^2 < 2^17: VCVT, not libgcc's 64-bit conversion
  }
  IC_INLINE int64_t form(int64_t s2, int32_t s1, int m) const { return c2 * s2 - c1 * s1 + m * sb2; }
  // form() of a prefix x[0 .. m), through the sums about c when fits32 (set_centre). With y = x - c and
  // r = nb c - sb, nb x - sb = nb y + r, so the form is nb^2 sum y^2 + 2 nb r sum y + m r^2, the same
  // integer: sum y^2 over a prefix is below 2^32 (exact in uint32 from the low words), |2 nb r| <= nb^2
  // <= 2^16, |sum y| < 2^29, m r^2 < 2^27. One UMULL and one SMULL instead of three 64-bit products.
  IC_INLINE int64_t prefix_form(int64_t s2, int32_t s1, int m) const {
    if (!fits32) return form(s2, s1, m);
    const uint32_t q = static_cast<uint32_t>(s2) - 2u * uc * static_cast<uint32_t>(s1) + static_cast<uint32_t>(m) * uc2;
    const int32_t y = s1 - m * c;
    return static_cast<int64_t>(static_cast<uint64_t>(nbsq) * q) + static_cast<int64_t>(tnr) * y + m * r2;
  }
  // Scaled energy of x[0 .. i) (a partial block costs its samples).
  int64_t energy_to(int i) const {
    const Sums r = prefix_at(x, prefix, n, i);
    return prefix_form(r.s2, r.s1, i);
  }
  // ... of x[0 .. k kBlock), k <= nblk.
  IC_INLINE int64_t energy_to_block(int k) const {
    const int m = k * kBlock < n ? k * kBlock : n;
    return prefix_form(prefix[k].s2, prefix[k].s1, m);
  }
  // ... of block k.
  IC_INLINE int64_t block_energy(int k) const {
    const int m = (k + 1 == nblk) ? n - k * kBlock : kBlock;
    return form(prefix[k + 1].s2 - prefix[k].s2, prefix[k + 1].s1 - prefix[k].s1, m);
  }
  // Can blocks [k0, k1) hold a sample with |float(x) - base| >= a (lim = bound(a), lim_f = 0.999 a^2)?
  // For full blocks whose sum of squares fits 32 bits (every 12-bit capture, up to 16 blocks) in float:
  // e = S2 - 2 base S1 + m base^2 is sum (x - base)^2 to within 1e-6 (S2 + m base^2), which the test
  // adds; exact int64 otherwise.
  IC_INLINE bool may_reach(int k0, int k1, float base, float lim_f, int64_t lim) const {
    const int64_t s2 = prefix[k1].s2 - prefix[k0].s2;
    const int32_t s1 = prefix[k1].s1 - prefix[k0].s1;
    if (k1 < nblk && (s2 >> 32) == 0) {
      const float s2f = static_cast<float>(static_cast<uint32_t>(s2));
      const float mb2 = static_cast<float>((k1 - k0) * kBlock) * base * base;
      const float e = (s2f - 2.0f * base * static_cast<float>(s1)) + mb2;
      return e + 1e-6f * (s2f + mb2) >= lim_f;
    }
    const int m = (k1 * kBlock < n ? k1 * kBlock : n) - k0 * kBlock;
    return form(s2, s1, m) >= lim;
  }
  IC_INLINE int block_end(int k) const { return (k + 1) * kBlock < n ? (k + 1) * kBlock : n; }
  float to_energy(int64_t e) const { return to_float(e) / nb2; }
  // A block whose scaled energy is below bound(a) holds no sample with |float(x) - base| >= a: a sample's
  // nb^2 (x - b)^2 never exceeds its block's energy; the margins (0.999, 0.004 counts) cover the rounding
  // of the float baseline (<= 2^-24 * 32768 = 0.002 counts) and of this bound.
  int64_t bound(float a) const {
    const float r = a - 0.004f;
    return r > 0.0f ? to_int64(0.999f * r * r * nb2) : 0;
  }

  // The sums about c (the pruning tests, prefix_form), used when exact. c = sb / nb rounded, so
  // |base - c| <= 0.502 (0.5, plus the float division's rounding <= 2^-24 * 32768). When the capture's
  // sum of (x - c)^2 is below 2^32 (its rms about the baseline under 2048 counts: every 12-bit capture),
  // every range's is too, and S2 - 2 c S1 + m c^2 over a range is exact in uint32 arithmetic on the low
  // words of the prefix sums (wrap-around is arithmetic mod 2^32): ~10 instructions a test, not ~25.
  // The scans below are compiled for either form (template argument kFits32 = fits32).
  void set_centre() {
    const int32_t num = 2 * sb + nb, den = 2 * nb;  // c = floor(sb / nb + 1/2); |num| < 2^25
    c = num / den;
    if (num % den != 0 && num < 0) --c;
    const int32_t r = nb * c - sb;  // |r| <= nb / 2
    nbsq = static_cast<uint32_t>(nb * nb);
    tnr = 2 * nb * r;
    r2 = r * r;
    const int64_t sc = prefix[nblk].s2 - 2 * static_cast<int64_t>(c) * prefix[nblk].s1 +
                       static_cast<int64_t>(n) * c * c;
    fits32 = (sc >> 32) == 0;
    uc = static_cast<uint32_t>(c);
    uc2 = uc * uc;
  }
  // What a test needs for one level a: the sample sought has |float(x) - base| >= a, so |x - base| >=
  // a - 0.004 (a < 2^16; larger levels no int16 sample reaches), and the integer |x - c| >= a - 0.506 >
  // fl(a - 0.52) (that subtraction rounds by <= 0.004), hence |x - c| >= q = ceil(fl(a - 0.52)) and the
  // range's sum of (x - c)^2 >= q^2 (q capped at 2^16 - 1 so that q^2 fits: a weaker test, still safe).
  struct Level {
    uint32_t q2;   // fits32
    float lim_f;   // otherwise: may_reach's bounds
    int64_t lim;
  };
  template <bool kFits32>
  Level level(float a) const {
    Level l = {0u, 0.0f, 0};
    if (kFits32) {
      const float r = a - 0.52f;
      if (r > 0.0f) {
        const uint32_t q = r < 65535.0f ? static_cast<uint32_t>(ceil_to_int(r)) : 65535u;
        l.q2 = q * q;
      }
    } else {
      l.lim = bound(a);
      const float r = a - 0.004f;  // bound()'s margin: lim_f = 0 (scan everything) when a <= 0.004
      l.lim_f = r > 0.0f ? 0.999f * r * r : 0.0f;
    }
    return l;
  }
  // Can blocks [k0, k1) hold a sample with |float(x) - base| >= a (l = level(a))?
  template <bool kFits32>
  IC_INLINE bool reaches(int k0, int k1, float base, const Level& l) const {
    if (!kFits32) return may_reach(k0, k1, base, l.lim_f, l.lim);
    const uint32_t s2 = static_cast<uint32_t>(prefix[k1].s2) - static_cast<uint32_t>(prefix[k0].s2);
    const uint32_t s1 = static_cast<uint32_t>(prefix[k1].s1 - prefix[k0].s1);
    const uint32_t m = static_cast<uint32_t>((k1 == nblk ? n : k1 * kBlock) - k0 * kBlock);
    return s2 - 2u * uc * s1 + m * uc2 >= l.q2;
  }
};

// Raises *peak to the largest |float(x) - base| of block k: the same value as that expression's maximum
// over the samples (float subtraction is monotone in x), from the block's integer extremes.
IC_INLINE void scan_peak(const Channel& ch, int k, float base, float* peak) {
  IC_WORK(peak_blocks, 1);
  int32_t lo, hi;
  if ((k + 1) * kBlock <= ch.n) {
    block_extremes(ch.x + k * kBlock, &lo, &hi);
  } else {
    range_extremes(ch.x, k * kBlock, ch.n, &lo, &hi);
  }
  const float a = fabsf(static_cast<float>(hi) - base);
  const float b = fabsf(static_cast<float>(lo) - base);
  if (a > *peak) *peak = a;
  if (b > *peak) *peak = b;
}

// max |x - base| over the capture: the blocks whose energy could hold a larger sample than the peak so
// far. With an onset, the crossing's block and the kArrivalBlocks - 1 after it (the first lobes, usually
// the largest: a high peak early rules out most other blocks) are taken first; the blocks between `start`
// and the crossing are skipped (their samples from `start` on are below the threshold, hence the peak).
constexpr int kArrivalBlocks = 3;
template <bool kFits32>
IC_NOINLINE float peak_abs(const Channel& ch, float base, int at, int start) {
  float peak = 0.0f;
  const int kc = at >= 0 ? at / kBlock : -1;
  const int ka = kc < 0 ? -1 : (kc + kArrivalBlocks < ch.nblk ? kc + kArrivalBlocks : ch.nblk);
  for (int k = kc; k >= 0 && k < ka; ++k) scan_peak(ch, k, base, &peak);
  Channel::Level lim = ch.level<kFits32>(peak);
  // The blocks skipped: [kc, ka), taken above, and those from `start` on before the crossing; the two are
  // one range [skip_lo, ka) (empty without an onset).
  int skip_lo = 0, skip_hi = 0;
  if (kc >= 0) {
    const int kb = (start + kBlock - 1) / kBlock;  // the first block with k kBlock >= start (start >= 0)
    skip_lo = kb < kc ? kb : kc;
    skip_hi = ka;
  }
  const uint32_t skip_span = static_cast<uint32_t>(skip_hi - skip_lo);
  // The blocks of group [g, gend) that can hold a larger sample than the peak so far.
  const auto blocks = [&](int g, int gend) {
    for (int k = g; k < gend; ++k) {
      if (static_cast<uint32_t>(k - skip_lo) < skip_span) continue;
      IC_WORK(reach_tests, 1);
      if (!ch.reaches<kFits32>(k, k + 1, base, lim)) continue;
      const float before = peak;
      scan_peak(ch, k, base, &peak);
      if (peak > before) lim = ch.level<kFits32>(peak);
    }
  };
  // Groups of kGroup blocks first: a group too weak for the peak rules out all of its blocks.
  constexpr int kGroup = 4;
  int g = 0;
  if constexpr (kFits32) {
    // The groups of full blocks with reaches<true>'s test written out, the prefix entries walked in order
    // and c in registers: ~10 instructions a group instead of ~25 (most groups pass; a ringing plate's
    // 64 samples hold the peak's square from a fifth of its amplitude on). A group that passes tests its
    // blocks the same way (reaches<true> on a full block), the peak and its level in registers.
    const uint32_t c2 = 2u * ch.uc, gc2 = static_cast<uint32_t>(kGroup * kBlock) * ch.uc2;
    const uint32_t bc2 = static_cast<uint32_t>(kBlock) * ch.uc2;
    const int groups_end = ch.n / kBlock / kGroup * kGroup;
    uint32_t q2 = lim.q2;
    float pk = peak;
    const Sums* pre = ch.prefix;
    uint32_t a2 = static_cast<uint32_t>(pre[0].s2), a1 = static_cast<uint32_t>(pre[0].s1);
    for (; g < groups_end; g += kGroup) {
      const uint32_t b2 = static_cast<uint32_t>(pre[g + kGroup].s2);
      const uint32_t b1 = static_cast<uint32_t>(pre[g + kGroup].s1);
      const uint32_t e = (b2 - a2) - c2 * (b1 - a1) + gc2;
      if (e >= q2) {
        uint32_t u2 = a2, u1 = a1;
        for (int k = g; k < g + kGroup; ++k) {
          const uint32_t v2 = static_cast<uint32_t>(pre[k + 1].s2), v1 = static_cast<uint32_t>(pre[k + 1].s1);
          const uint32_t eb = (v2 - u2) - c2 * (v1 - u1) + bc2;
          u2 = v2;
          u1 = v1;
          if (static_cast<uint32_t>(k - skip_lo) < skip_span) continue;
          IC_WORK(reach_tests, 1);
          if (eb < q2) continue;
          const float before = pk;
          scan_peak(ch, k, base, &pk);
          if (pk > before) q2 = ch.level<true>(pk).q2;
        }
      }
      a2 = b2;
      a1 = b1;
    }
    peak = pk;
    lim.q2 = q2;
  }
  for (; g < ch.nblk; g += kGroup) {
    const int gend = g + kGroup < ch.nblk ? g + kGroup : ch.nblk;
    if (ch.reaches<kFits32>(g, gend, base, lim)) blocks(g, gend);
  }
  return peak;
}

// Any sample at or beyond a rail. None when the peak is closer to the baseline than both rails (a sample
// at or beyond a rail is at least that far: float subtraction is monotone in x). Otherwise only blocks
// whose energy reaches the distance from the baseline to the nearer rail can hold one (reaches, in groups
// of four blocks first, as the peak scan), taken from the crossing's group on (where a clipped arrival
// reaches the rail), then the groups before it.
template <bool kFits32>
bool clipped(const Channel& ch, float base, float peak, int at, int adc_min, int adc_max) {
  const float room_lo = base - static_cast<float>(adc_min);
  const float room_hi = static_cast<float>(adc_max) - base;
  if (peak < room_lo && peak < room_hi) return false;
  const float room = room_lo < room_hi ? room_lo : room_hi;
  const Channel::Level lim = ch.level<kFits32>(room);
  constexpr int kGroup = 4;
  const int g0 = at >= 0 ? at / kBlock / kGroup * kGroup : 0;
  for (int j = 0, g = g0; j < ch.nblk; j += kGroup, g = g + kGroup < ch.nblk ? g + kGroup : 0) {
    const int gend = g + kGroup < ch.nblk ? g + kGroup : ch.nblk;
    if (!ch.reaches<kFits32>(g, gend, base, lim)) continue;
    for (int k = g; k < gend; ++k) {
      if (!ch.reaches<kFits32>(k, k + 1, base, lim)) continue;
      int32_t lo, hi;
      if ((k + 1) * kBlock <= ch.n) {
        block_extremes(ch.x + k * kBlock, &lo, &hi);
      } else {
        range_extremes(ch.x, k * kBlock, ch.n, &lo, &hi);
      }
      if (lo <= adc_min || hi >= adc_max) return true;
    }
  }
  return false;
}

// The samples that do not cross the threshold, as an integer band: lo <= x <= hi exactly when
// fabsf(float(x) - base) < thr (that expression is monotone in x on either side of the baseline). False
// when the band is empty (thr below the rounding of the baseline).
bool quiet_band(float base, float thr, int32_t* lo, int32_t* hi) {
  const auto crosses = [base, thr](int32_t v) { return fabsf(static_cast<float>(v) - base) >= thr; };
  const int32_t c = floor_to_int(base);
  if (crosses(c) || crosses(c + 1)) return false;
  int32_t h = floor_to_int(base + thr);
  if (h < c + 1) h = c + 1;
  while (crosses(h)) --h;
  while (!crosses(h + 1)) ++h;
  int32_t l = ceil_to_int(base - thr);
  if (l > c) l = c;
  while (crosses(l)) ++l;
  while (!crosses(l - 1)) --l;
  *lo = l;
  *hi = h;
  return true;
}

// threshold_crossing(x, n, base, thr, start), skipping the blocks too weak to hold a crossing and those
// whose extremes stay in the quiet band; *at is the first sample at or above the threshold (-1 if none).
template <bool kFits32>
float crossing(const Channel& ch, float base, float thr, int start, int* at) {
  if (start < 1) start = 1;
  const Channel::Level lim = ch.level<kFits32>(thr);
  int32_t lo = 0, hi = -1;
  const bool band = quiet_band(base, thr, &lo, &hi);
  const int first = start / kBlock;
  for (int k = first; k < ch.nblk; ++k) {
    // Four blocks at once where they are whole: too weak together, none of them holds a crossing (each
    // block's energy is part of theirs; peak_abs's groups). A channel without an onset is read to its end.
    if (kFits32 && (k & 3) == 0 && k >= first + 4 && k + 4 <= ch.nblk && !ch.reaches<kFits32>(k, k + 4, base, lim)) {
      k += 3;
      continue;
    }
    if (!ch.reaches<kFits32>(k, k + 1, base, lim)) continue;
    const int from = k * kBlock > start ? k * kBlock : start;
    const int end = ch.block_end(k);
    IC_WORK(crossing_blocks, 1);
    if (band) {
      int32_t mn, mx;
      range_extremes(ch.x, from, end, &mn, &mx);
      if (mn >= lo && mx <= hi) continue;
    }
    for (int i = from; i < end; ++i) {
      if (band ? (ch.x[i] < lo || ch.x[i] > hi) : fabsf(static_cast<float>(ch.x[i]) - base) >= thr) {
        *at = i;
        return crossing_subsample(ch.x, i, base, thr);
      }
    }
  }
  *at = -1;
  return -1.0f;
}

// The first sample where the scaled cumulative energy reaches `target`: bisection over the block
// boundaries, then one block sample by sample. n - 1 if it never does.
int energy_reaches(const Channel& ch, int64_t target) {
  if (ch.energy_to_block(ch.nblk) < target) return ch.n - 1;
  int lo = 0, hi = ch.nblk;  // energy_to_block(lo) < target <= energy_to_block(hi), or lo = 0
  if (target <= 0) hi = 0;
  while (hi - lo > 1) {
    const int mid = (lo + hi) / 2;
    if (ch.energy_to_block(mid) < target) {
      lo = mid;
    } else {
      hi = mid;
    }
  }
  int64_t cum = ch.energy_to_block(lo);
  for (int i = lo * kBlock; i < ch.n; ++i) {
    // |nb x - sb| <= 2^24 (nb <= kMaxBaselineSamples): a 32-bit difference, one SMLAL a sample.
    const int32_t d = ch.nb * ch.x[i] - ch.sb;
    cum += static_cast<int64_t>(d) * d;
    if (cum >= target) return i;
  }
  return ch.n - 1;
}

// hum_at at a block's first sample, its last and its centre, block after block from block 0: each the level's
// c0 plus a sinusoid sampled every kBlock samples, stepped by y_{k+1} = 2 cos(w kBlock) y_k - y_{k-1} (one
// multiply-add each a block; a sin_cos is ~70 instructions on the M4F). Full blocks only: a capture's last,
// shorter block takes hum_at. The steps' rounding leaves them within ~1e-6 of hum_at's amplitude over a capture
// (float phase arguments differ as much).
struct HumSteps {
  // set() before use (no default values: the struct sits unused in every channel without a hum)
  const Baseline* bl;
  float two_c;           // 2 cos(w kBlock)
  float f, fp, l, lp, m, mp;  // the sinusoid at block k's first, last and centre sample, and at block k - 1's
  // from the event's basis (HumBasis: the rate's, computed once)
  void set(const Baseline& b, const HumBasis& basis) {
    bl = &b;
    const int i = basis.index(b.w);
    const float rs = basis.blk_rs[i], rc = basis.blk_rc[i], ms = basis.blk_ms[i], mc = basis.blk_mc[i];
    const float ls = basis.blk_ls[i], lc = basis.blk_lc[i];
    two_c = 2.0f * rc;
    // c1 cos + c2 sin at a phase (cos, sin) and a block before it (the phase less w kBlock)
    const auto now = [&](float c, float s) { return b.c1 * c + b.c2 * s; };
    const auto before = [&](float c, float s) { return b.c1 * (c * rc + s * rs) + b.c2 * (s * rc - c * rs); };
    f = now(1.0f, 0.0f);
    fp = before(1.0f, 0.0f);
    l = now(lc, ls);
    lp = before(lc, ls);
    m = now(mc, ms);
    mp = before(mc, ms);
  }
  void next() {
    const float fn = two_c * f - fp, ln = two_c * l - lp, mn = two_c * m - mp;
    fp = f;
    f = fn;
    lp = l;
    l = ln;
    mp = m;
    m = mn;
  }
  float first() const { return bl->c0 + f; }
  float last() const { return bl->c0 + l; }
  float centre() const { return bl->c0 + m; }
};

// The extremes the onset scan read: of every sample in blocks [0, covered).
struct HumScan {
  int covered;
  int32_t lo, hi;
  void reset() {
    covered = 0;
    lo = INT32_MAX;
    hi = INT32_MIN;
  }
  void add(int k, int32_t l, int32_t h) {
    if (k == covered) ++covered;
    if (l < lo) lo = l;
    if (h > hi) hi = h;
  }
  // their largest |x - base| (as scan_peak computes it: rounding is monotone, so the extremes' is the max)
  float peak(float base) const {
    const float a = fabsf(static_cast<float>(hi) - base), b = fabsf(static_cast<float>(lo) - base);
    return a > b ? a : b;
  }
};

// The hum model's per-block departures d_k (block means of c0 + c1 cos + c2 sin) and the correction that
// turns the constant-baseline energies of Channel into energies about the model: for a block,
// sum (x - base - d)^2 = sum (x - base)^2 - 2 d sum (x - base) + m d^2. corr[k]: that correction summed
// over blocks [0, k) (counts^2). Used only when the hum is modelled.
struct HumEnergy {
  HumSteps steps;  // set before the onset scan (which steps a copy)
  HumScan scan;    // the onset scan's extremes (hum_crossing resets it)
  const Channel* ch;
  const Baseline* bl;
  float base;
  float gain16;    // mean of a unit sinusoid over a block
  float corr[kMaxBlocks + 1];
  float dk[kMaxBlocks];  // d_k, as build stepped it (the windows' and n2's partial blocks read it: no sin_cos)

  float block_d(int k) const { return dk[k]; }
  // d_k - c0 = g (c1 cos + c2 sin) at block k's centre, a sinusoid sampled every kBlock: y_{k+1} = 2 cos(w kBlock)
  // y_k - y_{k-1} (one multiply-add a block, as HumSteps)
  IC_NOINLINE void build(const Channel& channel, const Baseline& b, float level, const HumBasis& basis) {
    ch = &channel;
    bl = &b;
    base = level;
    gain16 = basis.blk_gain[basis.index(b.w)];
    // steps (set for the onset scan, not stepped): the sinusoid at block 0's centre and block -1's
    const float two_c = steps.two_c;
    float y = gain16 * steps.m, y_prev = gain16 * steps.mp;
    corr[0] = 0.0f;
    // Full blocks first (m = kBlock), then a shorter last block.
    const int full = channel.n / kBlock;
    const float mf = static_cast<float>(kBlock), mbase = mf * base, c0 = b.c0;
    float acc = 0.0f;
    int32_t prev = channel.prefix[0].s1;
    // two blocks a pass (the recurrence's registers swap roles instead of moving)
    int k = 0;
    for (; k + 1 < full; k += 2) {
      const float d0 = c0 + y;
      dk[k] = d0;
      const int32_t mid = channel.prefix[k + 1].s1, next = channel.prefix[k + 2].s1;
      const float dev0 = static_cast<float>(mid - prev) - mbase;
      acc = acc + d0 * (mf * d0 - 2.0f * dev0);
      corr[k + 1] = acc;
      y_prev = two_c * y - y_prev;  // block k + 1's
      const float d1 = c0 + y_prev;
      dk[k + 1] = d1;
      const float dev1 = static_cast<float>(next - mid) - mbase;
      prev = next;
      acc = acc + d1 * (mf * d1 - 2.0f * dev1);
      corr[k + 2] = acc;
      y = two_c * y_prev - y;        // block k + 2's (y_prev stays block k + 1's)
    }
    for (; k < full; ++k) {
      const float d = c0 + y;
      dk[k] = d;
      const int32_t next = channel.prefix[k + 1].s1;
      const float dev = static_cast<float>(next - prev) - mbase;
      prev = next;
      acc = acc + d * (mf * d - 2.0f * dev);
      corr[k + 1] = acc;
      const float yn = two_c * y - y_prev;
      y_prev = y;
      y = yn;
    }
    for (k = full; k < channel.nblk; ++k) {
      const int m = channel.block_end(k) - k * kBlock;
      const float d = c0 + y;
      dk[k] = d;
      const float dev = static_cast<float>(channel.prefix[k + 1].s1 - channel.prefix[k].s1) - m * base;
      corr[k + 1] = corr[k] + d * (static_cast<float>(m) * d - 2.0f * dev);
      const float yn = two_c * y - y_prev;
      y_prev = y;
      y = yn;
    }
  }
  // A scaled energy in counts^2 as its two words, each converted by one VCVT (within 2 ulp of the correctly
  // rounded conversion, libgcc's ~50-instruction __floatdisf: the sum with corr rounds more).
  IC_NOINLINE float scaled(int64_t e) const {
    const float hi = static_cast<float>(static_cast<int32_t>(e >> 32)) * 4294967296.0f;
    return (hi + static_cast<float>(static_cast<uint32_t>(e))) / ch->nb2;
  }
  // Energy about the model of x[0 .. k kBlock) and of x[0 .. i).
  float to_block(int k) const { return scaled(ch->energy_to_block(k)) + corr[k]; }
  // x[0 .. i): the nearer block boundary's, plus or less the samples in between about the block's model (at most
  // kBlock / 2 of them, in float: no partial prefix sums and no 64-bit algebra)
  IC_NOINLINE float to(int i) const {
    const int k = i / kBlock, a = k * kBlock;
    if (i == a) return to_block(k);
    const int e = ch->block_end(k);
    const float d = base + block_d(k);
    const bool back = e - i < i - a;
    const int from = back ? i : a, to_j = back ? e : i;
    float s = 0.0f;
    for (int j = from; j < to_j; ++j) {
      const float v = static_cast<float>(ch->x[j]) - d;
      s += v * v;
    }
    const float edge = to_block(back ? k + 1 : k);
    return back ? edge - s : edge + s;
  }
  // The first sample where the energy about the model reaches target (energy_reaches about the model).
  int reaches(float target) const {
    if (to_block(ch->nblk) < target) return ch->n - 1;
    int lo = 0, hi = ch->nblk;
    while (hi - lo > 1) {
      const int mid = (lo + hi) / 2;
      if (to_block(mid) < target) lo = mid; else hi = mid;
    }
    float cum = to_block(lo);
    const float d = base + block_d(lo);
    for (int i = lo * kBlock; i < ch->n; ++i) {
      const float v = static_cast<float>(ch->x[i]) - d;
      cum += v * v;
      if (cum >= target) return i;
    }
    return ch->n - 1;
  }
};

// The hum model near the onset: the global fit misses a hum whose amplitude drifts by up to a few counts,
// more than an onset threshold allows, so the scan tracks the residual (block mean - model) of the last
// kLocalBlocks quiet blocks, a straight line through them extrapolated: b(i) = level + hum_at(i) + r +
// slope (i - t).
constexpr int kLocalBlocks = 4;
struct LocalHum {
  const Baseline* bl;
  // the line: value r at sample t, per-sample slope; fitted when read after a quiet block joined (a scan adds
  // several before it reads the line: only the last kLocalBlocks count, so one fit serves them)
  mutable float r = 0.0f, slope = 0.0f, t = 0.0f;
  mutable bool stale = false;
  float rs[kLocalBlocks], ts[kLocalBlocks];
  int quiet = 0;                           // quiet blocks seen
  // hum_at near one sample nc (set_near: the AIC window's centre, one sin_cos): hum_at(nc + u) = c0 + nh cos(w u) +
  // nq sin(w u), the rotation by a = w u from its series to a^7 when |a| <= 0.5 (terms left out < 1e-7; sin_cos
  // beyond): the AIC window's ends and the crossing without a sin_cos each
  float nc = 0.0f, nh = 0.0f, nq = 0.0f;
  void set_near(float c) {
    if (!bl->hum) return;
    float sn, cs;
    sin_cos(bl->w * c, &sn, &cs);
    nc = c;
    nh = bl->c1 * cs + bl->c2 * sn;
    nq = bl->c2 * cs - bl->c1 * sn;
  }
  // (out of line: inlined at its four calls it grew the board's code, whose flash is tight)
  IC_NOINLINE float model_near(float i) const {
    if (!bl->hum) return with_hum(i, 0.0f);
    const float a = bl->w * (i - nc);
    float sn, cs;
    if (fabsf(a) <= 0.5f) {
      const float a2 = a * a;
      cs = 1.0f - a2 / 2.0f * (1.0f - a2 / 12.0f * (1.0f - a2 / 30.0f));
      sn = a * (1.0f - a2 / 6.0f * (1.0f - a2 / 20.0f * (1.0f - a2 / 42.0f)));
    } else {
      sin_cos(a, &sn, &cs);
    }
    return with_hum(i, bl->c0 + nh * cs + nq * sn);
  }
  // the model at sample i given hum_at(i) (HumSteps)
  float with_hum(float i, float hum) const {
    if (stale) fit();
    return bl->level + hum + r + slope * (i - t);
  }
  // block k is quiet: its residual joins the line; hum: hum_at at its centre (HumSteps::centre)
  void add_block(const Channel& ch, int k, float hum) {
    const int a = k * kBlock, e = ch.block_end(k);
    const float centre = 0.5f * static_cast<float>(a + e - 1);
    const float mean = static_cast<float>(ch.prefix[k + 1].s1 - ch.prefix[k].s1) / static_cast<float>(e - a);
    const int slot = quiet % kLocalBlocks;
    rs[slot] = mean - bl->level - hum;
    ts[slot] = centre;
    ++quiet;
    stale = true;
  }
  // the line through the last kLocalBlocks quiet blocks' residuals (their mean without a slope under three):
  // one pass, the times u about the newest block's (half-integers: exact, and so are their squares' sums while
  // the blocks lie within ~2,000 samples of each other)
  IC_NOINLINE void fit() const {
    stale = false;
    const int m = quiet < kLocalBlocks ? quiet : kLocalBlocks;
    const float t0 = ts[(quiet - 1) % kLocalBlocks];
    float su = 0.0f, sr = 0.0f, suu = 0.0f, sur = 0.0f;
    for (int j = 0; j < m; ++j) {
      const float u = ts[j] - t0;
      su += u;
      sr += rs[j];
      suu += u * u;
      sur += u * rs[j];
    }
    const float inv = 1.0f / static_cast<float>(m), ub = su * inv;
    t = t0 + ub;
    r = sr * inv;
    const float stt = suu - su * ub, str = sur - ub * sr;
    slope = m >= 3 && stt > 0.0f ? str / stt : 0.0f;
  }
};

// The first crossing of |x - b(i)| >= thr from `start` on, b the level plus the hum model and its local
// residual (LocalHum; linear within a block between its ends' values), glitches (is_spike) passed over and
// counted in *spikes. *local: the model at the crossing (for the AIC window and the first peak).
float hum_crossing(const Channel& ch, const Baseline& bl, float thr, int start, int* at, int* spikes,
                   LocalHum* local, HumSteps hs, HumScan* scan) {
  scan->reset();
  if (start < 1) start = 1;
  local->bl = &bl;
  // The residual from the quiet blocks before start (a block that reaches the threshold about the global
  // model, a glitch or the onset, is left out).
  // hum_at at block k's centre (HumSteps for a full block)
  const auto centre = [&](int k) {
    const int e = ch.block_end(k);
    return e - k * kBlock == kBlock ? hs.centre() : hum_at(bl, 0.5f * static_cast<float>(k * kBlock + e - 1));
  };
  // a block's extremes (the unrolled pair scan for a whole block, as the peak scan reads them)
  const auto extremes = [&](int a, int e, int32_t* lo, int32_t* hi) {
    if (e - a == kBlock) {
      block_extremes(ch.x + a, lo, hi);
    } else {
      range_extremes(ch.x, a, e, lo, hi);
    }
  };
  for (int k = 0; k < start / kBlock; ++k, hs.next()) {
    int32_t lo, hi;
    const int a = k * kBlock, e = ch.block_end(k);
    extremes(a, e, &lo, &hi);
    scan->add(k, lo, hi);
    const float span = static_cast<float>(hi - lo);
    if (span < 2.0f * thr || span < 2.0f * thr + 2.0f * fabsf(hs.first() - hs.last())) local->add_block(ch, k, centre(k));
  }
  int resume = start;
  for (int k = start / kBlock; k < ch.nblk; ++k, hs.next()) {
    const int a = k * kBlock > start ? k * kBlock : start;
    const int e = ch.block_end(k);
    if (e - a < 1) continue;
    const bool whole = a == k * kBlock && e - a == kBlock;
    const float ba = local->with_hum(static_cast<float>(a), whole ? hs.first() : hum_at(bl, static_cast<float>(a)));
    const float be = local->with_hum(static_cast<float>(e - 1), whole ? hs.last() : hum_at(bl, static_cast<float>(e - 1)));
    int32_t lo, hi;
    extremes(a, e, &lo, &hi);
    if (a == k * kBlock) scan->add(k, lo, hi);
    const float blo = (ba < be ? ba : be) - 0.5f, bhi = (ba > be ? ba : be) + 0.5f;
    if (static_cast<float>(hi) - blo < thr && bhi - static_cast<float>(lo) < thr) {
      if (a == k * kBlock) local->add_block(ch, k, centre(k));
      continue;
    }
    const float slope = e - 1 > a ? (be - ba) / static_cast<float>(e - 1 - a) : 0.0f;
    bool glitched = false;
    for (int i = a > resume ? a : resume; i < e; ++i) {
      const float bi = ba + slope * static_cast<float>(i - a);
      if (fabsf(static_cast<float>(ch.x[i]) - bi) < thr) continue;
      if (is_transient(ch.x, ch.n, i, bi, thr)) {
        ++*spikes;
        resume = i + 3;
        i += 2;
        glitched = true;
        continue;
      }
      *at = i;
      return crossing_subsample(ch.x, i, bi, thr);
    }
    if (a == k * kBlock && !glitched) local->add_block(ch, k, centre(k));  // every sample stayed below: quiet
  }
  *at = -1;
  return -1.0f;
}

// A hum channel's peak: the onset scan read the extremes of every block before the crossing's (scan.covered
// of them, when it reached the crossing's block): peak_abs skips them and their largest |x - base| joins
// its result; otherwise the whole capture.
IC_NOINLINE float hum_peak(const Channel& ch, float base, int at, const HumScan& scan) {
  const bool scanned = at >= 0 && scan.covered >= at / kBlock;
  const int from = scanned ? 0 : ch.n;
  const float rest = ch.fits32 ? peak_abs<true>(ch, base, at, from) : peak_abs<false>(ch, base, at, from);
  const float before = scanned ? scan.peak(base) : 0.0f;
  return before > rest ? before : rest;
}

// The AIC onset on a copy of the window with the baseline model taken out and the glitches before the
// crossing (samples at or beyond the threshold there) set to the baseline; (begin, end, search_from) as
// aic_pick_subsample. Returns the onset in samples of the capture, or -1.
float aic_on_clean_copy(const int16_t* x, const LocalHum& bl, int begin, int end, int icross, float thr,
                        int search_from) {
  int16_t buf[kMaxAicWindow];
  const int len = end - begin;
  const float b0 = bl.model_near(static_cast<float>(begin));
  const float bm = bl.model_near(0.5f * static_cast<float>(begin + end - 1));
  const float b1 = bl.model_near(static_cast<float>(end - 1));
  const float half = 0.5f * static_cast<float>(len - 1);
  // quadratic through the window's ends and middle: b(u) = bm + p u + q u^2, u = j - centre
  const float p = half > 0.0f ? (b1 - b0) / (2.0f * half) : 0.0f;
  const float q = half > 0.0f ? (b1 + b0 - 2.0f * bm) / (2.0f * half * half) : 0.0f;
  // u = j - centre, stepped by 1 (exact: half-integers below 2^9)
  const int pre = icross - begin;  // samples before the crossing: a glitch there is set to the baseline
  const int16_t* w = x + begin;
  float u = -half;
  for (int j = 0; j < len; ++j, u += 1.0f) {
    float v = static_cast<float>(w[j]) - (bm + u * (p + q * u));
    if (j < pre && fabsf(v) >= thr) v = 0.0f;
    buf[j] = static_cast<int16_t>(floor_to_int(v + 0.5f));
  }
  const float r = aic_pick_subsample(buf, 0, len, search_from - begin);
  return r >= 0.0f ? r + static_cast<float>(begin) : -1.0f;
}

// A glitch (a 1-2 sample spike of any size) after the onset adds its square to the capture's energy: a
// spike of a few hundred counts in the rung-down tail holds more than 1 - n2_fraction of it, so n2 (and
// with it the arrival's windows) jumps to the spike. spike_at tests the sample where n2 landed: taken out
// alone or with either neighbour (replaced by the line through the samples around them, rounded), the
// replacement that leaves the least local Delta^2 energy is kept; it is a spike when it departs from that
// line by at least the onset threshold, the Delta^2 terms it touches carry, per term, more than
// kSpikeRatio x the mean of the others within kSpikeReach samples, and the replacement removes more than
// kSpikeExplained of their energy (a ringing's own samples reach neither). Bounded cost: one sample's
// neighbourhood, only where n2 landed.
constexpr float kSpikeRatio = 25.0f;
constexpr float kSpikeExplained = 0.9f;
constexpr int kSpikeReach = 8;
constexpr int kMaxSpikes = 2;
constexpr float kArrivalSpikeRatio = 3.0f;  // extract_features: a channel's Delta^3 / Delta^1 over the others'
// Inside the arrival (a channel whose Delta^3 / Delta^1 already stands out) the spike's Delta^2 terms need
// only this ratio to the neighbourhood's (the arrival's own ringing is there; the replacement must still
// explain kSpikeExplained of them, which a ringing's own sample does not).
constexpr float kArrivalSpikeTermRatio = 4.0f;
// A channel whose ratio exceeds kArrivalSpikeBeyondRatio x the others' median (but not kArrivalSpikeRatio x) is
// done again seeking only a sample beyond its neighbours' range (beyond_neighbours): that test alone never
// takes a wave's sample, so the lower ratio only decides where the scan is worth its cost.
constexpr float kArrivalSpikeBeyondRatio = 2.0f;
constexpr float kSpikeBeyond = 1.5f;  // beyond_neighbours: a glitch lies more than this many ranges outside
enum { kHuntNone, kHuntBeyond, kHuntLargest };  // channel_features: how a glitch inside the arrival is sought

struct Spike {
  int at = -1, width = 0;  // samples [at, at + width) replaced
  int32_t value[2] = {0, 0};
  bool inside = false;     // found inside the arrival (the difference energies fill its terms otherwise)
};
constexpr int kSpikeFill = 5;  // difference terms either side whose mean fills an inside spike's terms

// Difference energies (k = 1..3) over m in [lo, hi) (lo >= 3) of x with the spike's samples replaced.
void local_difference_energies(const int16_t* x, const Spike& sp, int lo, int hi, int64_t out[kDiffOrders]) {
  const auto v = [&](int j) -> int64_t {
    return (j >= sp.at && j < sp.at + sp.width) ? sp.value[j - sp.at] : static_cast<int64_t>(x[j]);
  };
  for (int k = 0; k < kDiffOrders; ++k) out[k] = 0;
  for (int m = lo; m < hi; ++m) {
    const int64_t d1 = v(m) - v(m - 1), d1p = v(m - 1) - v(m - 2), d1pp = v(m - 2) - v(m - 3);
    const int64_t d2 = d1 - d1p, d2p = d1p - d1pp, d3 = d2 - d2p;
    out[0] += d1 * d1;
    out[1] += d2 * d2;
    out[2] += d3 * d3;
  }
}

// Necessary for spike_at(x, n, i, thr), ~160 instructions where n2 lands on a ringing or on noise (spike_at
// costs ~1.1k on the board):
//  - a replaced sample departs from its line by D >= thr only if one of the second differences
//    x[m] - 2 x[m-1] + x[m-2], m = i .. i + 2, reaches D (less the line's rounding, < 1);
//  - every candidate's terms lie in m = i - 1 .. i + 3, so their mean square is at most the largest there,
//    and the rest of the window holds at least every term outside them (summed exactly): the ratio test
//    needs that largest square above ratio x their sum / the window's length. The margins: ratio - 1 for
//    the float terms and the mean, and 1e-4 of the window's whole sum (at most that sum and 5 x the
//    largest) for spike_at's float sum less the candidate's (its rounding is ~1e-6 of the whole).
IC_INLINE float second_difference(const int16_t* x, int m) {
  return static_cast<float>(static_cast<int32_t>(x[m]) - 2 * static_cast<int32_t>(x[m - 1]) + x[m - 2]);
}

// sum of (Delta^2 x[m])^2 over m in [a, b), exact (|Delta^2 x| < 2^18: int64 sums).
int64_t second_difference_energy(const int16_t* x, int a, int b) {
  int64_t s = 0;
  for (int m = a; m < b; ++m) {
    const int32_t d = static_cast<int32_t>(x[m]) - 2 * static_cast<int32_t>(x[m - 1]) + x[m - 2];
    s += static_cast<int64_t>(d) * d;
  }
  return s;
}

bool may_be_spike(const int16_t* x, int n, int i, float thr, float ratio = kSpikeRatio) {
  const int lo = i - kSpikeReach > kDiffOrders ? i - kSpikeReach : kDiffOrders;
  const int hi = i + kSpikeReach + 3 < n ? i + kSpikeReach + 3 : n;
  if (hi - lo < 8 || i - 1 < lo || i + 3 >= hi) return false;
  float big = 0.0f, near = 0.0f;
  for (int m = i; m <= i + 2; ++m) {
    const float d = fabsf(second_difference(x, m));
    big = d > big ? d : big;
  }
  if (big < thr - 2.0f) return false;
  for (int m = i - 1; m <= i + 3; ++m) {
    const float d = second_difference(x, m);
    near = d * d > near ? d * d : near;
  }
  const float far = int64_to_float(second_difference_energy(x, lo, i - 1) + second_difference_energy(x, i + 4, hi));
  const float rest = far - 1e-4f * (far + 5.0f * near);
  return near > (ratio - 1.0f) * rest / static_cast<float>(hi - lo);
}

bool spike_at(const int16_t* x, int n, int i, float thr, Spike* sp, float ratio = kSpikeRatio) {
  // Delta^2 x[m] = x[m] - 2 x[m-1] + x[m-2] over m in [lo, hi), squared in float (the same operations on
  // host and board: the same decision).
  const int lo = i - kSpikeReach > kDiffOrders ? i - kSpikeReach : kDiffOrders;
  const int hi = i + kSpikeReach + 3 < n ? i + kSpikeReach + 3 : n;
  if (hi - lo < 8 || i < lo || i >= hi - 1) return false;
  float e2[2 * kSpikeReach + 3];
  float all = 0.0f;
  for (int m = lo; m < hi; ++m) {
    const float d = static_cast<float>(static_cast<int32_t>(x[m]) - 2 * static_cast<int32_t>(x[m - 1]) + x[m - 2]);
    e2[m - lo] = d * d;
    all += d * d;
  }
  const int starts[3] = {i, i, i - 1};
  const int widths[3] = {1, 2, 2};
  bool have = false;
  float best_left = 0.0f, best_orig = 0.0f, best_dev = 0.0f;
  int best_terms = 0;
  for (int k = 0; k < 3; ++k) {
    Spike c;
    c.at = starts[k];
    c.width = widths[k];
    if (c.at - 1 < lo - 2 || c.at + c.width >= hi) continue;
    const int32_t left = x[c.at - 1], right = x[c.at + c.width];
    float dev = 0.0f;
    for (int j = 0; j < c.width; ++j) {
      // the line through the neighbours, rounded half away from zero (exact integers: host = board)
      const int32_t num = (right - left) * (j + 1);
      const int32_t den = c.width + 1;
      c.value[j] = left + (2 * num + (num >= 0 ? den : -den)) / (2 * den);
      const float d = fabsf(static_cast<float>(x[c.at + j] - c.value[j]));
      dev = d > dev ? d : dev;
    }
    // the Delta^2 terms the replaced samples enter: m in [at, at + width + 2)
    const int a = c.at > lo ? c.at : lo;
    const int b = c.at + c.width + 2 < hi ? c.at + c.width + 2 : hi;
    // The samples those terms read, x[a - 2 .. b) with the replacement in (at most width + 4 = 6), copied
    // once: the terms below then read an array, not a per-access test of the replaced range.
    int32_t y[2 * 2 + 2];
    for (int j = a - 2; j < b; ++j) {
      y[j - (a - 2)] = (j >= c.at && j < c.at + c.width) ? c.value[j - c.at] : x[j];
    }
    float orig = 0.0f, left_e = 0.0f;
    for (int m = a; m < b; ++m) {
      orig += e2[m - lo];
      const int32_t* q = y + (m - a);  // q[0], q[1], q[2] = the values at m - 2, m - 1, m
      const float d = static_cast<float>(q[2] - 2 * q[1] + q[0]);
      left_e += d * d;
    }
    if (!have || left_e < best_left) {
      *sp = c;
      best_left = left_e;
      best_orig = orig;
      best_terms = b - a;
      best_dev = dev;
      have = true;
    }
  }
  if (!have || !(best_orig > 0.0f) || best_dev < thr || best_terms >= hi - lo) return false;
  const float rest = (all - best_orig) / static_cast<float>(hi - lo - best_terms);
  return best_orig / static_cast<float>(best_terms) > ratio * rest &&
         best_orig - best_left > kSpikeExplained * best_orig;
}

// How far a glitch candidate lies outside the range of the samples around it: samples [at, at + skip) are
// left out, the kSpikeReach samples either side give the range [mn, mx], and the result is the largest
// excursion of x[at .. at + eval) beyond it in units of the range (max(mx - mn, 1)): a wave's sample lies
// inside its neighbours' range or near it (the envelope changes over several samples), a spike of any size
// beyond it.
float beyond_neighbours(const int16_t* x, int n, int at, int skip, int eval) {
  const int lo = at - kSpikeReach > 0 ? at - kSpikeReach : 0;
  const int hi = at + skip + kSpikeReach < n ? at + skip + kSpikeReach : n;
  int32_t mn = INT32_MAX, mx = INT32_MIN;
  for (int j = lo; j < hi; ++j) {
    if (j == at) j += skip;
    if (j >= hi) break;
    const int32_t v = x[j];
    mn = v < mn ? v : mn;
    mx = v > mx ? v : mx;
  }
  if (mx < mn) return 0.0f;
  const int32_t range = mx - mn > 1 ? mx - mn : 1;
  float worst = -1.0f;
  for (int j = at; j < at + eval && j < n; ++j) {
    const int32_t v = x[j];
    const int32_t out = v > mx ? v - mx : (v < mn ? mn - v : 0);
    const float q = static_cast<float>(out) / static_cast<float>(range);
    worst = q > worst ? q : worst;
  }
  return worst;
}

// beyond_neighbours(x, n, i, 2, 1) (the range of the kSpikeReach samples either side of [i, i + 2)) where
// it exceeds kSpikeBeyond, else 0 or any value <= kSpikeBeyond. Any of the neighbours bounds x[i]'s excursion
// from above (it lies beyond their extreme) and the range from below (their own range, at least 1): taken
// nearest first, the scan stops once the excursion is no longer more than kSpikeBeyond ranges (2 out > kKeep
// range in integers; fl(out / range) > kSpikeBeyond implies it). A spike lies beyond them all and gets
// beyond_neighbours' own quotient (the same neighbours' min and max).
constexpr int32_t kKeep = static_cast<int32_t>(2.0f * kSpikeBeyond);
static_assert(static_cast<float>(kKeep) == 2.0f * kSpikeBeyond, "kSpikeBeyond must be a multiple of 1/2");
IC_NOINLINE float beyond_neighbours_over(const int16_t* x, int n, int i) {
  const int32_t v = x[i];
  int32_t mn = INT32_MAX, mx = INT32_MIN;
  for (int k = 1; k <= kSpikeReach; ++k) {
    const int l = i - k, r = i + 1 + k;  // [i, i + 2) left out
    if (l >= 0) {
      const int32_t u = x[l];
      mn = u < mn ? u : mn;
      mx = u > mx ? u : mx;
    }
    if (r < n) {
      const int32_t u = x[r];
      mn = u < mn ? u : mn;
      mx = u > mx ? u : mx;
    }
    if (mx < mn) continue;  // none yet
    const int32_t range = mx - mn > 1 ? mx - mn : 1;
    const int32_t out = v > mx ? v - mx : (v < mn ? mn - v : 0);
    if (2 * out <= kKeep * range) return 0.0f;
  }
  if (mx < mn) return 0.0f;
  const int32_t range = mx - mn > 1 ? mx - mn : 1;
  const int32_t out = v > mx ? v - mx : mn - v;
  return static_cast<float>(out) / static_cast<float>(range);
}

// A glitch inside the difference window [lo, hi) of a channel the ratio test sent (channel_features): with
// `largest`, the sample before the window's largest |Delta^2| (a lone spike's largest |Delta^2| is the term
// after it, a two-sample spike's one of the four it enters) tested like a late spike with the term ratio
// kArrivalSpikeTermRatio; failing that or without it, the sample lying furthest outside its neighbours' range
// when more than kSpikeBeyond ranges, which spike_at (ratio 1) must replace by a spike itself beyond them.
// Out of line: only such channels run it.
IC_NOINLINE bool find_inside_spike(const int16_t* x, int n, int lo, int hi, int icross, float thr, bool largest,
                                   Spike* sp) {
  if (largest) {
    int32_t big = 0;  // |Delta^2| < 2^18: exact as an integer as in a float
    int at = -1;
    for (int m = lo + 2; m < hi; ++m) {
      int32_t d = static_cast<int32_t>(x[m]) - 2 * static_cast<int32_t>(x[m - 1]) + x[m - 2];
      d = d < 0 ? -d : d;
      if (d > big) {
        big = d;
        at = m - 1;
      }
    }
    // spike_at(i) tries [i], [i, i + 1] and [i - 1, i]
    for (int i = at - 1; at >= 0 && i <= at + 2; ++i) {
      if (i > icross && i < n - 3 && may_be_spike(x, n, i, thr, kArrivalSpikeTermRatio) &&
          spike_at(x, n, i, thr, sp, kArrivalSpikeTermRatio)) {
        return true;
      }
    }
  }
  // The first of the samples lying furthest beyond their neighbours' range (beyond_neighbours(x, n, i, 2, 1)),
  // when more than kSpikeBeyond ranges. With the two nearest, a = x[i - 1] and b = x[i + 2], as the only
  // neighbours a sample outside [min(a, b), max(a, b)] lies out = (|s| - |d|) / 2 beyond them (s = 2 x[i] - a - b,
  // d = a - b) and one inside has |s| <= |d|: 2 out > kKeep max(|d|, 1), necessary for the whole range, is
  // |s| > max(4 |d|, 3) for kKeep = 3. A wave's sample mostly fails it (docs/findings.md, "Session 18:
  // spikecost"); the rest are tested with the next two, x[i - 2] and x[i + 3], as well, and those that pass
  // get beyond_neighbours_over.
  static_assert(kKeep == 3 && kSpikeReach >= 2, "the tests below are for kSpikeBeyond = 1.5");
  float best = kSpikeBeyond;
  int at = -1;
  const auto consider = [&](int i) {
    const float q = beyond_neighbours_over(x, n, i);
    if (q > best) {
      best = q;
      at = i;
    }
  };
  const int first = lo > 2 ? lo : 2, last = hi < n - 3 ? hi : n - 3;  // x[i - 2] .. x[i + 3] in the capture
  for (int i = lo; i < hi && i < first; ++i) consider(i);
  for (const int16_t* p = x + first; p < x + last; ++p) {
    const int32_t a = p[-1], b = p[2];
    int32_t s = 2 * static_cast<int32_t>(p[0]) - a - b, d = a - b;
    // |s| > 4 |d| needs s - 4 d and s + 4 d of one sign (their product is s^2 - 16 d^2): one test of the
    // two's signs (|s|, |d| < 2^18: no overflow) instead of two absolute values, on every sample.
    if (((s - 4 * d) ^ (s + 4 * d)) < 0) continue;
    s = s < 0 ? -s : s;
    d = d < 0 ? -d : d;
    if (s <= 4 * d || s <= 3) continue;
    const int32_t v = p[0], l = p[-2], r = p[3];
    int32_t mx = a > b ? a : b, mn = a < b ? a : b;
    mx = l > mx ? l : mx;
    mx = r > mx ? r : mx;
    mn = l < mn ? l : mn;
    mn = r < mn ? r : mn;
    const int32_t out = v > mx ? v - mx : (v < mn ? mn - v : 0);
    const int32_t range = mx - mn > 1 ? mx - mn : 1;
    if (2 * out > kKeep * range) consider(static_cast<int>(p - x));
  }
  for (int i = last > first ? last : first; i < hi; ++i) consider(i);
  for (int i = at; at >= 0 && i <= at + 1; ++i) {
    if (i > icross && i < n - 3 && spike_at(x, n, i, thr, sp, 1.0f) &&
        beyond_neighbours(x, n, sp->at, sp->width, sp->width) > kSpikeBeyond) {
      return true;
    }
  }
  return false;
}

// A spike's excess energy: its samples' squares about the baseline model less its replacement's.
float spike_excess(const int16_t* x, const Spike& sp, const Baseline& bl, float base) {
  float e = 0.0f;
  for (int j = 0; j < sp.width; ++j) {
    const int i = sp.at + j;
    const float b = bl.hum ? bl.level + hum_at(bl, static_cast<float>(i)) : base;
    const float e0 = static_cast<float>(x[i]) - b, e1 = static_cast<float>(sp.value[j]) - b;
    e += e0 * e0 - e1 * e1;
  }
  return e;
}

// What a glitch hunt inside the arrival starts from (channel_features records it on its first pass; open: the
// channel has an onset and room for another spike) and the window [lo, hi) it scans: from the pick (after
// the crossing) to n2, at most diff_window_us.
struct HuntWindow {  // no initialisers (no memset): the caller sets open false
  float toa, thr;
  int icross, n2;
  bool open;
  void bounds(const CoreConfig& cfg, int n, int* lo, int* hi) const {
    *lo = static_cast<int>(toa) > icross ? static_cast<int>(toa) : icross + 1;
    *hi = n2 + 1;
    const int cap = static_cast<int>(cfg.diff_window_us * cfg.fs_hz * 1.0e-6f + 0.5f);
    if (cap > 0 && *lo + cap < *hi) *hi = *lo + cap;
    if (*hi > n - 1) *hi = n - 1;
  }
};

void channel_features(const int16_t* x, int n, const CoreConfig& cfg, int c, HumBasis* basis,
                      ChannelFeatures* f, HuntWindow* window, int hunt = kHuntNone) {
  static_assert(sizeof(Channel) < 9000, "Channel lives on the stack");
  IC_WORK(channel_passes, 1);
  Channel ch;
  ch.x = x;
  ch.n = n;
  ch.nblk = block_prefix_sums(x, n, ch.prefix);  // the one pass over the capture
  Baseline bl;
  fit_baseline(x, n, ch.prefix, cfg.baseline_samples, cfg.fs_hz, cfg.hum_min_counts, basis, &bl);
  ch.set_baseline(bl.kept_n, bl.kept.s1);
  ch.set_centre();
  f->baseline = bl.level;
  f->noise_rms = bl.noise_rms;
  f->hum_counts = 0.0f;
  const float base = f->baseline;
  f->flags = bl.glitch_parts > 0 ? kFlagGlitch : 0;
  if (bl.hum) {
    // The hum's slope inflates the baseline's rms: the noise floor is the parts' rms about their own
    // lines (hum_noise_rms).
    f->noise_rms = hum_noise_rms(x, bl, cfg.baseline_samples);
    f->hum_counts = bl.hum_amp;
    f->flags |= kFlagHum;
    IC_WORK(hum_channels, 1);
  }

  // Onset threshold crossing (sub-sample). The threshold is in unit-gain counts: a channel with gain g
  // crosses at the same wave phase.
  const float gain = cfg.channel_gain[c] > 0.0f ? cfg.channel_gain[c] : 1.0f;
  float thr = cfg.onset_threshold_counts * gain;
  const float noise_thr = cfg.onset_noise_factor * f->noise_rms;
  if (noise_thr > thr) thr = noise_thr;
  int at = -1, spikes = 0;
  float cross = -1.0f;
  LocalHum local;
  HumEnergy hum_e;  // 4 KB of stack beside Channel's 8.2 KB, one channel at a time
  local.bl = &bl;
  local.r = base - bl.level;  // 0: without a hum the local model is the level
  if (bl.hum) {
    hum_e.steps.set(bl, *basis);
    cross = hum_crossing(ch, bl, thr, cfg.baseline_samples, &at, &spikes, &local, hum_e.steps, &hum_e.scan);
  } else {
    for (int from = cfg.baseline_samples;;) {
      cross = ch.fits32 ? crossing<true>(ch, base, thr, from, &at) : crossing<false>(ch, base, thr, from, &at);
      if (at < 0 || !is_transient(x, n, at, base, thr)) break;
      ++spikes;
      IC_WORK(transients, 1);
      from = at + 3;
    }
  }
  if (spikes > 0) f->flags |= kFlagGlitch;

  // Energy, peak and clipping over the whole capture.
  const int64_t energy_scaled = ch.energy_to_block(ch.nblk);
  if (bl.hum) hum_e.build(ch, bl, base, *basis);
  const float energy = bl.hum ? hum_e.to_block(ch.nblk) : ch.to_energy(energy_scaled);
  // Below the threshold from baseline_samples to the crossing (peak_abs skips those blocks) only when no
  // transient was passed over and the baseline is the level.
  const int below_from = (spikes > 0 || bl.hum) ? n : cfg.baseline_samples;
  const float peak = bl.hum ? hum_peak(ch, base, at, hum_e.scan)
                            : ch.fits32 ? peak_abs<true>(ch, base, at, below_from)
                                        : peak_abs<false>(ch, base, at, below_from);
  f->energy = energy;
  f->peak = peak;
  if (ch.fits32 ? clipped<true>(ch, base, peak, at, cfg.adc_min, cfg.adc_max)
                 : clipped<false>(ch, base, peak, at, cfg.adc_min, cfg.adc_max)) {
    f->flags |= kFlagClipped;
  }

  const float signal_rms = vsqrt_f32(energy / static_cast<float>(n));
  if (peak == 0.0f || signal_rms < cfg.dead_rms_counts) f->flags |= kFlagDead;

  // AIC refinement in a window around the crossing.
  f->toa_threshold = cross;
  f->toa_aic = kNaN;
  f->first_peak = 0.0f;
  f->pick_period = kNaN;
  f->n2 = n - 1;
  for (int w = 0; w < kEnergyWindows; ++w) f->window_energy[w] = 0.0f;
  for (int k = 0; k < kDiffOrders; ++k) f->diff_energy[k] = 0.0f;
  f->residual_ratio = kNaN;
  if (cross < 0.0f || (f->flags & kFlagDead) || cfg.channel_left_out[c]) {
    f->flags |= kFlagNoOnset;
    f->toa_us = kNaN;
    apply_gain(f, cfg.channel_gain[c]);
    return;
  }
  const int icross = static_cast<int>(cross);
  int begin = icross - cfg.aic_before;
  if (begin < 0) begin = 0;
  int end = icross + cfg.aic_after + 1;
  if (end > n) end = n;
  // The onset is sought in the last quarter of the samples before the crossing (the AIC minimum lies a few
  // samples before it on recorded drops); the earlier samples give the noise variance. Same picks as the whole-window search there, at
  // less than half the logarithms (docs/findings.md, "The per-event cost").
  bool clean_copy = bl.hum != 0;
  if (!clean_copy && icross > begin) {   // a glitch before the crossing would set the AIC's noise variance
    int32_t lo, hi;
    range_extremes(x, begin, icross, &lo, &hi);
    clean_copy = static_cast<float>(hi) - base >= thr || base - static_cast<float>(lo) >= thr;
  }
  local.set_near(0.5f * static_cast<float>(begin + end - 1));  // the hum about the AIC window (a hum channel)
  const float aic = clean_copy ? aic_on_clean_copy(x, local, begin, end, icross, thr, icross - cfg.aic_before / 4)
                               : aic_pick_subsample(x, begin, end, icross - cfg.aic_before / 4);
  float toa = cross;
  if (aic >= 0.0f && aic <= cross + 1.0f) {
    f->toa_aic = aic;
    toa = (1.0f - cfg.aic_blend) * cross + cfg.aic_blend * f->toa_aic;
  } else {
    f->flags |= kFlagAicFallback;
  }
  f->toa_us = toa * (1.0e6f / cfg.fs_hz) - channel_delay_us(cfg, c);

  const float base_on = local.model_near(cross);
  const int ipk = first_extremum(x, n, base_on, icross);
  f->first_peak = fabsf(static_cast<float>(x[ipk]) - base_on);
  f->pick_period = pick_period(x, n, base_on, cross, (f->flags & kFlagClipped) == 0);

  // n2: where the cumulative energy stops growing (reaches n2_fraction of the total).
  int n2 = bl.hum ? hum_e.reaches(cfg.n2_fraction * energy)
                  : energy_reaches(ch, ceil_to_int64(cfg.n2_fraction * to_float(energy_scaled)));
  // A glitch where n2 landed: its excess energy (its square about the baseline model less the
  // replacement's) leaves the total n2 is sought in (f->energy stays the whole capture's), and n2 is
  // sought again (spike_at).
  Spike late[kMaxSpikes];
  int n_spikes = 0;
  float excess[kMaxSpikes] = {0.0f, 0.0f};
  float spike_energy = 0.0f;
  while (n_spikes < kMaxSpikes && n2 > icross && n2 < n - 3 && may_be_spike(x, n, n2, thr) &&
         spike_at(x, n, n2, thr, &late[n_spikes])) {
    const float e = spike_excess(x, late[n_spikes], bl, base);
    excess[n_spikes++] = e;
    spike_energy += e;
    f->flags |= kFlagGlitch;
    const float target = cfg.n2_fraction * (energy - spike_energy);
    n2 = bl.hum ? hum_e.reaches(target) : energy_reaches(ch, ceil_to_int64(target * ch.nb2));
  }
  // A glitch inside the arrival (extract_features asks when this channel's Delta^3 / Delta^1 energy ratio
  // stands out from the other channels'): above kArrivalSpikeRatio x their median the sample before the
  // largest |Delta^2| of the difference window, tested like a late one; failing that (or between
  // kArrivalSpikeBeyondRatio and kArrivalSpikeRatio x) the window's sample lying furthest outside its
  // neighbours' range, when more than kSpikeBeyond ranges (beyond_neighbours). Scans of that window, only on
  // such channels. Its excess also leaves the cumulative energy beyond it: n2's target gains it while n2
  // stays beyond the spike.
  *window = HuntWindow{toa, thr, icross, n2, n_spikes < kMaxSpikes};
  if (hunt != kHuntNone && window->open) {
    int lo, hi;
    window->bounds(cfg, n, &lo, &hi);
    Spike& sp = late[n_spikes];
    IC_WORK(spike_hunts, 1);
    if (find_inside_spike(x, n, lo, hi, icross, thr, hunt == kHuntLargest, &sp)) {
      sp.inside = true;
      const float e = spike_excess(x, sp, bl, base);
      excess[n_spikes++] = e;
      spike_energy += e;
      f->flags |= kFlagGlitch;
      const float target = cfg.n2_fraction * (energy - spike_energy);
      n2 = bl.hum ? hum_e.reaches(target + e) : energy_reaches(ch, ceil_to_int64((target + e) * ch.nb2));
      if (n2 < sp.at) n2 = bl.hum ? hum_e.reaches(target) : energy_reaches(ch, ceil_to_int64(target * ch.nb2));
    }
  }
  f->n2 = n2;
  // Five equal windows from the onset to n2; the last one is the residual energy.
  const int start = static_cast<int>(toa);
  const int span = n2 + 1 - start;
  if (span >= kEnergyWindows) {
    if (bl.hum) {
      float at = hum_e.to(start);
      for (int w = 0; w < kEnergyWindows; ++w) {
        const float next = hum_e.to(start + (span * (w + 1)) / kEnergyWindows);
        f->window_energy[w] = next - at;
        at = next;
      }
    } else {
      int64_t at = ch.energy_to(start);
      for (int w = 0; w < kEnergyWindows; ++w) {
        const int b = start + (span * (w + 1)) / kEnergyWindows;
        const int64_t next = ch.energy_to(b);
        f->window_energy[w] = ch.to_energy(next - at);
        at = next;
      }
    }
    for (int k = 0; k < n_spikes; ++k) {
      const int i = late[k].at;
      for (int w = 0; w < kEnergyWindows; ++w) {
        if (i >= start + (span * w) / kEnergyWindows && i < start + (span * (w + 1)) / kEnergyWindows) {
          const float e = f->window_energy[w] - excess[k];
          f->window_energy[w] = e > 0.0f ? e : 0.0f;
        }
      }
    }
    const float arrival_total = energy - spike_energy;  // the capture's, less the glitches' excess
    f->residual_ratio = arrival_total > 0.0f ? f->window_energy[kEnergyWindows - 1] / arrival_total : kNaN;
  }
  // Difference energies over the first diff_window_us of the arrival (at most up to n2): the only
  // per-sample pass besides the block sums. Most of the high-frequency energy arrives in the first few
  // ms; a longer window costs instructions and adds little (README of impactapp).
  int dend = n2 + 1;
  const int dcap = static_cast<int>(cfg.diff_window_us * cfg.fs_hz * 1.0e-6f + 0.5f);
  if (dcap > 0 && start + dcap < dend) dend = start + dcap;
  if (dend > start && start >= kDiffOrders) {
    int64_t d[kDiffOrders];
    difference_energies(x, start, dend, d);
    for (int k = 0; k < n_spikes; ++k) {
      // a spike inside the window: its terms with the replacement's samples
      const Spike& sp = late[k];
      const int a = sp.at > start ? sp.at : start;
      const int b = sp.at + sp.width + 3 < dend ? sp.at + sp.width + 3 : dend;
      if (b <= a) continue;
      int64_t o[kDiffOrders], p[kDiffOrders];
      local_difference_energies(x, Spike(), a, b, o);
      local_difference_energies(x, sp, a, b, p);
      if (sp.inside) {
        // Inside the arrival the line through the neighbours misses a ringing's sample by up to ~0.7 x
        // its amplitude: the terms the spike enters take the mean of the kSpikeFill terms either side
        // instead (the ringing's local level; integer sums, the same on host and board).
        const int la = a - kSpikeFill > start ? a - kSpikeFill : start;
        const int hb = b + kSpikeFill < dend ? b + kSpikeFill : dend;
        const int64_t count = (a - la) + (hb - b);
        if (count > 0) {
          int64_t q1[kDiffOrders], q2[kDiffOrders];
          local_difference_energies(x, Spike(), la, a, q1);
          local_difference_energies(x, Spike(), b, hb, q2);
          for (int m = 0; m < kDiffOrders; ++m) p[m] = (q1[m] + q2[m]) * (b - a) / count;
        }
      }
      for (int m = 0; m < kDiffOrders; ++m) d[m] += p[m] - o[m];
    }
    // Less the noise floor's share: white noise of variance s^2 adds C(2k, k) s^2 = 2, 6, 20 s^2 a sample
    // to (Delta^k x)^2, and Delta^3 weights the noise's high frequencies like the contact's (2 counts of
    // added noise raised the Delta^3 energy ~7 % and the twin's heights with it: docs/findings.md, "A
    // faulty lab"). s is the baseline's noise_rms (hum removed); clean captures lose ~3 % of Delta^3.
    const float noise = f->noise_rms * f->noise_rms * static_cast<float>(dend - start);
    for (int k = 0; k < kDiffOrders; ++k) {
      const float e = to_float(d[k]) - kNoiseDiffGain[k] * noise;
      f->diff_energy[k] = e > 0.0f ? e : 0.0f;
    }
  }
  apply_gain(f, cfg.channel_gain[c]);
}

}  // namespace

int32_t extract_features(const int16_t* const adc[kChannels], int n, const CoreConfig& cfg,
                         EventFeatures* out) {
  if (out == nullptr) return kErrNullInput;
  out->status = kOk;
  for (int c = 0; c < kChannels; ++c) {
    if (adc[c] == nullptr) return out->status = kErrNullInput;
  }
  if (n > kMaxSamples) return out->status = kErrTooManySamples;
  if (cfg.baseline_samples < 2 || cfg.baseline_samples > kMaxBaselineSamples ||
      n < cfg.baseline_samples + 16) {
    return out->status = kErrTooFewSamples;
  }
  if (!(cfg.fs_hz > 0.0f) || cfg.aic_before < 0 || cfg.aic_after < 0 ||
      cfg.aic_before + cfg.aic_after + 1 > kMaxAicWindow || !(cfg.n2_fraction > 0.0f) ||
      cfg.n2_fraction > 1.0f || !(cfg.diff_window_us >= 0.0f)) {
    return out->status = kErrBadConfig;
  }
  if (check_bond_inverse(cfg) != kOk) return out->status = kErrBadConfig;
  // A channel with a bond inverse is read, from here on, through it, and only on its span [0, E)
  // (bond_span_end: the other channels' first crossing sets where the windows its features read end): one
  // buffer of kBondSpanMax samples a channel (kMaxBondChannels; the host's batches may run on several threads,
  // the board has one and no thread storage). The other channels are done first, as without an inverse.
#if defined(__ARM_ARCH) && !defined(__linux__)
  static int16_t bond_buffer[kMaxBondChannels][kBondSpanMax];
#else
  static thread_local int16_t bond_buffer[kMaxBondChannels][kBondSpanMax];
#endif
  const int16_t* ch_adc[kChannels];
  int ch_n[kChannels];
  int onsets = 0;
  // The rate's hum basis, kept from event to event (filled when a hum is first fitted at this rate; the host's
  // batches may run on several threads: one each).
#if defined(__ARM_ARCH) && !defined(__linux__)
  static HumBasis basis;
#else
  static thread_local HumBasis basis;
#endif
  basis.event_mains = 0;  // one mains frequency an event: named by a channel's fit (fit_baseline)
  HuntWindow window[kChannels];
  bool bonded = false;
  float anchor = INFINITY;
  for (int c = 0; c < kChannels; ++c) {
    ch_adc[c] = adc[c];
    ch_n[c] = n;
    window[c].open = false;
    if (bond_inverse_on(cfg, c)) {
      bonded = true;
      continue;
    }
    channel_features(adc[c], n, cfg, c, &basis, &out->ch[c], &window[c]);
    if (!(out->ch[c].flags & kFlagNoOnset) && out->ch[c].toa_threshold < anchor) anchor = out->ch[c].toa_threshold;
  }
  if (bonded) {
    const int e = bond_span_end(cfg, n, anchor < INFINITY ? anchor : -1.0f);
    for (int c = 0, b = 0; c < kChannels; ++c) {
      if (!bond_inverse_on(cfg, c)) continue;
      bond_inverse(adc[c], e, cfg.bond_corner_hz[c], cfg.bond_gain[c], cfg.bond_limit_hz[c], cfg, bond_buffer[b]);
      ch_adc[c] = bond_buffer[b++];
      ch_n[c] = e;
      channel_features(ch_adc[c], e, cfg, c, &basis, &out->ch[c], &window[c]);
    }
  }
  adc = ch_adc;
  // A glitch inside one channel's arrival raises its Delta^3 / Delta^1 energy ratio (a lone spike's is 10;
  // an arrival's is set by the contact and the plate, alike on every channel: on the bundled sessions, clean
  // or with noise and hum, at most 2.7 x the median of the other channels'): a channel above
  // kArrivalSpikeRatio x that median is done again hunting the spike (channel_features); one above
  // kArrivalSpikeBeyondRatio x (a broadband arrival's ratio is nearer a spike's, so the spike raises it
  // less) seeking a sample beyond its neighbours' range. Four divisions an event; the scans only on such
  // channels.
  float ratio[kChannels];
  int n_ratio = 0;
  for (int c = 0; c < kChannels; ++c) {
    const ChannelFeatures& f = out->ch[c];
    ratio[c] = NAN;
    if ((f.flags & (kFlagNoOnset | kFlagClipped | kFlagDead)) == 0 && f.diff_energy[0] > 0.0f) {
      ratio[c] = f.diff_energy[2] / f.diff_energy[0];
      ++n_ratio;
    }
  }
  if (n_ratio >= 3) {
    for (int c = 0; c < kChannels; ++c) {
      if (!(ratio[c] == ratio[c])) continue;
      float o[kChannels - 1];
      int m = 0;
      for (int k = 0; k < kChannels; ++k) {
        if (k != c && ratio[k] == ratio[k]) o[m++] = ratio[k];
      }
      // the median of the others (of two, the larger)
      float med;
      if (m == 3) {
        const float lo = o[0] < o[1] ? o[0] : o[1], hi = o[0] < o[1] ? o[1] : o[0];
        med = o[2] < lo ? lo : (o[2] > hi ? hi : o[2]);
      } else {
        med = o[0] > o[1] ? o[0] : o[1];
      }
      const int hunt = ratio[c] > kArrivalSpikeRatio * med ? kHuntLargest : ratio[c] > kArrivalSpikeBeyondRatio * med ? kHuntBeyond : kHuntNone;
      // The hunt runs on the first pass's window; only where it finds a glitch is the channel done again
      // (without one, channel_features would return what it did).
      if (hunt == kHuntNone || !window[c].open) continue;
      Spike probe;
      int lo, hi;
      window[c].bounds(cfg, ch_n[c], &lo, &hi);
      IC_WORK(spike_hunts, 1);
      if (find_inside_spike(adc[c], ch_n[c], lo, hi, window[c].icross, window[c].thr, hunt == kHuntLargest, &probe)) {
        channel_features(adc[c], ch_n[c], cfg, c, &basis, &out->ch[c], &window[c], hunt);
      }
    }
  }
  for (int c = 0; c < kChannels; ++c) {
    if (!(out->ch[c].flags & kFlagNoOnset)) ++onsets;
  }
  for (int p = 0; p < kPairs; ++p) {
    out->dtoa_us[p] = out->ch[kPairI[p]].toa_us - out->ch[kPairJ[p]].toa_us;
  }
  // The band picks, all in one window from the first threshold crossing (band_onset; off by default).
  float first = INFINITY;
  for (int c = 0; c < kChannels; ++c) {
    out->ch[c].toa_band_us = kNaN;
    if (!(out->ch[c].flags & kFlagNoOnset) && out->ch[c].toa_threshold < first) first = out->ch[c].toa_threshold;
  }
  if (cfg.band_pick_hz > 0.0f && first < INFINITY) {
    for (int c = 0; c < kChannels; ++c) {
      if (out->ch[c].flags & (kFlagNoOnset | kFlagDead)) continue;
      const float s = band_onset(adc[c], ch_n[c], out->ch[c].baseline, out->ch[c].noise_rms, static_cast<int>(first), cfg);
      out->ch[c].toa_band_us = s * (1.0e6f / cfg.fs_hz) - cfg.capture_delay_us[c];
    }
  }
  // ToA order: insertion sort, channels without an onset last.
  for (int c = 0; c < kChannels; ++c) out->order[c] = static_cast<uint8_t>(c);
  for (int a = 1; a < kChannels; ++a) {
    const uint8_t key = out->order[a];
    const float tk = out->ch[key].toa_us;
    int b = a - 1;
    while (b >= 0) {
      const float tb = out->ch[out->order[b]].toa_us;
      const bool later = (tb != tb) ? (tk == tk) : (tk == tk && tk < tb);
      if (!later) break;
      out->order[b + 1] = out->order[b];
      --b;
    }
    out->order[b + 1] = key;
  }
  if (onsets == 0) out->status = kErrNoTrigger;
  return out->status;
}

}  // namespace impactcore
