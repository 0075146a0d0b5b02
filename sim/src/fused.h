// The stepper's inner loop: one element row and the central-difference update of the node row below it in a
// single pass, 16 elements at a time (GCC/Clang vector extensions: the compiler maps a 16-float vector onto
// one AVX-512, two AVX2 or four SSE registers in each multiversioned clone).
//
// Same element as element.h (see there for the algebra). Per block of 16 elements i0..i0+15 of row j:
//   P = P_in + B0, Q = Q_in + B1 (node row j: P_in, Q_in hold the top-edge terms of element row j - 1),
//   top-edge terms T0, T1 stored as node row j + 1's P_in, Q_in,
//   nodal force f_i = (P_i - Q_i) + (P_{i-1} + Q_{i-1}), the i - 1 term shifted in from the previous block,
//   d = alpha d - beta f, u += d   (node row j is final: element rows j - 1 and j have used it).
// State rows are padded to a multiple of 16 floats (plus one block), 64-byte aligned; padding holds zeros
// and beta = 0, so it stays zero. Elements past nx in the last block are masked out.
#pragma once

#if !defined(IMPACTSIM_NO_FUSED) && ((defined(__GNUC__) && __GNUC__ >= 12) || defined(__clang__))
#define IMPACTSIM_FUSED 1

#include <cstdint>
#include <cstring>

#include "element.h"

#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wpsabi"  // the vector helpers are always inlined: no ABI crosses a call
#endif

