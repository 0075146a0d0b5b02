// The MITC4 Mindlin-Reissner rectangle, written for a structured grid: one call processes one row of
// elements so the compiler vectorises across elements.
//
// Bilinear field per element: u = c0 + c1 xi + c2 eta + c3 xi eta, with a = hx/2, b = hy/2.
// Curvatures k = (bx,x, by,y, bx,y + by,x) are linear; the exact (2x2 Gauss) bending energy splits into the
// centre term (weight 4ab) and the xi- and eta-linear "hourglass" terms (weight 4ab/3).
// MITC4 shear: gamma_xz = (c1w/a + c0x) + eta (c3w/a + c2x) (tied at edge midpoints xi = 0, eta = +-1),
//              gamma_yz = (c2w/b + c0y) + xi  (c3w/b + c1y).
// Element nodal forces are dU/du; nodes 1..4 = (-,-), (+,-), (+,+), (-,+).
#pragma once

#include <cstdint>

#include "impactsim.h"

namespace impactsim {
namespace detail {

template <typename Real>
struct ElemConst {
  Real inv_a, inv_b, four_ab, four_ab_3, nu, half_1mnu, hg_x, hg_y;  // hg_*: hourglass bending factors / D
  ElemConst(double hx, double hy, double nu_) {
    const double a = hx / 2, b = hy / 2;
    inv_a = Real(1 / a);
    inv_b = Real(1 / b);
    four_ab = Real(4 * a * b);
    four_ab_3 = Real(4 * a * b / 3);
    nu = Real(nu_);
    half_1mnu = Real((1 - nu_) / 2);
    hg_x = Real(4 * a * b / 3 * ((1 - nu_) / 2 / (b * b) + 1 / (a * a)));
    hg_y = Real(4 * a * b / 3 * (1 / (b * b) + (1 - nu_) / 2 / (a * a)));
  }
};

// Row of n elements: node row 0 (p0*) and node row 1 (p1*), element i spans nodes i, i+1 of both rows.
// Writes element nodal forces e[12][n]: index field*4 + local node (field 0 w, 1 bx, 2 by).
constexpr int kChunk = 128;        // elements per chunk (compile-time stride of the element-force buffer)
constexpr int kStride = kChunk + 8;

template <typename Real, int Stride>
inline void row_forces(int n, const Real* __restrict w0, const Real* __restrict w1,
                       const Real* __restrict x0, const Real* __restrict x1, const Real* __restrict y0,
                       const Real* __restrict y1, const Real* __restrict d, const Real* __restrict s,
                       const ElemConst<Real>& k, Real* __restrict e) {
  Real* __restrict e0 = e;
  Real* __restrict e1 = e + Stride;
  Real* __restrict e2 = e + 2 * Stride;
  Real* __restrict e3 = e + 3 * Stride;
  Real* __restrict e4 = e + 4 * Stride;
  Real* __restrict e5 = e + 5 * Stride;
  Real* __restrict e6 = e + 6 * Stride;
  Real* __restrict e7 = e + 7 * Stride;
  Real* __restrict e8 = e + 8 * Stride;
  Real* __restrict e9 = e + 9 * Stride;
  Real* __restrict e10 = e + 10 * Stride;
  Real* __restrict e11 = e + 11 * Stride;
  const Real q = Real(0.25);
#pragma omp simd
  for (int i = 0; i < n; ++i) {
    // bilinear coefficients (times 4) of the three fields
    const Real wp = w0[i] + w1[i + 1], wq = w0[i + 1] + w1[i], wr = w1[i + 1] - w0[i], ws = w0[i + 1] - w1[i];
    const Real xp = x0[i] + x1[i + 1], xq = x0[i + 1] + x1[i], xr = x1[i + 1] - x0[i], xs = x0[i + 1] - x1[i];
    const Real yp = y0[i] + y1[i + 1], yq = y0[i + 1] + y1[i], yr = y1[i + 1] - y0[i], ys = y0[i + 1] - y1[i];
    const Real c1w = q * (wr + ws), c2w = q * (wr - ws), c3w = q * (wp - wq);
    const Real c0x = q * (xp + xq), c1x = q * (xr + xs), c2x = q * (xr - xs), c3x = q * (xp - xq);
    const Real c0y = q * (yp + yq), c1y = q * (yr + ys), c2y = q * (yr - ys), c3y = q * (yp - yq);
    const Real D = d[i], S = s[i];
    // bending, centre
    const Real k1 = c1x * k.inv_a, k2 = c2y * k.inv_b, k3 = c2x * k.inv_b + c1y * k.inv_a;
    const Real DA = D * k.four_ab;
    const Real m1 = DA * (k1 + k.nu * k2), m2 = DA * (k.nu * k1 + k2), m3 = DA * k.half_1mnu * k3;
    // shear (MITC4)
    const Real SA = S * k.four_ab, SA3 = S * k.four_ab_3;
    const Real qx0 = SA * (c1w * k.inv_a + c0x), qx1 = SA3 * (c3w * k.inv_a + c2x);
    const Real qy0 = SA * (c2w * k.inv_b + c0y), qy1 = SA3 * (c3w * k.inv_b + c1y);
    // dU/dc per field
    const Real g1w = qx0 * k.inv_a, g2w = qy0 * k.inv_b, g3w = qx1 * k.inv_a + qy1 * k.inv_b;
    const Real g0x = qx0, g1x = m1 * k.inv_a, g2x = m3 * k.inv_b + qx1, g3x = D * k.hg_x * c3x;
    const Real g0y = qy0, g1y = m3 * k.inv_a + qy1, g2y = m2 * k.inv_b, g3y = D * k.hg_y * c3y;
    // back to nodes: f_n = (g0 + xi_n g1 + eta_n g2 + xi_n eta_n g3) / 4
    e0[i] = q * (-g1w - g2w + g3w);
    e1[i] = q * (g1w - g2w - g3w);
    e2[i] = q * (g1w + g2w + g3w);
    e3[i] = q * (-g1w + g2w - g3w);
    e4[i] = q * (g0x - g1x - g2x + g3x);
    e5[i] = q * (g0x + g1x - g2x - g3x);
    e6[i] = q * (g0x + g1x + g2x + g3x);
    e7[i] = q * (g0x - g1x + g2x - g3x);
    e8[i] = q * (g0y - g1y - g2y + g3y);
    e9[i] = q * (g0y + g1y - g2y - g3y);
    e10[i] = q * (g0y + g1y + g2y + g3y);
    e11[i] = q * (g0y - g1y + g2y - g3y);
  }
}

// Adds the forces of n elements of a row into node rows f0 (bottom) and f1 (top): element i's local nodes
// 1, 4 (n1, n4) go to node i and 2, 3 (n2, n3) to node i + 1
// (1 = (i, bottom), 2 = (i+1, bottom), 3 = (i+1, top), 4 = (i, top)).
template <typename Real>
inline void scatter_nodes(int n, const Real* __restrict n1, const Real* __restrict n2, const Real* __restrict n3,
                          const Real* __restrict n4, Real* __restrict f0, Real* __restrict f1) {
  f0[0] += n1[0];
  f1[0] += n4[0];
#pragma omp simd
  for (int i = 1; i < n; ++i) {
    f0[i] += n1[i] + n2[i - 1];
    f1[i] += n4[i] + n3[i - 1];
  }
  f0[n] += n2[n - 1];
  f1[n] += n3[n - 1];
}

// A whole row: en[0..3][n] (stride n) are the forces at local nodes 1..4.
template <typename Real>
inline void row_scatter(int n, const Real* __restrict e, Real* __restrict f0, Real* __restrict f1) {
  scatter_nodes(n, e, e + n, e + 2 * n, e + 3 * n, f0, f1);
}

// Chunk version: elements c0..c0+n-1 of a row (forces in e with compile-time stride) into node rows f0, f1
// (pointing at node c0).
template <typename Real, int Stride>
inline void chunk_scatter(int n, const Real* __restrict e, Real* __restrict f0, Real* __restrict f1) {
  scatter_nodes(n, e, e + Stride, e + 2 * Stride, e + 3 * Stride, f0, f1);
}

// Element forces of element row (rows o0 / o1 of the node arrays) added into node-row force buffers.
template <typename Real>
inline void element_row(int nx, const Real* w0, const Real* w1, const Real* x0, const Real* x1, const Real* y0,
                        const Real* y1, const Real* d, const Real* s, const ElemConst<Real>& k, Real* e,
                        Real* const flo[3], Real* const fhi[3]) {
  for (int c0 = 0; c0 < nx; c0 += kChunk) {
    const int n = nx - c0 < kChunk ? nx - c0 : kChunk;
    row_forces<Real, kStride>(n, w0 + c0, w1 + c0, x0 + c0, x1 + c0, y0 + c0, y1 + c0, d + c0, s + c0, k, e);
    for (int fld = 0; fld < 3; ++fld)
      chunk_scatter<Real, kStride>(n, e + 4 * fld * kStride, flo[fld] + c0, fhi[fld] + c0);
  }
}

}  // namespace detail
}  // namespace impactsim
