// Plate: mesh, material, element operators (forces, strain energy, largest eigenvalue), sub-cycling patches
// and node springs. The explicit run is in run.cpp.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <stdexcept>

#include "element.h"
#include "impactsim.h"
#include "sweep.h"

namespace impactsim {

int version() { return 1; }

using detail::Accumulators;
using detail::DenormalGuard;
using detail::need;
using detail::sweep;

namespace {
// The spec's material (isotropic from nu when none is given), checked: bending and shear matrices positive
// definite (else the explicit step has no stability limit).
Material material_of(const PlateSpec& s) {
  if (s.material.empty()) return Material::isotropic(s.nu);
  need(s.material.size() == 9, "material needs 9 ratios (d11, d12, d22, d66, d16, d26, sxx, syy, sxy)");
  Material m;
  const std::vector<double>& r = s.material;
  m.d11 = r[0], m.d12 = r[1], m.d22 = r[2], m.d66 = r[3], m.d16 = r[4], m.d26 = r[5];
  m.sxx = r[6], m.syy = r[7], m.sxy = r[8];
  for (double v : r) need(std::isfinite(v), "material ratios must be finite");
  const double det2 = m.d11 * m.d22 - m.d12 * m.d12;
  const double det3 = m.d11 * (m.d22 * m.d66 - m.d26 * m.d26) - m.d12 * (m.d12 * m.d66 - m.d26 * m.d16) +
                      m.d16 * (m.d12 * m.d26 - m.d22 * m.d16);
  need(m.d11 > 0 && det2 > 0 && det3 > 0, "material bending matrix must be positive definite");
  need(m.sxx > 0 && m.sxx * m.syy - m.sxy * m.sxy > 0, "material shear matrix must be positive definite");
  return m;
}
}  // namespace

detail::Coef<Real> Plate::coef_f(double d, double s) const {
  return detail::Coef<Real>(s_.hx_m, s_.hy_m, material_, d, s);
}
detail::Coef<double> Plate::coef_d(double d, double s) const {
  return detail::Coef<double>(s_.hx_m, s_.hy_m, material_, d, s);
}

Plate::Plate(PlateSpec spec) : s_(std::move(spec)) {
  need(s_.nx >= 1 && s_.ny >= 1, "mesh needs at least one element per direction");
  need(s_.hx_m > 0 && s_.hy_m > 0, "element size must be positive");
  need(s_.nu > -1 && s_.nu < 0.5, "Poisson ratio must be in (-1, 0.5)");
  const size_t ne = static_cast<size_t>(elements()), nn = static_cast<size_t>(nodes());
  need(s_.d_elem.size() == ne && s_.s_elem.size() == ne, "d_elem/s_elem need one value per element");
  need(s_.mass_w.size() == nn && s_.mass_r.size() == nn, "mass_w/mass_r need one value per node");
  need(s_.fix_w.size() == nn && s_.fix_bx.size() == nn && s_.fix_by.size() == nn,
       "fix_w/fix_bx/fix_by need one value per node");
  need(s_.damping_per_s >= 0, "damping must be >= 0");
  material_ = material_of(s_);
  // base element: the most common (D, S); the others become corrections K(D - D0, S - S0)
  std::map<std::pair<double, double>, int64_t> count;
  for (size_t e = 0; e < ne; ++e) {
    need(s_.d_elem[e] > 0 && s_.s_elem[e] > 0, "element stiffness must be positive");
    ++count[{s_.d_elem[e], s_.s_elem[e]}];
  }
  auto most = std::max_element(count.begin(), count.end(),
                               [](const auto& x, const auto& y) { return x.second < y.second; });
  d0_ = most->first.first;
  s0_ = most->first.second;
  base_f_ = coef_f(d0_, s0_);
  base_d_ = coef_d(d0_, s0_);
  row_start_.assign(static_cast<size_t>(s_.ny) + 1, 0);
  for (int j = 0; j < s_.ny; ++j) {
    row_start_[j] = static_cast<int64_t>(special_.size());
    for (int i = 0; i < s_.nx; ++i) {
      const size_t e = static_cast<size_t>(j) * s_.nx + i;
      if (s_.d_elem[e] == d0_ && s_.s_elem[e] == s0_) continue;
      const double dd = s_.d_elem[e] - d0_, ds = s_.s_elem[e] - s0_;
      special_.push_back({i, coef_f(dd, ds), coef_d(dd, ds)});
    }
  }
  row_start_[s_.ny] = static_cast<int64_t>(special_.size());
  inv_mw_.resize(nn);
  inv_mr_.resize(2 * nn);
  for (size_t k = 0; k < nn; ++k) {
    need(s_.mass_w[k] > 0 && s_.mass_r[k] > 0, "nodal masses must be positive");
    inv_mw_[k] = s_.fix_w[k] ? Real(0) : Real(1 / s_.mass_w[k]);
    inv_mr_[k] = s_.fix_bx[k] ? Real(0) : Real(1 / s_.mass_r[k]);
    inv_mr_[nn + k] = s_.fix_by[k] ? Real(0) : Real(1 / s_.mass_r[k]);
  }
}

namespace {

template <typename T>
void forces(const Plate& p, const detail::Coef<T>& base, const T* w, const T* bx, const T* by, T* fw, T* fbx,
            T* fby) {
  const PlateSpec& s = p.spec();
  const int nx = s.nx, rl = nx + 1;
  Accumulators<T> acc(nx);
  sweep<T>(nx, s.ny, rl, base, p.special().data(), p.row_start().data(), w, bx, by, acc,
           [&](int j, const detail::RowAcc<T>& a) {
             const size_t o = static_cast<size_t>(j) * rl;
             for (int i = 0; i < rl; ++i) {
               fw[o + i] = detail::node_force(a.pw, a.qw, i);
               fbx[o + i] = detail::node_force(a.px, a.qx, i);
               fby[o + i] = detail::node_force(a.py, a.qy, i);
             }
           });
  const std::vector<int64_t>& sn = p.spring_nodes();
  for (size_t r = 0; r < sn.size(); ++r) fw[sn[r]] += T(p.spring_k(r)) * w[sn[r]];
}
}  // namespace

void Plate::internal_force(const Real* w, const Real* bx, const Real* by, Real* fw, Real* fbx,
                           Real* fby) const {
  forces<Real>(*this, base_f_, w, bx, by, fw, fbx, fby);
}

void Plate::internal_force_double(const double* w, const double* bx, const double* by, double* fw, double* fbx,
                                  double* fby) const {
  forces<double>(*this, base_d_, w, bx, by, fw, fbx, fby);
}

double Plate::strain_energy(const Real* w, const Real* bx, const Real* by) const {
  const size_t nn = static_cast<size_t>(nodes());
  std::vector<Real> f(3 * nn);
  internal_force(w, bx, by, f.data(), f.data() + nn, f.data() + 2 * nn);
  double u = 0;
  for (size_t k = 0; k < nn; ++k) u += double(w[k]) * f[k] + double(bx[k]) * f[nn + k] + double(by[k]) * f[2 * nn + k];
  return 0.5 * u;
}

namespace {
// Largest eigenvalue of the symmetric tridiagonal matrix (diagonal a[0..k), off-diagonal b[0..k-1)) by
// bisection on the Sturm sequence count.
double tridiagonal_max_eigenvalue(const std::vector<double>& a, const std::vector<double>& b) {
  const size_t k = a.size();
  double lo = 1e300, hi = -1e300;
  for (size_t i = 0; i < k; ++i) {  // Gershgorin
    const double r = (i > 0 ? std::fabs(b[i - 1]) : 0.0) + (i + 1 < k ? std::fabs(b[i]) : 0.0);
    lo = std::min(lo, a[i] - r);
    hi = std::max(hi, a[i] + r);
  }
  auto count_below = [&](double x) {  // eigenvalues < x
    int n = 0;
    double d = 1;
    for (size_t i = 0; i < k; ++i) {
      d = a[i] - x - (i > 0 ? b[i - 1] * b[i - 1] / d : 0.0);
      if (d == 0) d = -1e-300;
      if (d < 0) ++n;
    }
    return n;
  };
  for (int it = 0; it < 200 && hi - lo > 1e-15 * std::max(std::fabs(hi), std::fabs(lo)); ++it) {
    const double mid = 0.5 * (lo + hi);
    if (count_below(mid) == static_cast<int>(k)) hi = mid; else lo = mid;
  }
  return hi;
}
}  // namespace

void Plate::set_subcycling(double fine_dt_s, int layer) {
  need(layer >= 0, "subcycling layer must be >= 0");
  patches_.clear();
  sub_.assign(static_cast<size_t>(nodes()), 0);
  fine_dt_ = 0;
  if (!(fine_dt_s > 0) || special_.empty()) return;
  fine_dt_ = fine_dt_s;
  const int nx = s_.nx, ny = s_.ny;
  // clusters of special elements (8-connected) -> node boxes dilated by layer, merged while a box's ring
  // touches another box (ring nodes must be large-step nodes)
  std::vector<uint8_t> mark(static_cast<size_t>(elements()), 0);
  for (int j = 0; j < ny; ++j)
    for (int64_t k = row_start_[j]; k < row_start_[j + 1]; ++k) mark[static_cast<size_t>(j) * nx + special_[k].i] = 1;
  struct Box { int i0, i1, j0, j1; };
  std::vector<Box> boxes;
  std::vector<int64_t> stack;
  for (size_t e0 = 0; e0 < mark.size(); ++e0) {
    if (mark[e0] != 1) continue;
    Box b{nx, -1, ny, -1};
    stack.assign(1, static_cast<int64_t>(e0));
    mark[e0] = 2;
    while (!stack.empty()) {
      const int64_t e = stack.back();
      stack.pop_back();
      const int i = static_cast<int>(e % nx), j = static_cast<int>(e / nx);
      b = {std::min(b.i0, i), std::max(b.i1, i + 1), std::min(b.j0, j), std::max(b.j1, j + 1)};
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const int a = i + di, c = j + dj;
          if (a < 0 || a >= nx || c < 0 || c >= ny) continue;
          const size_t f = static_cast<size_t>(c) * nx + a;
          if (mark[f] == 1) {
            mark[f] = 2;
            stack.push_back(static_cast<int64_t>(f));
          }
        }
    }
    boxes.push_back({std::max(b.i0 - layer, 0), std::min(b.i1 + layer, nx), std::max(b.j0 - layer, 0),
                     std::min(b.j1 + layer, ny)});
  }
  for (bool merged = true; merged;) {
    merged = false;
    for (size_t a = 0; a < boxes.size() && !merged; ++a)
      for (size_t b = a + 1; b < boxes.size() && !merged; ++b) {
        const Box &p = boxes[a], &q = boxes[b];
        if (p.i0 - 1 <= q.i1 && q.i0 - 1 <= p.i1 && p.j0 - 1 <= q.j1 && q.j0 - 1 <= p.j1) {
          boxes[a] = {std::min(p.i0, q.i0), std::max(p.i1, q.i1), std::min(p.j0, q.j0), std::max(p.j1, q.j1)};
          boxes.erase(boxes.begin() + static_cast<std::ptrdiff_t>(b));
          merged = true;
        }
      }
  }
  const int64_t rl = nx + 1;
  for (const Box& b : boxes) {
    const Patch pt{b.i0, b.i1, b.j0, b.j1, std::max(b.i0 - 1, 0), std::min(b.i1 + 1, nx), std::max(b.j0 - 1, 0),
                   std::min(b.j1 + 1, ny)};
    for (int j = pt.j0; j <= pt.j1; ++j)
      for (int i = pt.i0; i <= pt.i1; ++i) sub_[static_cast<size_t>(j * rl + i)] = 1;
    patches_.push_back(pt);
  }
  for (int64_t k : spring_node_) need(!sub_[static_cast<size_t>(k)], "a node spring on a sub-cycled node");
}

