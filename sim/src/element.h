// The MITC4 Mindlin-Reissner rectangle in stencil form for a structured grid: one pass over an element row
// vectorised across elements, no per-element data (all elements share one stiffness; elements that differ,
// e.g. under a disc, are added as corrections K(D - D0, S - S0), the element being linear in D and S).
//
// Bilinear field per element: u = c0 + c1 xi + c2 eta + c3 xi eta, a = hx/2, b = hy/2, nodes
// 1..4 = (-,-), (+,-), (+,+), (-,+). With the edge sums/differences of the bottom (b) and top (t) node rows,
// S = u_left + u_right, D = u_right - u_left:  4c0 = Sb + St, 4c1 = Db + Dt, 4c2 = St - Sb, 4c3 = Dt - Db.
// Curvatures k = (bx,x, by,y, bx,y + by,x) are linear; the exact (2x2 Gauss) bending energy splits into the
// centre term (weight 4ab) and the xi- and eta-linear "hourglass" terms (weight 4ab/3).
// MITC4 shear: gamma_xz = (c1w/a + c0x) + eta (c3w/a + c2x) (tied at edge midpoints xi = 0, eta = +-1),
//              gamma_yz = (c2w/b + c0y) + xi  (c3w/b + c1y).
// Material (impactsim.h Material): moments M = D k, shear forces Q = S gamma; the centre terms carry every
// coupling; the hourglass terms couple C3x and C3y through D16 / a^2 + D26 / b^2; the shear's linear parts
// (eta in gamma_xz, xi in gamma_yz) integrate to zero against each other, so S_xy enters the centre only.
// Element nodal forces dU/du: f_n = g0 + xi_n g1 + eta_n g2 + xi_n eta_n g3 (the g below carry every 1/4).
// Assembly in edge form: per field, the bottom edge of element (i, j) adds B0 = g0 - g2, B1 = g1 - g3 to the
// accumulators P, Q of node row j at edge i, the top edge T0 = g0 + g2, T1 = g1 + g3 to those of row j + 1;
// then node i of a row gets f_i = P[i] - Q[i] + P[i-1] + Q[i-1] (P, Q zero outside 0..nx-1).
#pragma once

#include <cstdint>

#include "impactsim.h"  // detail::Coef

#if defined(__GNUC__)
#define IMPACTSIM_INLINE inline __attribute__((always_inline))  // into each multiversioned stepper clone
#else
#define IMPACTSIM_INLINE inline
#endif

