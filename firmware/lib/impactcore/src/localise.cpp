// Physics localiser: time-difference-of-arrival least squares, robust and bounded to the plate.
#include <math.h>

#include "impactcore.h"

namespace impactcore {
namespace {

// Solves the 3x3 system a x = b by Gaussian elimination with partial pivoting. False if singular.
bool solve3(float a[3][3], float b[3], float x[3]) {
  for (int col = 0; col < 3; ++col) {
    int piv = col;
    for (int r = col + 1; r < 3; ++r) {
      if (fabsf(a[r][col]) > fabsf(a[piv][col])) piv = r;
    }
    if (fabsf(a[piv][col]) < 1e-12f) return false;
    if (piv != col) {
      for (int k = 0; k < 3; ++k) {
        const float t = a[col][k];
        a[col][k] = a[piv][k];
        a[piv][k] = t;
      }
      const float t = b[col];
      b[col] = b[piv];
      b[piv] = t;
    }
    for (int r = col + 1; r < 3; ++r) {
      const float f = a[r][col] / a[col][col];
      for (int k = col; k < 3; ++k) a[r][k] -= f * a[col][k];
      b[r] -= f * b[col];
    }
  }
  for (int r = 2; r >= 0; --r) {
    float s = b[r];
    for (int k = r + 1; k < 3; ++k) s -= a[r][k] * x[k];
    x[r] = s / a[r][r];
  }
  return true;
}

float clampf(float v, float lo, float hi) { return v < lo ? lo : (v > hi ? hi : v); }

struct Problem {
  const float* toa;
  const float* sx;
  const float* sy;
  int idx[kChannels];
  int m;
  float v;
  float huber;
  float lx, ly;
};

// Huber cost of (x, y) with t0 at its weighted optimum; also returns that t0.
float huber_cost(const Problem& p, float x, float y, float* t0_out) {
  float r[kChannels];
  float t0 = 0.0f;
  for (int k = 0; k < p.m; ++k) {
    const int i = p.idx[k];
    r[k] = p.toa[i] - hypotf(x - p.sx[i], y - p.sy[i]) / p.v;
    t0 += r[k];
  }
  t0 /= static_cast<float>(p.m);
  // Two reweighting passes for t0 (the median-like centre under Huber weights).
  for (int pass = 0; pass < 2; ++pass) {
    float sw = 0.0f, swr = 0.0f;
    for (int k = 0; k < p.m; ++k) {
      const float e = fabsf(r[k] - t0);
      const float w = e <= p.huber ? 1.0f : p.huber / e;
      sw += w;
      swr += w * r[k];
    }
    t0 = swr / sw;
  }
  float cost = 0.0f;
  for (int k = 0; k < p.m; ++k) {
    const float e = fabsf(r[k] - t0);
    cost += e <= p.huber ? 0.5f * e * e : p.huber * (e - 0.5f * p.huber);
  }
  *t0_out = t0;
  return cost;
}

// IRLS Gauss-Newton from (x, y); returns the Huber cost at the end and the normal matrix there.
float refine(const Problem& p, float* x_io, float* y_io, float* t0_io, int* iters, float jtj[3][3]) {
  float x = *x_io, y = *y_io, t0 = 0.0f;
  huber_cost(p, x, y, &t0);
  int it = 0;
  for (it = 0; it < 25; ++it) {
    float a[3][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
    float g[3] = {0, 0, 0};
    for (int k = 0; k < p.m; ++k) {
      const int i = p.idx[k];
      const float dx = x - p.sx[i];
      const float dy = y - p.sy[i];
      float d = hypotf(dx, dy);
      if (d < 1e-3f) d = 1e-3f;
      const float e = p.toa[i] - (t0 + d / p.v);
      const float ae = fabsf(e);
      const float w = ae <= p.huber ? 1.0f : p.huber / ae;
      const float j[3] = {dx / (d * p.v), dy / (d * p.v), 1.0f};  // d(model)/d(x, y, t0)
      for (int q = 0; q < 3; ++q) {
        g[q] += w * j[q] * e;
        for (int c = 0; c < 3; ++c) a[q][c] += w * j[q] * j[c];
      }
    }
    for (int q = 0; q < 3; ++q) {
      for (int c = 0; c < 3; ++c) jtj[q][c] = a[q][c];
      a[q][q] *= 1.0f + 1e-4f;
      a[q][q] += 1e-9f;
    }
    float step[3];
    if (!solve3(a, g, step)) break;
    const float nx = clampf(x + step[0], 0.0f, p.lx);
    const float ny = clampf(y + step[1], 0.0f, p.ly);
    const float moved = fabsf(nx - x) + fabsf(ny - y);
    x = nx;
    y = ny;
    t0 += step[2];
    if (moved < 1e-3f) {
      ++it;
      break;
    }
  }
  const float cost = huber_cost(p, x, y, &t0);
  *x_io = x;
  *y_io = y;
  *t0_io = t0;
  *iters = it;
  return cost;
}

// Closed-form start: with the earliest sensor r as reference, range differences d_i = v (t_i - t_r)
// give linear equations in (x, y, R_r): 2 (s_r - s_i).p - 2 d_i R_r = d_i^2 - |s_i|^2 + |s_r|^2.
bool closed_form(const Problem& p, float* x, float* y) {
  if (p.m != 4) return false;
  int r = p.idx[0];
  for (int k = 1; k < p.m; ++k) {
    if (p.toa[p.idx[k]] < p.toa[r]) r = p.idx[k];
  }
  float a[3][3];
  float b[3];
  int row = 0;
  const float sr2 = p.sx[r] * p.sx[r] + p.sy[r] * p.sy[r];
  for (int k = 0; k < p.m; ++k) {
    const int i = p.idx[k];
    if (i == r) continue;
    const float d = p.v * (p.toa[i] - p.toa[r]);
    const float si2 = p.sx[i] * p.sx[i] + p.sy[i] * p.sy[i];
    a[row][0] = 2.0f * (p.sx[r] - p.sx[i]);
    a[row][1] = 2.0f * (p.sy[r] - p.sy[i]);
    a[row][2] = -2.0f * d;
    b[row] = d * d - si2 + sr2;
    ++row;
  }
  float sol[3];
  if (!solve3(a, b, sol) || !(sol[0] == sol[0]) || !(sol[1] == sol[1])) return false;
  *x = clampf(sol[0], 0.0f, p.lx);
  *y = clampf(sol[1], 0.0f, p.ly);
  return true;
}

}  // namespace

LocaliserResult localise_tdoa(const float toa_us[kChannels], const uint8_t use[kChannels],
                              const float sensor_x_mm[kChannels], const float sensor_y_mm[kChannels],
                              float velocity_mm_per_us, float sigma_us, float plate_x_mm,
                              float plate_y_mm, float huber_us) {
  LocaliserResult res = {};
  res.status = kOk;
  Problem p;
  p.toa = toa_us;
  p.sx = sensor_x_mm;
  p.sy = sensor_y_mm;
  p.m = 0;
  p.v = velocity_mm_per_us;
  p.huber = huber_us > 0.0f ? huber_us : 1e-3f;
  p.lx = plate_x_mm;
  p.ly = plate_y_mm;
  for (int c = 0; c < kChannels; ++c) {
    if (use[c] && toa_us[c] == toa_us[c]) p.idx[p.m++] = c;
  }
  if (p.m < 3 || !(velocity_mm_per_us > 0.0f) || !(plate_x_mm > 0.0f) || !(plate_y_mm > 0.0f)) {
    res.status = p.m < 3 ? kErrTooFewSamples : kErrBadConfig;
    res.x_mm = res.y_mm = res.t0_us = NAN;
    res.cov_xx = res.cov_xy = res.cov_yy = NAN;
    res.rms_residual_us = NAN;
    return res;
  }
  // Starts: closed form, centre, four quadrant centres.
  float starts[6][2];
  int n_starts = 0;
  float cx, cy;
  if (closed_form(p, &cx, &cy)) {
    starts[n_starts][0] = cx;
    starts[n_starts][1] = cy;
    ++n_starts;
  }
  const float fx[5] = {0.5f, 0.25f, 0.75f, 0.75f, 0.25f};
  const float fy[5] = {0.5f, 0.25f, 0.25f, 0.75f, 0.75f};
  for (int k = 0; k < 5; ++k) {
    starts[n_starts][0] = fx[k] * plate_x_mm;
    starts[n_starts][1] = fy[k] * plate_y_mm;
    ++n_starts;
  }
  float best_cost = 0.0f;
  float best_x = 0.0f, best_y = 0.0f, best_t0 = 0.0f;
  float best_jtj[3][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
  int best_it = 0;
  for (int k = 0; k < n_starts; ++k) {
    float x = starts[k][0], y = starts[k][1], t0 = 0.0f;
    float jtj[3][3];
    int it = 0;
    const float cost = refine(p, &x, &y, &t0, &it, jtj);
    if (k == 0 || cost < best_cost) {
      best_cost = cost;
      best_x = x;
      best_y = y;
      best_t0 = t0;
      best_it = it;
      for (int q = 0; q < 3; ++q)
        for (int c = 0; c < 3; ++c) best_jtj[q][c] = jtj[q][c];
    }
  }
  float ss = 0.0f;
  for (int k = 0; k < p.m; ++k) {
    const int i = p.idx[k];
    const float e = toa_us[i] - (best_t0 + hypotf(best_x - sensor_x_mm[i], best_y - sensor_y_mm[i]) / p.v);
    ss += e * e;
  }
  res.x_mm = best_x;
  res.y_mm = best_y;
  res.t0_us = best_t0;
  res.rms_residual_us = sqrtf(ss / static_cast<float>(p.m));
  res.iterations = best_it;
  // Covariance of (x, y): sigma^2 times the (x, y) block of (J^T W J)^-1.
  float cov[2][2] = {{NAN, NAN}, {NAN, NAN}};
  for (int col = 0; col < 2; ++col) {
    float tmp[3][3];
    for (int q = 0; q < 3; ++q)
      for (int c = 0; c < 3; ++c) tmp[q][c] = best_jtj[q][c];
    float e[3] = {0.0f, 0.0f, 0.0f};
    e[col] = 1.0f;
    float inv_col[3];
    if (solve3(tmp, e, inv_col)) {
      cov[0][col] = inv_col[0];
      cov[1][col] = inv_col[1];
    }
  }
  const float s2 = sigma_us * sigma_us;
  res.cov_xx = s2 * cov[0][0];
  res.cov_xy = s2 * 0.5f * (cov[0][1] + cov[1][0]);
  res.cov_yy = s2 * cov[1][1];
  return res;
}

}  // namespace impactcore