void Plate::set_node_springs(std::vector<double> k_w, std::vector<double> c_w) {
  const size_t nn = static_cast<size_t>(nodes());
  need((k_w.empty() || k_w.size() == nn) && (c_w.empty() || c_w.size() == nn),
       "node springs need one stiffness and one damping value per node (or none)");
  spring_node_.clear();
  spring_k_.clear();
  spring_c_.clear();
  for (size_t k = 0; k < nn; ++k) {
    const double kk = k_w.empty() ? 0.0 : k_w[k], cc = c_w.empty() ? 0.0 : c_w[k];
    need(std::isfinite(kk) && kk >= 0 && std::isfinite(cc) && cc >= 0, "node springs must be finite and >= 0");
    if (kk == 0 && cc == 0) continue;
    need(!s_.fix_w[k], "a node spring on a held w dof");
    need(sub_.empty() || !sub_[k], "a node spring on a sub-cycled node");
    spring_node_.push_back(static_cast<int64_t>(k));
    spring_k_.push_back(kk);
    spring_c_.push_back(cc);
  }
}

int64_t Plate::subcycled_nodes() const {
  int64_t n = 0;
  for (uint8_t f : sub_) n += f;
  return n;
}

double Plate::max_eigenvalue(int max_iter, double rtol, bool coarse) const {
  need(max_iter >= 2, "max_iter must be >= 2");
  const size_t nn = static_cast<size_t>(nodes()), n = 3 * nn;
  std::vector<double> s(n);  // M^-1/2 on free dofs, 0 on fixed ones
  for (size_t k = 0; k < nn; ++k) {
    const bool held = coarse && !sub_.empty() && sub_[k];
    s[k] = held ? 0.0 : std::sqrt(double(inv_mw_[k]));
    s[nn + k] = held ? 0.0 : std::sqrt(double(inv_mr_[k]));
    s[2 * nn + k] = held ? 0.0 : std::sqrt(double(inv_mr_[nn + k]));
  }
  std::vector<double> q(n), qp(n, 0.0), z(n);
  std::vector<Real> u(n), f(n);
  uint64_t state = 0x9E3779B97F4A7C15ull;  // deterministic start vector
  double norm = 0;
  for (size_t k = 0; k < n; ++k) {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    q[k] = s[k] > 0 ? double(state >> 11) * 0x1.0p-53 - 0.5 : 0.0;
    norm += q[k] * q[k];
  }
  need(norm > 0, "no free degree of freedom");
  for (auto& x : q) x /= std::sqrt(norm);
  std::vector<double> alpha, beta;
  double theta = 0, beta_prev = 0;
  DenormalGuard ftz;
  for (int it = 0; it < max_iter; ++it) {
    for (size_t k = 0; k < n; ++k) u[k] = Real(s[k] * q[k]);
    internal_force(u.data(), u.data() + nn, u.data() + 2 * nn, f.data(), f.data() + nn, f.data() + 2 * nn);
    double a = 0;
    for (size_t k = 0; k < n; ++k) {
      z[k] = s[k] * double(f[k]);
      a += q[k] * z[k];
    }
    double b = 0;
    for (size_t k = 0; k < n; ++k) {
      z[k] -= a * q[k] + beta_prev * qp[k];
      b += z[k] * z[k];
    }
    b = std::sqrt(b);
    alpha.push_back(a);
    if ((it + 1) % 5 == 0 || b == 0 || it + 1 == max_iter) {
      const double th = tridiagonal_max_eigenvalue(alpha, beta);
      const bool done = it >= 9 && std::fabs(th - theta) <= rtol * th;
      theta = th;
      if (done || b == 0) break;
    }
    beta.push_back(b);
    beta_prev = b;
    for (size_t k = 0; k < n; ++k) {
      qp[k] = q[k];
      q[k] = z[k] / b;
    }
  }
  return theta;
}

