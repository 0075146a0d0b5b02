// Physics localiser: time-difference-of-arrival least squares with a closed-form start.
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

}  // namespace

LocaliserResult localise_tdoa(const float toa_us[kChannels], const uint8_t use[kChannels],
                              const float sensor_x_mm[kChannels], const float sensor_y_mm[kChannels],
                              float velocity_mm_per_us, float sigma_us, float plate_x_mm,
                              float plate_y_mm) {
  LocaliserResult res = {};
  res.status = kOk;
  int idx[kChannels];
  int m = 0;
  for (int c = 0; c < kChannels; ++c) {
    if (use[c] && toa_us[c] == toa_us[c]) idx[m++] = c;
  }
  if (m < 3 || !(velocity_mm_per_us > 0.0f)) {
    res.status = m < 3 ? kErrTooFewSamples : kErrBadConfig;
    res.x_mm = res.y_mm = res.t0_us = NAN;
    return res;
  }
  const float v = velocity_mm_per_us;
  // Closed-form start: with the earliest sensor r as reference, range differences d_i = v (t_i - t_r)
  // give linear equations in (x, y, R_r): 2 (s_r - s_i).p - 2 d_i R_r = d_i^2 - |s_i|^2 + |s_r|^2.
  int r = idx[0];
  for (int k = 1; k < m; ++k) {
    if (toa_us[idx[k]] < toa_us[r]) r = idx[k];
  }
  float x = 0.5f * plate_x_mm;
  float y = 0.5f * plate_y_mm;
  if (m == 4) {
    float a[3][3];
    float b[3];
    int row = 0;
    const float sr2 = sensor_x_mm[r] * sensor_x_mm[r] + sensor_y_mm[r] * sensor_y_mm[r];
    for (int k = 0; k < m; ++k) {
      const int i = idx[k];
      if (i == r) continue;
      const float d = v * (toa_us[i] - toa_us[r]);
      const float si2 = sensor_x_mm[i] * sensor_x_mm[i] + sensor_y_mm[i] * sensor_y_mm[i];
      a[row][0] = 2.0f * (sensor_x_mm[r] - sensor_x_mm[i]);
      a[row][1] = 2.0f * (sensor_y_mm[r] - sensor_y_mm[i]);
      a[row][2] = -2.0f * d;
      b[row] = d * d - si2 + sr2;
      ++row;
    }
    float sol[3];
    if (solve3(a, b, sol) && sol[0] == sol[0] && sol[1] == sol[1]) {
      x = fminf(fmaxf(sol[0], 0.0f), plate_x_mm);
      y = fminf(fmaxf(sol[1], 0.0f), plate_y_mm);
    }
  }
  // t0 start: mean of t_i - dist_i / v.
  float t0 = 0.0f;
  for (int k = 0; k < m; ++k) {
    const int i = idx[k];
    t0 += toa_us[i] - hypotf(x - sensor_x_mm[i], y - sensor_y_mm[i]) / v;
  }
  t0 /= static_cast<float>(m);

  // Gauss-Newton on (x, y, t0) with a small Levenberg term for robustness.
  float jtj[3][3];
  int it = 0;
  for (it = 0; it < 30; ++it) {
    float a[3][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
    float g[3] = {0, 0, 0};
    for (int k = 0; k < m; ++k) {
      const int i = idx[k];
      const float dx = x - sensor_x_mm[i];
      const float dy = y - sensor_y_mm[i];
      float d = hypotf(dx, dy);
      if (d < 1e-3f) d = 1e-3f;
      const float res_i = toa_us[i] - (t0 + d / v);
      const float j[3] = {dx / (d * v), dy / (d * v), 1.0f};  // d(model)/d(x, y, t0)
      for (int p = 0; p < 3; ++p) {
        g[p] += j[p] * res_i;
        for (int q = 0; q < 3; ++q) a[p][q] += j[p] * j[q];
      }
    }
    for (int p = 0; p < 3; ++p) {
      for (int q = 0; q < 3; ++q) jtj[p][q] = a[p][q];
      a[p][p] *= 1.0f + 1e-6f;
    }
    float step[3];
    if (!solve3(a, g, step)) {
      res.status = kErrSingular;
      break;
    }
    x += step[0];
    y += step[1];
    t0 += step[2];
    if (fabsf(step[0]) + fabsf(step[1]) < 1e-4f) {
      ++it;
      break;
    }
  }
  float ss = 0.0f;
  for (int k = 0; k < m; ++k) {
    const int i = idx[k];
    const float e = toa_us[i] - (t0 + hypotf(x - sensor_x_mm[i], y - sensor_y_mm[i]) / v);
    ss += e * e;
  }
  res.x_mm = x;
  res.y_mm = y;
  res.t0_us = t0;
  res.rms_residual_us = sqrtf(ss / static_cast<float>(m));
  res.iterations = it;
  // Covariance of (x, y): sigma^2 times the (x, y) block of (J^T J)^-1.
  float inv_col[3];
  float e0[3] = {1, 0, 0};
  float e1[3] = {0, 1, 0};
  float tmp[3][3];
  float cov[2][2] = {{NAN, NAN}, {NAN, NAN}};
  for (int p = 0; p < 3; ++p)
    for (int q = 0; q < 3; ++q) tmp[p][q] = jtj[p][q];
  if (solve3(tmp, e0, inv_col)) {
    cov[0][0] = inv_col[0];
    cov[1][0] = inv_col[1];
  }
  for (int p = 0; p < 3; ++p)
    for (int q = 0; q < 3; ++q) tmp[p][q] = jtj[p][q];
  if (solve3(tmp, e1, inv_col)) {
    cov[0][1] = inv_col[0];
    cov[1][1] = inv_col[1];
  }
  const float s2 = sigma_us * sigma_us;
  res.cov_xx = s2 * cov[0][0];
  res.cov_xy = s2 * 0.5f * (cov[0][1] + cov[1][0]);
  res.cov_yy = s2 * cov[1][1];
  return res;
}

}  // namespace impactcore
