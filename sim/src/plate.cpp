// Plate: mesh + element + lumped mass + central-difference stepper + Hertz contact + sensor sampling.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <sstream>
#include <stdexcept>

#if defined(__SSE__) || defined(__x86_64__)
#include <xmmintrin.h>
#define IMPACTSIM_X86 1
#endif

#include "element.h"
#include "fused.h"
#include "impactsim.h"

namespace impactsim {

int version() { return 1; }

namespace {

void need(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument(what);
}

// d and beta are stored row by row (6 rs floats a row), block-interleaved [16-node block][d w, bx, by |
// beta w, bx, by][16]: node i, field f at db_index(i, f), its beta kBetaOffset further on.
constexpr int kBetaOffset = 48;
inline size_t db_index(int64_t i, int f) { return static_cast<size_t>((i / 16) * 96 + f * 16 + i % 16); }

struct AlignedFloats {  // zero-initialised, 64-byte aligned
  std::vector<float> raw;
  float* p;
  explicit AlignedFloats(size_t n) : raw(n + 16, 0.0f) {
    const size_t mis = reinterpret_cast<uintptr_t>(raw.data()) % 64;
    p = raw.data() + (mis ? (64 - mis) / sizeof(float) : 0);
  }
};

struct Bilinear {  // node indices and weights of a point inside the mesh
  int64_t node[4];
  double wt[4];
};

// Flush denormals to zero while stepping (wave fronts have exponentially small tails; denormal arithmetic is
// ~100x slower on x86). Restores the caller's mode.
struct DenormalGuard {
#ifdef IMPACTSIM_X86
  unsigned int saved = _mm_getcsr();
  DenormalGuard() { _mm_setcsr(saved | 0x8040u); }
  ~DenormalGuard() { _mm_setcsr(saved); }
#endif
};

Bilinear locate(const PlateSpec& s, double x, double y) {
  const double lx = s.nx * s.hx_m, ly = s.ny * s.hy_m;
  need(x >= 0 && x <= lx && y >= 0 && y <= ly, "contact point lies off the plate");
  int i = std::min(static_cast<int>(x / s.hx_m), s.nx - 1);
  int j = std::min(static_cast<int>(y / s.hy_m), s.ny - 1);
  const double xi = x / s.hx_m - i, eta = y / s.hy_m - j;  // 0..1
  const int64_t r = s.nx + 1;
  Bilinear b;
  b.node[0] = j * r + i;
  b.node[1] = j * r + i + 1;
  b.node[2] = (j + 1) * r + i + 1;
  b.node[3] = (j + 1) * r + i;
  b.wt[0] = (1 - xi) * (1 - eta);
  b.wt[1] = xi * (1 - eta);
  b.wt[2] = xi * eta;
  b.wt[3] = (1 - xi) * eta;
  return b;
}

}  // namespace

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
  base_f_ = detail::Coef<Real>(s_.hx_m, s_.hy_m, s_.nu, d0_, s0_);
  base_d_ = detail::Coef<double>(s_.hx_m, s_.hy_m, s_.nu, d0_, s0_);
  row_start_.assign(static_cast<size_t>(s_.ny) + 1, 0);
  for (int j = 0; j < s_.ny; ++j) {
    row_start_[j] = static_cast<int64_t>(special_.size());
    for (int i = 0; i < s_.nx; ++i) {
      const size_t e = static_cast<size_t>(j) * s_.nx + i;
      if (s_.d_elem[e] == d0_ && s_.s_elem[e] == s0_) continue;
      const double dd = s_.d_elem[e] - d0_, ds = s_.s_elem[e] - s0_;
      special_.push_back({i, detail::Coef<Real>(s_.hx_m, s_.hy_m, s_.nu, dd, ds),
                          detail::Coef<double>(s_.hx_m, s_.hy_m, s_.nu, dd, ds)});
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
const detail::Coef<T>& coef_of(const Plate::Special& sp);
template <>
const detail::Coef<float>& coef_of<float>(const Plate::Special& sp) {
  return sp.kf;
}
template <>
const detail::Coef<double>& coef_of<double>(const Plate::Special& sp) {
  return sp.kd;
}

// Edge accumulators of two node rows (rolling), each array padded by one zero on both sides.
template <typename T>
struct Accumulators {
  std::vector<T> buf;
  detail::RowAcc<T> row[2];
  int nx;
  explicit Accumulators(int nx_) : buf(static_cast<size_t>(12) * (nx_ + 2), T(0)), nx(nx_) {
    for (int r = 0; r < 2; ++r) {
      T* b = buf.data() + static_cast<size_t>(6 * r) * (nx + 2) + 1;
      const size_t l = static_cast<size_t>(nx) + 2;
      row[r] = {b, b + l, b + 2 * l, b + 3 * l, b + 4 * l, b + 5 * l};
    }
  }
  void clear(int r) {
    const detail::RowAcc<T>& a = row[r];
    for (T* p : {a.pw, a.qw, a.px, a.qx, a.py, a.qy}) std::fill(p, p + nx, T(0));
  }
};

// One pass over the element rows (state rows rs apart): after element row j (and its corrections) node row j is complete and
// done(j, acc) is called with its accumulators; node row ny last. done may overwrite node row j's state:
// later element rows no longer read it.
template <typename T, typename Done>
IMPACTSIM_INLINE void sweep(int nx, int ny, int64_t rs, const detail::Coef<T>& base, const Plate::Special* special,
                            const int64_t* row_start, const T* w, const T* bx, const T* by, Accumulators<T>& acc,
                            Done&& done) {
  int cur = 0;
  acc.clear(cur);
  for (int j = 0; j < ny; ++j) {
    const int64_t o0 = j * rs, o1 = o0 + rs;
    const detail::RowIn<T> in{w + o0, w + o1, bx + o0, bx + o1, by + o0, by + o1};
    const detail::RowAcc<T>& lo = acc.row[cur];
    const detail::RowAcc<T>& hi = acc.row[1 - cur];
    detail::element_row<T, false>(nx, in, base, lo, hi);
    for (int64_t k = row_start[j]; k < row_start[j + 1]; ++k) {
      const int i = special[k].i;
      detail::element_row<T, true>(1, in.at(i), coef_of<T>(special[k]), lo.at(i), hi.at(i));
    }
    done(j, lo);
    cur = 1 - cur;
  }
  done(ny, acc.row[cur]);
}

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

// The stepper's pass: internal forces and the central-difference update of a row as soon as it is complete,
//   d_{n+1/2} = alpha d_{n-1/2} - beta f,  u_{n+1} = u_n + d_{n+1/2}   (d = dt v, beta = dt^2 c2 / m, 0 at
// fixed dofs and padding). External loads are added afterwards (they do not enter this step's internal forces).
struct StepArgs {
  int nx, ny;
  int64_t rs;         // row stride of the state arrays (padded: a multiple of 16 floats, one block to spare)
  size_t np;          // field stride, (ny + 1) * rs
  const detail::Coef<float>* base;
  const Plate::Special* special;
  const int64_t* row_start;
  float* u;           // [w | bx | by], 64-byte aligned rows
  float* db;          // d and beta, rows of 6 rs floats, block-interleaved (db_index)
  float alpha;
  Accumulators<float>* acc;  // portable path
  float* edge;               // fused path: 2 x 6 edge arrays of rs floats, block-interleaved (zero beyond nx)
  const int64_t* scaled_row;     // fused path: per element row, index into the scale tables or -1
  const uint8_t* scaled_block;   // [scaled row][16-element block]: 1 if the block holds a special element
  const float* scale;            // [scaled row][D / D0 (rs floats), S / S0 (rs floats)]
  int64_t nblocks;
};

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(IMPACTSIM_NO_CLONES)
#define IMPACTSIM_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define IMPACTSIM_CLONES
#endif
#if defined(__GNUC__)
#define IMPACTSIM_LAMBDA_INLINE __attribute__((always_inline))
#else
#define IMPACTSIM_LAMBDA_INLINE
#endif

IMPACTSIM_CLONES void step_fast(const StepArgs& a) {
  const int64_t rs = a.rs;
  const size_t np = a.np;
  float* const u = a.u;
  const float alpha = a.alpha;
#ifdef IMPACTSIM_FUSED
  static_assert(detail::kLanes == 16 && detail::kBetaOffset == kBetaOffset, "d/beta layout differs from fused.h");
  float* const set[2] = {a.edge, a.edge + 6 * rs};
  std::fill(set[0], set[0] + 6 * rs, 0.0f);
  int cur = 0;
  detail::FusedRow fr;
  for (int j = 0; j <= a.ny; ++j) {
    for (int f = 0; f < 3; ++f) {
      fr.u0[f] = u + f * np + j * rs;
      fr.u1[f] = u + f * np + (j < a.ny ? j + 1 : j) * rs;
    }
    fr.db = a.db + j * 6 * rs;
    fr.in = set[cur];
    fr.out = set[1 - cur];
    if (j == a.ny) {
      detail::last_row(a.nx, alpha, fr);
      break;
    }
    const int64_t sr = a.scaled_row[j];  // rows with disc elements: per-element stiffness on their blocks
    if (sr >= 0)
      detail::fused_row(a.nx, *a.base, alpha, fr, a.scaled_block + sr * a.nblocks, a.scale + 2 * sr * rs,
                        a.scale + (2 * sr + 1) * rs);
    else
      detail::fused_row(a.nx, *a.base, alpha, fr, nullptr, nullptr, nullptr);
    cur = 1 - cur;
  }
#else
  const int rl = a.nx + 1;
  sweep<float>(a.nx, a.ny, rs, *a.base, a.special, a.row_start, u, u + np, u + 2 * np, *a.acc,
               [&](int j, const detail::RowAcc<float>& acc) IMPACTSIM_LAMBDA_INLINE {
                 const size_t o = static_cast<size_t>(j) * rs;
                 const float* const p[3] = {acc.pw, acc.px, acc.py};
                 const float* const q[3] = {acc.qw, acc.qx, acc.qy};
                 for (int fld = 0; fld < 3; ++fld) {
                   float* __restrict uu = u + fld * np + o;
                   float* const db = a.db + j * 6 * rs;
                   const float* __restrict pp = p[fld];
                   const float* __restrict qq = q[fld];
                   for (int i = 0; i < rl; ++i) {
                     float* const dd = db + db_index(i, fld);
                     const float dn = alpha * dd[0] - dd[kBetaOffset] * detail::node_force(pp, qq, i);
                     dd[0] = dn;
                     uu[i] += dn;
                   }
                 }
               });
#endif
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

namespace {
// A functional as runs of consecutive (padded) node indices, so its value is a few contiguous dot products.
struct Segmented {
  std::vector<int64_t> start, length;
  std::vector<double> wx, wy;  // concatenated over the runs
  explicit Segmented(const Functional& fn) {
    std::vector<size_t> order(fn.node.size());
    for (size_t k = 0; k < order.size(); ++k) order[k] = k;
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return fn.node[a] < fn.node[b]; });
    for (size_t k : order) {
      const int64_t node = fn.node[k];
      if (!start.empty() && node == start.back() + length.back() - 1) {  // repeated node: add its weights
        wx.back() += fn.wx[k];
        wy.back() += fn.wy[k];
        continue;
      }
      if (start.empty() || node != start.back() + length.back()) {
        start.push_back(node);
        length.push_back(0);
      }
      ++length.back();
      wx.push_back(fn.wx[k]);
      wy.push_back(fn.wy[k]);
    }
  }
  double operator()(const Real* bx, const Real* by) const {
    double v = 0;
    const double* ax = wx.data();
    const double* ay = wy.data();
    for (size_t r = 0; r < start.size(); ++r) {
      const Real* x = bx + start[r];
      const Real* y = by + start[r];
      const int64_t n = length[r];
#pragma omp simd reduction(+ : v)
      for (int64_t k = 0; k < n; ++k) v += ax[k] * x[k] + ay[k] * y[k];
      ax += n;
      ay += n;
    }
    return v;
  }
};

// True if every value is finite (NaN and Inf survive a multiplication by zero; the sum's order is immaterial).
IMPACTSIM_CLONES bool all_finite(const float* x, size_t n) {
  float acc = 0;
#pragma omp simd reduction(+ : acc)
  for (size_t k = 0; k < n; ++k) acc += x[k] * 0.0f;
  return acc == 0;
}
}  // namespace

RunResult Plate::run(const RunConfig& c) const {
  DenormalGuard ftz;
  const size_t nn = static_cast<size_t>(nodes());
  need(c.dt_s > 0 && std::isfinite(c.dt_s), "time step must be positive");
  need(c.n_steps >= 0, "n_steps must be >= 0");
  need(c.record_every >= 1, "record_every must be >= 1");
  need(c.n_record >= 0, "n_record must be >= 0");
  for (const auto* fn : {&c.load}) {
    need(fn->node.size() == fn->wx.size() && fn->node.size() == fn->wy.size(), "functional arrays differ in size");
  }
  for (const auto& fn : c.sensors) {
    need(fn.node.size() == fn.wx.size() && fn.node.size() == fn.wy.size(), "functional arrays differ in size");
    for (auto k : fn.node) need(k >= 0 && static_cast<size_t>(k) < nn, "functional node out of range");
  }
  for (auto k : c.load.node) need(k >= 0 && static_cast<size_t>(k) < nn, "load node out of range");
  Bilinear cp{};
  if (c.ball.enabled) {
    need(c.ball.mass_kg > 0 && c.ball.k_hertz > 0, "ball mass and Hertz constant must be positive");
    cp = locate(s_, c.ball.x_m, c.ball.y_m);
  }

  // state: u = [w | bx | by]; d = dt * v at half steps, likewise. Rows padded to rs floats (64-byte aligned),
  // so node k = j * rl + i lives at j * rs + i.
  const int nx = s_.nx, ny = s_.ny, rl = nx + 1;
  const int64_t rs = 16 * ((nx + 15) / 16 + 1);
  const size_t np = static_cast<size_t>(ny + 1) * rs;
  auto at = [&](int64_t k) { return static_cast<size_t>((k / rl) * rs + k % rl); };
  AlignedFloats u_buf(3 * np), db_buf(static_cast<size_t>(ny + 1) * 6 * rs), mass_buf(3 * np);
  float* const u = u_buf.p;
  float* const db = db_buf.p;  // d = dt * v and beta, see db_index
  float* const mass = mass_buf.p;
  auto d_at = [&](int f, int64_t k) { return static_cast<size_t>((k / rl) * 6 * rs) + db_index(k % rl, f); };
  auto load_init = [&](const std::vector<double>& src, size_t field, double scale, float* dst, const char* name) {
    if (src.empty()) return;
    need(src.size() == nn, std::string(name) + " needs one value per node");
    for (size_t k = 0; k < nn; ++k) dst[dst == u ? field * np + at(k) : d_at(int(field), k)] = Real(scale * src[k]);
  };
  load_init(c.w0, 0, 1.0, u, "w0");
  load_init(c.bx0, 1, 1.0, u, "bx0");
  load_init(c.by0, 2, 1.0, u, "by0");
  load_init(c.vw0, 0, c.dt_s, db, "vw0");
  load_init(c.vbx0, 1, c.dt_s, db, "vbx0");
  load_init(c.vby0, 2, c.dt_s, db, "vby0");
  const double cd = 0.5 * s_.damping_per_s * c.dt_s;
  const Real alpha = Real((1 - cd) / (1 + cd));
  for (size_t r = 0; r < spring_node_.size(); ++r)
    need(spring_c_[r] * c.dt_s <= s_.mass_w[static_cast<size_t>(spring_node_[r])],
         "node dashpot too strong for the explicit step: c_w dt / m_w must be <= 1");
  for (size_t k = 0; k < nn; ++k) {
    const size_t o = at(k);
    const Real inv_m[3] = {inv_mw_[k], inv_mr_[k], inv_mr_[nn + k]};
    const Real m_k[3] = {Real(s_.mass_w[k]), Real(s_.mass_r[k]), Real(s_.mass_r[k])};
    for (int f = 0; f < 3; ++f) {
      db[d_at(f, k) + kBetaOffset] = Real(c.dt_s * c.dt_s / (1 + cd) * inv_m[f]);
      mass[f * np + o] = m_k[f];
      if (inv_m[f] == 0) u[f * np + o] = db[d_at(f, k)] = 0;  // fixed dofs stay at zero
    }
  }
  // Sub-cycled patches (set_subcycling): each patch with its ring of large-step nodes is a small grid of its
  // own, stepped msub times per step with dt / msub by the same stepper (step_fast); the ring has beta = d = 0
  // there and is set before each sub-step to u_n + theta (u_{n+1} - u_n), theta = k / msub. The patch's nodes
  // get beta = d = 0 in the global pass, which so leaves them alone; they are copied back after the sub-steps.
  const int msub = (!patches_.empty() && fine_dt_ > 0)
                       ? std::max(1, static_cast<int>(std::ceil(c.dt_s / fine_dt_ - 1e-9))) : 1;
  const double dts = c.dt_s / msub, cds = 0.5 * s_.damping_per_s * dts;
  const Real alpha_s = Real((1 - cds) / (1 + cds));
  struct PatchGrid {
    const Patch* pt;
    int64_t rs;                  // local row stride (padded like the plate's)
    size_t np;                   // local field stride
    AlignedFloats u, db, edge;   // local state, d and beta (db_index layout), edge arrays of the fused pass
    Accumulators<Real> acc;      // portable pass
    std::vector<Special> special;
    std::vector<int64_t> row_start, scaled_row;
    std::vector<uint8_t> scaled_block;
    std::vector<float> scale;
    std::vector<int64_t> ring_l, ring_g, in_l, in_g;  // local / global padded node of each ring / patch node
    std::vector<Real> ring0, ring1;                   // [3][ring]: u_n, u_{n+1}
    std::vector<Real> mass, d_old;                    // [3][patch node] (energy steps)
    std::vector<int64_t> load_l;                      // this step's loads on the patch: local node, field
    std::vector<int> load_f;
    std::vector<Real> load_v;
    StepArgs args;
    PatchGrid(int lnx, int lny)
        : rs(16 * ((lnx + 15) / 16 + 1)), np(static_cast<size_t>(lny + 1) * rs), u(3 * np),
          db(static_cast<size_t>(lny + 1) * 6 * rs), edge(static_cast<size_t>(12) * rs), acc(lnx) {}
  };
  std::vector<std::unique_ptr<PatchGrid>> grids;
  if (msub > 1) {
    for (const Patch& pt : patches_) {
      const int lnx = pt.ei1 - pt.ei0, lny = pt.ej1 - pt.ej0;  // elements of the local grid
      grids.push_back(std::make_unique<PatchGrid>(lnx, lny));
      PatchGrid& g = *grids.back();
      g.pt = &pt;
      const int64_t lrs = g.rs;
      // elements unlike the base one: corrections (portable pass) and per-block scale tables (fused pass)
      const int64_t nb = (lnx + 15) / 16;
      g.row_start.assign(static_cast<size_t>(lny) + 1, 0);
      g.scaled_row.assign(static_cast<size_t>(lny), -1);
      for (int lj = 0, n_rows = 0; lj < lny; ++lj) {
        const int j = pt.ej0 + lj;
        g.row_start[lj] = static_cast<int64_t>(g.special.size());
        bool any = false;
        for (int64_t k = row_start_[j]; k < row_start_[j + 1]; ++k) {
          if (special_[k].i < pt.ei0 || special_[k].i >= pt.ei1) continue;
          g.special.push_back(special_[k]);
          g.special.back().i -= pt.ei0;
          any = true;
        }
        if (!any) continue;
        g.scaled_row[lj] = n_rows++;
        g.scaled_block.resize(static_cast<size_t>(n_rows * nb), 0);
        g.scale.resize(static_cast<size_t>(2 * n_rows * lrs), 1.0f);
        float* ds = g.scale.data() + 2 * (n_rows - 1) * lrs;
        float* ss = ds + lrs;
        for (int li = 0; li < lnx; ++li) {
          const size_t e = static_cast<size_t>(j) * nx + pt.ei0 + li;
          ds[li] = Real(s_.d_elem[e] / d0_);
          ss[li] = Real(s_.s_elem[e] / s0_);
          if (s_.d_elem[e] != d0_ || s_.s_elem[e] != s0_) g.scaled_block[(n_rows - 1) * nb + li / 16] = 1;
        }
      }
      g.row_start[lny] = static_cast<int64_t>(g.special.size());
      for (int lj = 0; lj <= lny; ++lj)
        for (int li = 0; li <= lnx; ++li) {
          const int i = pt.ei0 + li, j = pt.ej0 + lj;
          const int64_t k = static_cast<int64_t>(j) * rl + i, gl = static_cast<int64_t>(at(k)), ll = lj * lrs + li;
          for (int f = 0; f < 3; ++f) g.u.p[f * g.np + ll] = u[f * np + gl];
          if (!sub_[static_cast<size_t>(k)]) {
            g.ring_l.push_back(ll);
            g.ring_g.push_back(gl);
            continue;
          }
          g.in_l.push_back(ll);
          g.in_g.push_back(gl);
          const Real inv_m[3] = {inv_mw_[k], inv_mr_[k], inv_mr_[nn + k]};
          const std::vector<double>* v0[3] = {&c.vw0, &c.vbx0, &c.vby0};
          for (int f = 0; f < 3; ++f) {
            float* const dl = g.db.p + lj * 6 * lrs + db_index(li, f);
            dl[kBetaOffset] = Real(dts * dts / (1 + cds) * inv_m[f]);
            if (!v0[f]->empty() && inv_m[f] != 0) dl[0] = Real(dts * (*v0[f])[k]);
            db[d_at(f, k)] = db[d_at(f, k) + kBetaOffset] = 0;
          }
        }
      const size_t nr = g.ring_l.size(), ni = g.in_l.size();
      g.ring0.assign(3 * nr, Real(0));
      g.ring1.assign(3 * nr, Real(0));
      g.d_old.assign(3 * ni, Real(0));
      g.mass.resize(3 * ni);
      for (int f = 0; f < 3; ++f)
        for (size_t r = 0; r < ni; ++r) g.mass[f * ni + r] = mass[f * np + g.in_g[r]];
      g.args = StepArgs{lnx, lny, lrs, g.np, &base_f_, g.special.data(), g.row_start.data(), g.u.p, g.db.p,
                        alpha_s, &g.acc, g.edge.p, g.scaled_row.data(), g.scaled_block.data(), g.scale.data(), nb};
    }
  }
  // local db offset of local padded node l, field f
  auto local_d = [](const PatchGrid& g, int64_t l, int f) {
    return static_cast<size_t>((l / g.rs) * 6 * g.rs) + db_index(l % g.rs, f);
  };
  std::vector<Segmented> sensors;  // node indices into the padded rows
  for (Functional fn : c.sensors) {
    for (auto& k : fn.node) k = static_cast<int64_t>(at(k));
    sensors.emplace_back(fn);
  }
  Functional hat = c.load;
  for (auto& k : hat.node) k = static_cast<int64_t>(at(k));
  int64_t cp_at[4] = {0, 0, 0, 0};
  if (c.ball.enabled)
    for (int a = 0; a < 4; ++a) cp_at[a] = static_cast<int64_t>(at(cp.node[a]));

  RunResult res;
  const int m = c.record_every;
  const int64_t nrec = c.n_record;
  const size_t ns = sensors.size();
  res.sensors.assign(ns * nrec, 0.0);
  if (c.record_field) res.field.assign(static_cast<size_t>(nrec) * nn, 0.0f);
  if (c.record_energy) res.energy.assign(static_cast<size_t>(nrec) * 4, 0.0);
  if (c.ball.enabled) res.force_n.reserve(static_cast<size_t>(c.n_steps));

  const double delta_rec = m * c.dt_s;
  Accumulators<Real> acc(nx);
  AlignedFloats edge(static_cast<size_t>(12) * rs);
  // rows holding elements unlike the base one: stiffness ratios per element, flags per 16-element block
  const int64_t nblocks = (nx + 15) / 16;
  std::vector<int64_t> scaled_row(static_cast<size_t>(ny), -1);
  std::vector<uint8_t> scaled_block;
  std::vector<float> scale;
  for (int j = 0, n_rows = 0; j < ny; ++j) {
    if (row_start_[j + 1] == row_start_[j]) continue;
    scaled_row[j] = n_rows++;
    scaled_block.resize(static_cast<size_t>(n_rows * nblocks), 0);
    scale.resize(static_cast<size_t>(2 * n_rows * rs), 1.0f);
    float* ds = scale.data() + 2 * (n_rows - 1) * rs;
    float* ss = ds + rs;
    for (int i = 0; i < nx; ++i) {
      const size_t e = static_cast<size_t>(j) * nx + i;
      ds[i] = Real(s_.d_elem[e] / d0_);
      ss[i] = Real(s_.s_elem[e] / s0_);
      if (s_.d_elem[e] != d0_ || s_.s_elem[e] != s0_) scaled_block[(n_rows - 1) * nblocks + i / 16] = 1;
    }
  }
  const StepArgs step{nx, ny, rs, np, &base_f_, special_.data(), row_start_.data(), u, db, alpha, &acc,
                      edge.p, scaled_row.data(), scaled_block.data(), scale.data(), nblocks};
  std::vector<Real> frow(static_cast<size_t>(3) * rl);  // energy steps: explicit forces of one node row
  // external loads of the step: (padded node, field, value), sorted by node
  struct Load {
    int64_t node;
    int field;
    Real value;
  };
  std::vector<Load> loads;

  double zb = 0, vb = c.ball.v0_m_s;  // ball: position (down = into the plate), velocity at half step
  bool in_contact = false;
  double t_first = -1, t_last = -1;
  Real* const uw = u;
  Real* const ubx = u + np;
  Real* const uby = u + 2 * np;

  for (int64_t n = 0; n < c.n_steps; ++n) {
    const double t = n * c.dt_s;
    const int64_t q = n / m;
    const int r = static_cast<int>(n % m);
    const double frac = double(r) / m;
    const bool on_grid = (r == 0) && q < nrec;
    const bool want_energy = c.record_energy && on_grid;

    // ball contact (state at t_n)
    loads.clear();
    double force = 0, delta = 0;
    if (c.ball.enabled) {
      double wp = 0;
      for (int a = 0; a < 4; ++a) wp += cp.wt[a] * uw[cp_at[a]];
      delta = zb - wp;
      if (delta > 0) {
        force = c.ball.k_hertz * delta * std::sqrt(delta);
        if (!in_contact) {
          ++res.contacts;
          if (t_first < 0) t_first = t;
        }
        in_contact = true;
        t_last = t;
      } else {
        in_contact = false;
      }
      if (force > 0)
        for (int a = 0; a < 4; ++a) loads.push_back({cp_at[a], 0, Real(cp.wt[a] * force)});
      res.force_n.push_back(force);
    }
    if (c.hat_load) {
      const double phi = std::max(0.0, 1.0 - std::fabs(t - delta_rec) / delta_rec);
      if (phi > 0) {
        for (size_t k = 0; k < hat.node.size(); ++k) {
          loads.push_back({hat.node[k], 1, Real(phi * hat.wx[k])});
          loads.push_back({hat.node[k], 2, Real(phi * hat.wy[k])});
        }
      }
    }
    for (size_t r = 0; r < spring_node_.size(); ++r) {  // node springs and dashpots: -k w_n - c v_{n-1/2}
      const int64_t k = spring_node_[r];
      const size_t o = at(k);
      const double v = double(db[d_at(0, k)]) / c.dt_s;
      loads.push_back({static_cast<int64_t>(o), 0, Real(-spring_k_[r] * double(uw[o]) - spring_c_[r] * v)});
    }
    if (loads.size() > 1)
      std::sort(loads.begin(), loads.end(), [](const Load& x, const Load& y) { return x.node < y.node; });

    // outputs at time t (hat weights onto the record grid)
    if (q < nrec) {
      const double w_lo = (1 - frac) / m, w_hi = frac / m;
      const bool hi_ok = r > 0 && q + 1 < nrec;
      for (size_t si = 0; si < ns; ++si) {
        const double val = sensors[si](ubx, uby);
        res.sensors[si * nrec + q] += w_lo * val;
        if (hi_ok) res.sensors[si * nrec + q + 1] += w_hi * val;
      }
      if (c.record_field) {
        float* lo = res.field.data() + static_cast<size_t>(q) * nn;
        const float a = float(w_lo), b = float(w_hi);
        for (int j = 0; j <= ny; ++j) {
          const Real* row = uw + static_cast<size_t>(j) * rs;
          float* lo_j = lo + static_cast<size_t>(j) * rl;
          for (int i = 0; i < rl; ++i) lo_j[i] += a * row[i];
          if (hi_ok) {
            float* hi_j = lo_j + nn;
            for (int i = 0; i < rl; ++i) hi_j[i] += b * row[i];
          }
        }
      }
    }

    for (auto& gp : grids) {  // u_n of the patch's ring; the step's loads on the patch's nodes
      PatchGrid& g = *gp;
      const size_t nr = g.ring_l.size();
      for (int f = 0; f < 3; ++f)
        for (size_t r = 0; r < nr; ++r) g.ring0[f * nr + r] = u[f * np + g.ring_g[r]];
      g.load_l.clear();
      g.load_f.clear();
      g.load_v.clear();
      const Patch& pt = *g.pt;
      for (const Load& ld : loads) {
        const int j = static_cast<int>(ld.node / rs), i = static_cast<int>(ld.node % rs);
        if (i < pt.i0 || i > pt.i1 || j < pt.j0 || j > pt.j1) continue;
        g.load_l.push_back((j - pt.ej0) * g.rs + (i - pt.ei0));
        g.load_f.push_back(ld.field);
        g.load_v.push_back(ld.value);
      }
    }

    if (!want_energy) {
      step_fast(step);
      for (const Load& l : loads) {  // u_{n+1} += beta P, d += beta P
        const size_t k = static_cast<size_t>(l.field) * np + l.node;
        float* const dk = db + (l.node / rs) * 6 * rs + db_index(l.node % rs, l.field);
        const Real inc = dk[kBetaOffset] * l.value;
        dk[0] += inc;
        u[k] += inc;
      }
    } else {  // the portable pass, with the strain and kinetic energy (plate) accumulated
      double se = 0, ke = 0;
      size_t li = 0;
      sweep<Real>(nx, ny, rs, base_f_, special_.data(), row_start_.data(), uw, ubx, uby, acc,
                  [&](int j, const detail::RowAcc<Real>& a) {
                    const int64_t row0 = static_cast<int64_t>(j) * rs;
                    const Real* const p[3] = {a.pw, a.px, a.py};
                    const Real* const qq[3] = {a.qw, a.qx, a.qy};
                    for (int fld = 0; fld < 3; ++fld)
                      for (int i = 0; i < rl; ++i) {
                        frow[fld * rl + i] = detail::node_force(p[fld], qq[fld], i);
                        se += double(u[fld * np + row0 + i]) * frow[fld * rl + i];
                      }
                    while (li < loads.size() && loads[li].node < row0 + rl) {
                      frow[loads[li].field * rl + (loads[li].node - row0)] -= loads[li].value;
                      ++li;
                    }
                    for (int fld = 0; fld < 3; ++fld)
                      for (int i = 0; i < rl; ++i) {
                        const size_t k = fld * np + row0 + i;
                        float* const dk = db + static_cast<size_t>(j) * 6 * rs + db_index(i, fld);
                        const Real dn = alpha * dk[0] - dk[kBetaOffset] * frow[fld * rl + i];
                        ke += double(mass[k]) * dk[0] * dn;
                        dk[0] = dn;
                        u[k] += dn;
                      }
                  });
      for (size_t r = 0; r < spring_node_.size(); ++r) {  // spring energy at u_n (springs are part of K)
        const double wn = double(u[at(spring_node_[r])]) - double(db[d_at(0, spring_node_[r])]);
        se += spring_k_[r] * wn * wn;
      }
      res.energy[q * 4 + 0] = 0.5 * ke / (c.dt_s * c.dt_s);
      res.energy[q * 4 + 1] = 0.5 * se;
    }
    double ke_sub = 0;  // sub-cycled patches: msub steps of dt / msub, the ring interpolated in time
    for (auto& gp : grids) {
      PatchGrid& g = *gp;
      const size_t nr = g.ring_l.size(), ni = g.in_l.size();
      float* const lu = g.u.p;
      for (int f = 0; f < 3; ++f)  // u_{n+1} of the ring
        for (size_t r = 0; r < nr; ++r) g.ring1[f * nr + r] = u[f * np + g.ring_g[r]];
      for (int k = 0; k < msub; ++k) {
        const Real th = Real(k) / Real(msub);
        for (int f = 0; f < 3; ++f)
          for (size_t r = 0; r < nr; ++r)
            lu[f * g.np + g.ring_l[r]] = g.ring0[f * nr + r] + th * (g.ring1[f * nr + r] - g.ring0[f * nr + r]);
        const bool energy_now = want_energy && k == 0;
        if (energy_now)
          for (int f = 0; f < 3; ++f)
            for (size_t r = 0; r < ni; ++r) g.d_old[f * ni + r] = g.db.p[local_d(g, g.in_l[r], f)];
        step_fast(g.args);
        for (size_t l = 0; l < g.load_l.size(); ++l) {  // the step's loads at every sub-step (impulse dt P)
          float* const dk = g.db.p + local_d(g, g.load_l[l], g.load_f[l]);
          const Real inc = dk[kBetaOffset] * g.load_v[l];
          dk[0] += inc;
          lu[g.load_f[l] * g.np + g.load_l[l]] += inc;
        }
        if (energy_now)
          for (int f = 0; f < 3; ++f)
            for (size_t r = 0; r < ni; ++r)
              ke_sub += double(g.mass[f * ni + r]) * g.d_old[f * ni + r] * g.db.p[local_d(g, g.in_l[r], f)];
      }
      for (int f = 0; f < 3; ++f)
        for (size_t r = 0; r < ni; ++r) u[f * np + g.in_g[r]] = lu[f * g.np + g.in_l[r]];
    }
    if (want_energy) res.energy[q * 4 + 0] += 0.5 * ke_sub / (dts * dts);

    if (c.ball.enabled) {
      const double vb_old = vb;
      vb += c.dt_s * (c.ball.g_m_s2 - force / c.ball.mass_kg);
      if (want_energy) {
        res.energy[q * 4 + 2] = 0.5 * c.ball.mass_kg * vb_old * vb;
        res.energy[q * 4 + 3] = (delta > 0 ? 0.4 * c.ball.k_hertz * delta * delta * std::sqrt(delta) : 0.0) -
                                c.ball.mass_kg * c.ball.g_m_s2 * zb;
      }
      zb += c.dt_s * vb;
    }
    res.steps_done = n + 1;

    if (c.nan_check_every > 0 && ((n + 1) % c.nan_check_every == 0 || n + 1 == c.n_steps)) {
      const bool bad = !std::isfinite(zb) || !std::isfinite(vb) || !all_finite(u, 3 * np);
      if (bad) {
        std::ostringstream os;
        os << "numerical blow-up (NaN/Inf) detected at step " << (n + 1) << " of " << c.n_steps
           << " (t = " << (n + 1) * c.dt_s * 1e6 << " us, checked every " << c.nan_check_every
           << " steps, dt = " << c.dt_s * 1e6 << " us)";
        throw std::runtime_error(os.str());
      }
    }
    if (c.stop_after_contact && t_first >= 0 && !in_contact && vb < 0 &&
        t - t_last > std::max(c.quiet_after_contact_s, t_last - t_first)) {
      break;
    }
  }
  res.ball_z_m = zb;
  res.ball_v_m_s = vb;
  res.contact_start_s = t_first;
  res.contact_end_s = t_last;
  res.w.resize(nn);
  res.bx.resize(nn);
  res.by.resize(nn);
  for (size_t k = 0; k < nn; ++k) {
    res.w[k] = u[at(k)];
    res.bx[k] = u[np + at(k)];
    res.by[k] = u[2 * np + at(k)];
  }
  return res;
}

std::vector<double> element_stiffness(double hx_m, double hy_m, double d, double nu, double s) {
  PlateSpec sp;
  sp.nx = sp.ny = 1;
  sp.hx_m = hx_m;
  sp.hy_m = hy_m;
  sp.nu = nu;
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