std::vector<double> element_stiffness(double hx_m, double hy_m, double d, double nu, double s,
                                      const std::vector<double>& material) {
  PlateSpec sp;
  sp.nx = sp.ny = 1;
  sp.hx_m = hx_m;
  sp.hy_m = hy_m;
  sp.nu = nu;
  sp.material = material;
  sp.d_elem = {d};
  sp.s_elem = {s};
  sp.mass_w.assign(4, 1.0);
  sp.mass_r.assign(4, 1.0);
  sp.fix_w.assign(4, 0);
  sp.fix_bx.assign(4, 0);
  sp.fix_by.assign(4, 0);
  Plate p(sp);
  // mesh node order (0,0),(1,0),(0,1),(1,1) -> local 1,2,4,3
  const int local_to_mesh[4] = {0, 1, 3, 2};
  std::vector<double> k(144);
  for (int col = 0; col < 12; ++col) {
    Real u[12] = {0}, f[12];
    const int node = col / 3, field = col % 3;
    u[field * 4 + local_to_mesh[node]] = 1;
    p.internal_force(u, u + 4, u + 8, f, f + 4, f + 8);
    for (int row = 0; row < 12; ++row) k[row * 12 + col] = f[(row % 3) * 4 + local_to_mesh[row / 3]];
  }
  return k;
}

}  // namespace impactsim
