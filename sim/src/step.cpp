// Plate::Run's step (contact and loads, outputs on the record grid, the central-difference update of the
// plate and of its sub-cycled patches, the ball), its result, and Plate::run.
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "run.h"

namespace impactsim {

using detail::DenormalGuard;
using detail::sweep;

// Hertz contact at t_n: the force (0 when apart) and the overlap delta; the force's loads on the contact nodes.
double Plate::Run::contact(double t, double& delta) {
  double force = 0, wp = 0;
  for (int a = 0; a < 4; ++a) wp += cp_.wt[a] * u_[cp_at_[a]];
  delta = zb_ - wp;
  if (delta > 0) {
    force = c_.ball.k_hertz * delta * std::sqrt(delta);
    if (!in_contact_) {
      ++res_.contacts;
      if (t_first_ < 0) t_first_ = t;
    }
    in_contact_ = true;
    t_last_ = t;
  } else {
    in_contact_ = false;
  }
  if (force > 0)
    for (int a = 0; a < 4; ++a) loads_.push_back({cp_at_[a], 0, Real(cp_.wt[a] * force)});
  res_.force_n.push_back(force);
  return force;
}

// The hat load (reciprocity runs) and the node springs and dashpots (-k w_n - c v_{n-1/2}); loads sorted.
// The hat through a first-order low-pass of time constant tau: the hat is (r(s) - 2 r(s - Delta) + r(s - 2 Delta))
// / Delta with r the unit ramp from its start s = t - load_delay_s, and the low-pass's ramp response is
// s - tau (1 - exp(-s / tau)) for s > 0 (0 before); after the hat (s >= 2 Delta) the ramps' linear parts cancel and
// the tail is tau exp(-(s - 2 Delta) / tau) (1 - exp(-Delta / tau))^2 / Delta, written so (no cancellation).
static double lowpassed_hat(double s, double delta, double tau) {
  if (s >= 2.0 * delta) {
    const double e = -std::expm1(-delta / tau);
    return tau * std::exp(-(s - 2.0 * delta) / tau) * e * e / delta;
  }
  auto ramp = [tau](double u) { return u > 0 ? u + tau * std::expm1(-u / tau) : 0.0; };
  return (ramp(s) - 2.0 * ramp(s - delta)) / delta;
}

void Plate::Run::add_loads(double t) {
  const double delta_rec = c_.record_every * c_.dt_s;
  if (c_.hat_load) {
    const double phi = c_.load_lowpass_s > 0
                           ? lowpassed_hat(t - c_.load_delay_s, delta_rec, c_.load_lowpass_s)
                           : std::max(0.0, 1.0 - std::fabs(t - delta_rec - c_.load_delay_s) / delta_rec);
    if (phi > 0) {
      for (size_t k = 0; k < hat_.node.size(); ++k) {
        loads_.push_back({hat_.node[k], 1, Real(phi * hat_.wx[k])});
        loads_.push_back({hat_.node[k], 2, Real(phi * hat_.wy[k])});
      }
    }
  }
  for (size_t r = 0; r < p_.spring_node_.size(); ++r) {
    const int64_t k = p_.spring_node_[r];
    const size_t o = at(k);
    const double v = double(db_[d_at(0, k)]) / c_.dt_s;
    loads_.push_back({static_cast<int64_t>(o), 0, Real(-p_.spring_k_[r] * double(u_[o]) - p_.spring_c_[r] * v)});
  }
  if (loads_.size() > 1)
    std::sort(loads_.begin(), loads_.end(), [](const Load& x, const Load& y) { return x.node < y.node; });
}

// Outputs at t_n = (q m + r) dt onto the record grid (hat weights on samples q and q + 1).
void Plate::Run::record(int64_t q, int r) {
  const int m = c_.record_every;
  const int64_t nrec = c_.n_record;
  const double frac = double(r) / m;
  const double w_lo = (1 - frac) / m, w_hi = frac / m;
  const bool hi_ok = r > 0 && q + 1 < nrec;
  for (size_t si = 0; si < sensors_.size(); ++si) {
    const double val = sensors_[si](u_ + np_, u_ + 2 * np_);
    res_.sensors[si * nrec + q] += w_lo * val;
    if (hi_ok) res_.sensors[si * nrec + q + 1] += w_hi * val;
  }
  if (!c_.record_field) return;
  float* lo = res_.field.data() + static_cast<size_t>(q) * nn_;
  const float a = float(w_lo), b = float(w_hi);
  for (int j = 0; j <= ny_; ++j) {
    const Real* row = u_ + static_cast<size_t>(j) * rs_;
    float* lo_j = lo + static_cast<size_t>(j) * rl_;
    for (int i = 0; i < rl_; ++i) lo_j[i] += a * row[i];
    if (hi_ok) {
      float* hi_j = lo_j + nn_;
      for (int i = 0; i < rl_; ++i) hi_j[i] += b * row[i];
    }
  }
}

// u_n of each patch's ring; the step's loads on the patch's nodes.
void Plate::Run::patch_loads() {
  for (auto& gp : grids_) {
    PatchGrid& g = *gp;
    const size_t nr = g.ring_l.size();
    for (int f = 0; f < 3; ++f)
      for (size_t r = 0; r < nr; ++r) g.ring0[f * nr + r] = u_[f * np_ + g.ring_g[r]];
    g.load_l.clear();
    g.load_f.clear();
    g.load_v.clear();
    const Patch& pt = *g.pt;
    for (const Load& ld : loads_) {
      const int j = static_cast<int>(ld.node / rs_), i = static_cast<int>(ld.node % rs_);
      if (i < pt.i0 || i > pt.i1 || j < pt.j0 || j > pt.j1) continue;
      g.load_l.push_back((j - pt.ej0) * g.rs + (i - pt.ei0));
      g.load_f.push_back(ld.field);
      g.load_v.push_back(ld.value);
    }
  }
}

// After a step: its rows' neighbours and the rows of its nonzero loads may be off rest (a zero load adds +-0
// to d and u at rest, which leaves them +0).
void Plate::Run::widen_cone() {
  if (!cone_) return;
  if (rest_lo_ <= rest_hi_) {
    rest_lo_ = std::max(0, rest_lo_ - 1), rest_hi_ = std::min(ny_, rest_hi_ + 1);
    rest_clo_ = std::max(0, rest_clo_ - 1), rest_chi_ = std::min(nx_, rest_chi_ + 1);
  }
  for (const Load& l : loads_) {
    if (l.value == 0) continue;
    const int j = static_cast<int>(l.node / rs_), i = static_cast<int>(l.node % rs_);
    const bool empty = rest_lo_ > rest_hi_;
    rest_lo_ = empty ? j : std::min(rest_lo_, j);
    rest_hi_ = empty ? j : std::max(rest_hi_, j);
    rest_clo_ = empty ? i : std::min(rest_clo_, i);
    rest_chi_ = empty ? i : std::max(rest_chi_, i);
  }
}

// Step n_ of a force_only window whose last step end_step_ is known: the contact point's displacement at
// end_step_ needs the nodes within r = end_step_ - n_ - 1 rows and columns of the contact nodes updated. The
// fused pass takes the rows and columns just outside what it steps to be at rest (no forces from there), so the
// first row and column it steps may come out wrong: one more on each side keeps those errors r + 1 away, where
// they reach the contact point after end_step_.
void Plate::Run::backward_cone(int& j_lo, int& j_hi, int& c_lo, int& c_hi) {
  const int r = static_cast<int>(std::min<int64_t>(end_step_ - n_ - 1, 1 << 29));
  j_lo = std::max(j_lo, cp_jlo_ - r - 1);
  j_hi = std::min(j_hi, cp_jhi_ + r + 1);
  c_lo = std::max(c_lo, cp_ilo_ - r - 1);
  c_hi = std::min(c_hi, cp_ihi_ + r + 1);
  shrunk_ = true;
}

// After step n of a force_only window with the ball apart and rising: the step at which the window will end
// (step()'s stop rule, the same floating-point test) unless it touches again.
void Plate::Run::predict_end(int64_t n) {
  const RunConfig& c = c_;
  const double quiet = std::max(c.quiet_after_contact_s, c.quiet_after_contact_fraction * (t_last_ - t_first_));
  int64_t m = n + 1;
  while (m < c.n_steps && !(m * c.dt_s - t_last_ > quiet)) ++m;
  end_step_ = m;
}

// The plate's step: the fused pass and then the loads (u_{n+1} += beta P, d += beta P); on energy steps the
// portable pass with the loads inside and the strain and kinetic energy accumulated (record sample q).
void Plate::Run::advance_plate(bool energy, int64_t q) {
  float* const u = u_;
  float* const db = db_;
  const size_t np = np_;
  const int64_t rs = rs_;
  if (!energy) {
    int j_lo = rest_lo_ - 1, j_hi = rest_hi_ + 1, c_lo = rest_clo_ - 1, c_hi = rest_chi_ + 1;
    const bool any = rest_lo_ <= rest_hi_;
    if (end_step_ >= 0) backward_cone(j_lo, j_hi, c_lo, c_hi);
    args_.j_lo = j_lo;
    args_.j_hi = j_hi;
    args_.b_lo = std::max(0, c_lo) / 16;
    args_.b_hi = any && c_lo <= c_hi && j_lo <= j_hi ? std::min(nx_, c_hi) / 16 : -1;
    detail::step_fast(args_);
    widen_cone();
    for (const Load& l : loads_) {
      const size_t k = static_cast<size_t>(l.field) * np + l.node;
      float* const dk = db + (l.node / rs) * 6 * rs + db_index(l.node % rs, l.field);
      const Real inc = dk[kDbBeta] * l.value;
      dk[0] += inc;
      u[k] += inc;
    }
    return;
  }
  double se = 0, ke = 0;
  size_t li = 0;
  const int rl = rl_;
  const Real alpha = alpha_;
  std::vector<Real>& frow = frow_;
  sweep<Real>(nx_, ny_, rs, p_.base_f_, p_.special_.data(), p_.row_start_.data(), u, u + np, u + 2 * np, acc_,
              [&](int j, const detail::RowAcc<Real>& a) {
                const int64_t row0 = static_cast<int64_t>(j) * rs;
                const Real* const p[3] = {a.pw, a.px, a.py};
                const Real* const qq[3] = {a.qw, a.qx, a.qy};
                for (int fld = 0; fld < 3; ++fld)
                  for (int i = 0; i < rl; ++i) {
                    frow[fld * rl + i] = detail::node_force(p[fld], qq[fld], i);
                    se += double(u[fld * np + row0 + i]) * frow[fld * rl + i];
                  }
                while (li < loads_.size() && loads_[li].node < row0 + rl) {
                  frow[loads_[li].field * rl + (loads_[li].node - row0)] -= loads_[li].value;
                  ++li;
                }
                for (int fld = 0; fld < 3; ++fld)
                  for (int i = 0; i < rl; ++i) {
                    const size_t k = fld * np + row0 + i;
                    float* const dk = db + static_cast<size_t>(j) * 6 * rs + db_index(i, fld);
                    const Real dn = alpha * dk[0] - dk[kDbBeta] * frow[fld * rl + i];
                    ke += double(mass_[k]) * dk[0] * dn;
                    dk[0] = dn;
                    u[k] += dn;
                  }
              });
  widen_cone();
  for (size_t r = 0; r < p_.spring_node_.size(); ++r) {  // spring energy at u_n (springs are part of K)
    const double wn = double(u[at(p_.spring_node_[r])]) - double(db[d_at(0, p_.spring_node_[r])]);
    se += p_.spring_k_[r] * wn * wn;
  }
  res_.energy[q * 4 + 0] = 0.5 * ke / (c_.dt_s * c_.dt_s);
  res_.energy[q * 4 + 1] = 0.5 * se;
}

// The sub-cycled patches: msub steps of dt / msub, the ring interpolated in time; returns their kinetic
// energy term (2 x KE x dts^2) on energy steps.
double Plate::Run::advance_patches(bool energy) {
  double ke_sub = 0;
  for (auto& gp : grids_) {
    PatchGrid& g = *gp;
    const size_t nr = g.ring_l.size(), ni = g.in_l.size();
    float* const lu = g.u.p;
    for (int f = 0; f < 3; ++f)  // u_{n+1} of the ring
      for (size_t r = 0; r < nr; ++r) g.ring1[f * nr + r] = u_[f * np_ + g.ring_g[r]];
    for (int k = 0; k < msub_; ++k) {
      const Real th = Real(k) / Real(msub_);
      for (int f = 0; f < 3; ++f)
        for (size_t r = 0; r < nr; ++r)
          lu[f * g.np + g.ring_l[r]] = g.ring0[f * nr + r] + th * (g.ring1[f * nr + r] - g.ring0[f * nr + r]);
      const bool energy_now = energy && k == 0;
      if (energy_now)
        for (int f = 0; f < 3; ++f)
          for (size_t r = 0; r < ni; ++r) g.d_old[f * ni + r] = g.db.p[g.d_of(g.in_l[r], f)];
      detail::step_fast(g.args);
      for (size_t l = 0; l < g.load_l.size(); ++l) {  // the step's loads at every sub-step (impulse dt P)
        float* const dk = g.db.p + g.d_of(g.load_l[l], g.load_f[l]);
        const Real inc = dk[kDbBeta] * g.load_v[l];
        dk[0] += inc;
        lu[g.load_f[l] * g.np + g.load_l[l]] += inc;
      }
      if (energy_now)
        for (int f = 0; f < 3; ++f)
          for (size_t r = 0; r < ni; ++r)
            ke_sub += double(g.mass[f * ni + r]) * g.d_old[f * ni + r] * g.db.p[g.d_of(g.in_l[r], f)];
    }
    for (int f = 0; f < 3; ++f)
      for (size_t r = 0; r < ni; ++r) u_[f * np_ + g.in_g[r]] = lu[f * g.np + g.in_l[r]];
  }
  return ke_sub;
}

void Plate::Run::check(int64_t n) const {
  const int every = c_.nan_check_every;
  if (every <= 0 || ((n + 1) % every != 0 && n + 1 != c_.n_steps)) return;
  if (std::isfinite(zb_) && std::isfinite(vb_) && detail::all_finite(u_, 3 * np_)) return;
  std::ostringstream os;
  os << "numerical blow-up (NaN/Inf) detected at step " << (n + 1) << " of " << c_.n_steps
     << " (t = " << (n + 1) * c_.dt_s * 1e6 << " us, checked every " << every << " steps, dt = " << c_.dt_s * 1e6
     << " us)";
  throw std::runtime_error(os.str());
}

bool Plate::Run::step(int64_t n) {
  const RunConfig& c = c_;
  const double t = n * c.dt_s;
  const int m = c.record_every;
  const int64_t q = n / m;
  const int r = static_cast<int>(n % m);
  const bool want_energy = c.record_energy && r == 0 && q < c.n_record;
  loads_.clear();
  double force = 0, delta = 0;
  n_ = n;
  if (c.ball.enabled) force = contact(t, delta);
  add_loads(t);
  if (q < c.n_record) record(q, r);
  patch_loads();
  advance_plate(want_energy, q);
  const double ke_sub = advance_patches(want_energy);
  if (want_energy) res_.energy[q * 4 + 0] += 0.5 * ke_sub / (dts_ * dts_);
  if (c.ball.enabled) {
    const double vb_old = vb_;
    vb_ += c.dt_s * (c.ball.g_m_s2 - force / c.ball.mass_kg);
    if (want_energy) {
      res_.energy[q * 4 + 2] = 0.5 * c.ball.mass_kg * vb_old * vb_;
      res_.energy[q * 4 + 3] = (delta > 0 ? 0.4 * c.ball.k_hertz * delta * delta * std::sqrt(delta) : 0.0) -
                               c.ball.mass_kg * c.ball.g_m_s2 * zb_;
    }
    zb_ += c.dt_s * vb_;
  }
  res_.steps_done = n + 1;
  check(n);
  const bool apart = c.stop_after_contact && t_first_ >= 0 && !in_contact_ && vb_ < 0;
  const bool over = apart && t - t_last_ > std::max(c.quiet_after_contact_s,
                                                    c.quiet_after_contact_fraction * (t_last_ - t_first_));
  if (end_step_ >= 0 && !over && (n >= end_step_ || in_contact_)) {  // a touch: the window goes on
    if (shrunk_) {  // ... past what the shrunk steps kept exact
      inexact_ = true;
      return false;
    }
    end_step_ = -1;
  }
  if (!over && apart && end_step_ < 0 && c.force_only && cone_) predict_end(n);
  return !over;
}

RunResult Plate::Run::result() {
  res_.ball_z_m = zb_;
  res_.ball_v_m_s = vb_;
  res_.contact_start_s = t_first_;
  res_.contact_end_s = t_last_;
  res_.w.resize(nn_);
  res_.bx.resize(nn_);
  res_.by.resize(nn_);
  const float nan = std::numeric_limits<float>::quiet_NaN();   // shrunk: nodes were left behind
  for (size_t k = 0; k < nn_; ++k) {
    res_.w[k] = shrunk_ ? nan : u_[at(k)];
    res_.bx[k] = shrunk_ ? nan : u_[np_ + at(k)];
    res_.by[k] = shrunk_ ? nan : u_[2 * np_ + at(k)];
  }
  return std::move(res_);
}

RunResult Plate::run(const RunConfig& c) const {
  DenormalGuard ftz;
  {
    Run r(*this, c);
    for (int64_t n = 0; n < c.n_steps; ++n)
      if (!r.step(n)) break;
    if (!r.inexact()) return r.result();
  }
  RunConfig whole = c;  // a touch after the backward cone shrank: the window again, every step whole
  whole.force_only = false;
  return run(whole);
}

}  // namespace impactsim