namespace impactsim {
namespace detail {

constexpr int kLanes = 16;
typedef float v16 __attribute__((vector_size(64)));

IMPACTSIM_INLINE v16 vload(const float* p) {
  v16 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
IMPACTSIM_INLINE void vstore(float* p, v16 v) { std::memcpy(p, &v, sizeof v); }
// [prev[15], cur[0], ..., cur[14]]: the value of lane i - 1
IMPACTSIM_INLINE v16 from_left(v16 prev, v16 cur) {
  return __builtin_shufflevector(prev, cur, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30);
}

struct FusedRow {
  float* u0[3];          // node row j (read, then updated), fields w, bx, by
  const float* u1[3];    // node row j + 1 (read)
  float* db;             // node row j: d = dt * velocity and beta = dt^2 / ((1 + cd) m) (0 at fixed dofs and
                         // padding), block-interleaved [block][d w, bx, by | beta w, bx, by][16 lanes] (db_at)
  const float* in;       // P_w, Q_w, P_x, Q_x, P_y, Q_y of node row j, interleaved by block (edge_at)
  float* out;            // the same for node row j + 1 (written)
};

// Edge arrays are stored block-interleaved, [block][6 arrays][16 lanes], so one pointer reaches all six.
constexpr int kEdgeBlock = 6 * kLanes;
IMPACTSIM_INLINE int64_t edge_at(int64_t i, int q) { return (i / kLanes) * kEdgeBlock + q * kLanes + i % kLanes; }
// d and beta likewise: d of field f at db_at(i, f), beta at db_at(i, f) + kBetaOffset.
constexpr int kBetaOffset = 3 * kLanes;
IMPACTSIM_INLINE int64_t db_at(int64_t i, int f) { return edge_at(i, f); }

// d: this block's d of the field (beta kBetaOffset further on)
IMPACTSIM_INLINE void update_block(int i0, v16 p, v16 q, v16& carry, float alpha, float* u, v16 u_now, float* d) {
  const v16 r = p + q;
  const v16 f = (p - q) + from_left(carry, r);
  carry = r;
  const v16 dn = alpha * vload(d) - vload(d + kBetaOffset) * f;
  vstore(d, dn);
  vstore(u + i0, u_now + dn);
}

// Scaled: element i has bending stiffness ds[i] D0 and shear stiffness ss[i] S0 (disc elements).
// Coupled: the material's coupling terms (Coef::coupled: material axes not along x, y).
template <bool Masked, bool Scaled, bool Coupled>
IMPACTSIM_INLINE void element_block(int i0, v16 mask, const Coef<float>& k, float alpha, const FusedRow& r,
                                    const float* ds, const float* ss, v16 carry[3]) {
  const v16 w0 = vload(r.u0[0] + i0), w0n = vload(r.u0[0] + i0 + 1);
  const v16 w1 = vload(r.u1[0] + i0), w1n = vload(r.u1[0] + i0 + 1);
  const v16 x0 = vload(r.u0[1] + i0), x0n = vload(r.u0[1] + i0 + 1);
  const v16 x1 = vload(r.u1[1] + i0), x1n = vload(r.u1[1] + i0 + 1);
  const v16 y0 = vload(r.u0[2] + i0), y0n = vload(r.u0[2] + i0 + 1);
  const v16 y1 = vload(r.u1[2] + i0), y1n = vload(r.u1[2] + i0 + 1);
  const v16 dwb = w0n - w0, dwt = w1n - w1, swb = w0 + w0n, swt = w1 + w1n;
  const v16 dxb = x0n - x0, dxt = x1n - x1, sxb = x0 + x0n, sxt = x1 + x1n;
  const v16 dyb = y0n - y0, dyt = y1n - y1, syb = y0 + y0n, syt = y1 + y1n;
  const v16 c1w = dwb + dwt, c2w = swt - swb, c3w = dwt - dwb;
  const v16 c0x = sxb + sxt, c1x = dxb + dxt, c2x = sxt - sxb, c3x = dxt - dxb;
  const v16 c0y = syb + syt, c1y = dyb + dyt, c2y = syt - syb, c3y = dyt - dyb;
  v16 sa = k.sa + v16{}, sa3 = k.sa3 + v16{}, sb = k.sb + v16{}, sb3 = k.sb3 + v16{};
  v16 h3x = k.h3x + v16{}, h3y = k.h3y + v16{};
  v16 dsc = 1.0f + v16{}, sv = 1.0f + v16{};
  if (Scaled) {
    sv = vload(ss + i0);
    dsc = vload(ds + i0);
    sa *= sv, sa3 *= sv, sb *= sv, sb3 *= sv, h3x *= dsc, h3y *= dsc;
  }
  const v16 gx0 = c1w * k.ka + c0x, gy0 = c2w * k.kb + c0y;
  v16 qx0 = sa * gx0, qy0 = sb * gy0;
  const v16 qx1 = sa3 * (c3w * k.ka + c2x), qy1 = sb3 * (c3w * k.kb + c1y);
  v16 g1x = k.b11 * c1x + k.b12 * c2y, g2y = k.b12 * c1x + k.b22 * c2y;
  v16 tx = k.c22 * c2x + k.c12 * c1y, ty = k.c12 * c2x + k.c11 * c1y;
  v16 g3x = h3x * c3x, g3y = h3y * c3y;
  if (Coupled) {
    const v16 sc = Scaled ? k.sc * sv : k.sc + v16{};
    qx0 += sc * gy0, qy0 += sc * gx0;
    g1x += k.e16 * c2x + k.f16 * c1y, g2y += k.f26 * c2x + k.e26 * c1y;
    tx += k.e16 * c1x + k.f26 * c2y, ty += k.f16 * c1x + k.e26 * c2y;
    const v16 h3c = Scaled ? k.h3c * dsc : k.h3c + v16{};
    g3x += h3c * c3y, g3y += h3c * c3x;
  }
  if (Scaled) g1x *= dsc, g2y *= dsc, tx *= dsc, ty *= dsc;
  const v16 g1w = qx0 * k.ka, g2w = qy0 * k.kb, g3w = qx1 * k.ka + qy1 * k.kb;
  const v16 g2x = qx1 + tx;
  const v16 g1y = qy1 + ty;
  v16 bpw = -g2w, bqw = g1w - g3w, tpw = g2w, tqw = g1w + g3w;
  v16 bpx = qx0 - g2x, bqx = g1x - g3x, tpx = qx0 + g2x, tqx = g1x + g3x;
  v16 bpy = qy0 - g2y, bqy = g1y - g3y, tpy = qy0 + g2y, tqy = g1y + g3y;
  if (Masked) {
    bpw *= mask, bqw *= mask, tpw *= mask, tqw *= mask;
    bpx *= mask, bqx *= mask, tpx *= mask, tqx *= mask;
    bpy *= mask, bqy *= mask, tpy *= mask, tqy *= mask;
  }
  float* const out = r.out + 6 * i0;
  const float* const in = r.in + 6 * i0;
  vstore(out, tpw);
  vstore(out + kLanes, tqw);
  vstore(out + 2 * kLanes, tpx);
  vstore(out + 3 * kLanes, tqx);
  vstore(out + 4 * kLanes, tpy);
  vstore(out + 5 * kLanes, tqy);
  float* const db = r.db + 6 * i0;
  update_block(i0, vload(in) + bpw, vload(in + kLanes) + bqw, carry[0], alpha, r.u0[0], w0, db);
  update_block(i0, vload(in + 2 * kLanes) + bpx, vload(in + 3 * kLanes) + bqx, carry[1], alpha, r.u0[1], x0,
               db + kLanes);
  update_block(i0, vload(in + 4 * kLanes) + bpy, vload(in + 5 * kLanes) + bqy, carry[2], alpha, r.u0[2], y0,
               db + 2 * kLanes);
}

// Blocks b_lo..b_hi only (16-node blocks; nodes outside at rest, so the carry into b_lo is zero).
template <bool Coupled>
IMPACTSIM_INLINE void fused_row_of(int nx, const Coef<float>& k, float alpha, const FusedRow& r,
                                   const uint8_t* scaled, const float* ds, const float* ss, int b_lo, int b_hi) {
  v16 carry[3] = {v16{}, v16{}, v16{}};
  const int full = nx / kLanes;
  if (b_hi < full) {
    for (int b = b_lo; b <= b_hi; ++b) {
      if (scaled && scaled[b])
        element_block<false, true, Coupled>(b * kLanes, v16{}, k, alpha, r, ds, ss, carry);
      else
        element_block<false, false, Coupled>(b * kLanes, v16{}, k, alpha, r, ds, ss, carry);
    }
    return;
  }
  for (int b = b_lo; b < full; ++b) {
    if (scaled && scaled[b])
      element_block<false, true, Coupled>(b * kLanes, v16{}, k, alpha, r, ds, ss, carry);
    else
      element_block<false, false, Coupled>(b * kLanes, v16{}, k, alpha, r, ds, ss, carry);
  }
  const int rest = nx - full * kLanes;
  if (rest > 0) {  // elements past nx masked; node nx lies in this block
    v16 mask{};
    for (int l = 0; l < rest; ++l) mask[l] = 1.0f;
    if (scaled && scaled[full])
      element_block<true, true, Coupled>(full * kLanes, mask, k, alpha, r, ds, ss, carry);
    else
      element_block<true, false, Coupled>(full * kLanes, mask, k, alpha, r, ds, ss, carry);
  } else {  // node nx: only element nx - 1 (lane 15 of the carry)
    for (int fld = 0; fld < 3; ++fld) {
      const float f = carry[fld][kLanes - 1];
      float* const d = r.db + db_at(nx, fld);
      const float dn = alpha * d[0] - d[kBetaOffset] * f;
      d[0] = dn;
      r.u0[fld][nx] += dn;
    }
  }
}

// Element row j (nx elements) and node row j (nodes 0..nx). scaled: null, or one flag per block (then ds, ss
// hold the row's stiffness ratios, see element_block).
IMPACTSIM_INLINE void fused_row(int nx, const Coef<float>& k, float alpha, const FusedRow& r, const uint8_t* scaled,
                                const float* ds, const float* ss, int b_lo, int b_hi) {
  if (k.coupled)
    fused_row_of<true>(nx, k, alpha, r, scaled, ds, ss, b_lo, b_hi);
  else
    fused_row_of<false>(nx, k, alpha, r, scaled, ds, ss, b_lo, b_hi);
}

// The last node row (ny): forces from element row ny - 1 only (r.in), nodes 0..nx.
IMPACTSIM_INLINE void last_row(int nx, float alpha, const FusedRow& r, int b_lo, int b_hi) {
  v16 carry[3] = {v16{}, v16{}, v16{}};
  for (int i0 = b_lo * kLanes; i0 <= nx && i0 <= b_hi * kLanes; i0 += kLanes)
    for (int fld = 0; fld < 3; ++fld)
      update_block(i0, vload(r.in + 6 * i0 + 2 * fld * kLanes), vload(r.in + 6 * i0 + (2 * fld + 1) * kLanes),
                   carry[fld], alpha, r.u0[fld],
                   vload(r.u0[fld] + i0), r.db + 6 * i0 + fld * kLanes);
}

}  // namespace detail
}  // namespace impactsim

#endif