namespace impactsim {
namespace detail {

template <typename Real>
struct RowIn {  // node rows j (0) and j + 1 (1) of the three fields, at the first element's left node
  const Real *w0, *w1, *x0, *x1, *y0, *y1;
  RowIn at(int64_t i) const { return {w0 + i, w1 + i, x0 + i, x1 + i, y0 + i, y1 + i}; }
};

template <typename Real>
struct RowAcc {  // edge accumulators P, Q of one node row for the three fields, at the first element's edge
  Real *pw, *qw, *px, *qx, *py, *qy;
  RowAcc at(int64_t i) const { return {pw + i, qw + i, px + i, qx + i, py + i, qy + i}; }
};

// Elements 0..n-1 of a row: adds their bottom-edge terms into lo; top-edge terms are stored into hi
// (AddTop = false: first pass over a row, hi is fresh) or added (AddTop = true: corrections).
template <typename Real, bool AddTop>
IMPACTSIM_INLINE void element_row(int n, const RowIn<Real>& in, const Coef<Real>& k, const RowAcc<Real>& lo,
                        const RowAcc<Real>& hi) {
  const Real* __restrict w0 = in.w0;
  const Real* __restrict w1 = in.w1;
  const Real* __restrict x0 = in.x0;
  const Real* __restrict x1 = in.x1;
  const Real* __restrict y0 = in.y0;
  const Real* __restrict y1 = in.y1;
  Real* __restrict lpw = lo.pw;
  Real* __restrict lqw = lo.qw;
  Real* __restrict lpx = lo.px;
  Real* __restrict lqx = lo.qx;
  Real* __restrict lpy = lo.py;
  Real* __restrict lqy = lo.qy;
  Real* __restrict hpw = hi.pw;
  Real* __restrict hqw = hi.qw;
  Real* __restrict hpx = hi.px;
  Real* __restrict hqx = hi.qx;
  Real* __restrict hpy = hi.py;
  Real* __restrict hqy = hi.qy;
  const Real ka = k.ka, kb = k.kb, sa = k.sa, sa3 = k.sa3, sb = k.sb, sb3 = k.sb3, b11 = k.b11, b12 = k.b12,
             b22 = k.b22, c11 = k.c11, c12 = k.c12, c22 = k.c22, h3x = k.h3x, h3y = k.h3y, sc = k.sc,
             e16 = k.e16, f16 = k.f16, e26 = k.e26, f26 = k.f26, h3c = k.h3c;
#pragma omp simd
  for (int i = 0; i < n; ++i) {
    const Real dwb = w0[i + 1] - w0[i], dwt = w1[i + 1] - w1[i], swb = w0[i] + w0[i + 1], swt = w1[i] + w1[i + 1];
    const Real dxb = x0[i + 1] - x0[i], dxt = x1[i + 1] - x1[i], sxb = x0[i] + x0[i + 1], sxt = x1[i] + x1[i + 1];
    const Real dyb = y0[i + 1] - y0[i], dyt = y1[i + 1] - y1[i], syb = y0[i] + y0[i + 1], syt = y1[i] + y1[i + 1];
    const Real c1w = dwb + dwt, c2w = swt - swb, c3w = dwt - dwb;
    const Real c0x = sxb + sxt, c1x = dxb + dxt, c2x = sxt - sxb, c3x = dxt - dxb;
    const Real c0y = syb + syt, c1y = dyb + dyt, c2y = syt - syb, c3y = dyt - dyb;
    // shear (MITC4)
    const Real gx0 = c1w * ka + c0x, gy0 = c2w * kb + c0y;
    const Real qx0 = sa * gx0 + sc * gy0, qy0 = sb * gy0 + sc * gx0;
    const Real qx1 = sa3 * (c3w * ka + c2x), qy1 = sb3 * (c3w * kb + c1y);
    // generalised forces (the coupling terms last: zero for an isotropic or axis-aligned material)
    const Real g1w = qx0 * ka, g2w = qy0 * kb, g3w = qx1 * ka + qy1 * kb;
    const Real g1x = b11 * c1x + b12 * c2y + e16 * c2x + f16 * c1y;
    const Real g2x = qx1 + c22 * c2x + c12 * c1y + e16 * c1x + f26 * c2y, g3x = h3x * c3x + h3c * c3y;
    const Real g1y = qy1 + c12 * c2x + c11 * c1y + f16 * c1x + e26 * c2y;
    const Real g2y = b12 * c1x + b22 * c2y + f26 * c2x + e26 * c1y, g3y = h3y * c3y + h3c * c3x;
    lpw[i] -= g2w;
    lqw[i] += g1w - g3w;
    lpx[i] += qx0 - g2x;
    lqx[i] += g1x - g3x;
    lpy[i] += qy0 - g2y;
    lqy[i] += g1y - g3y;
    if (AddTop) {
      hpw[i] += g2w;
      hqw[i] += g1w + g3w;
      hpx[i] += qx0 + g2x;
      hqx[i] += g1x + g3x;
      hpy[i] += qy0 + g2y;
      hqy[i] += g1y + g3y;
    } else {
      hpw[i] = g2w;
      hqw[i] = g1w + g3w;
      hpx[i] = qx0 + g2x;
      hqx[i] = g1x + g3x;
      hpy[i] = qy0 + g2y;
      hqy[i] = g1y + g3y;
    }
  }
}

// Nodal force of node i (0..nx) of a row from its edge accumulators (p[-1] = q[-1] = p[nx] = q[nx] = 0).
template <typename Real>
IMPACTSIM_INLINE Real node_force(const Real* p, const Real* q, int i) {
  return (p[i] + p[i - 1]) + (q[i - 1] - q[i]);
}

}  // namespace detail
}  // namespace impactsim
