// Plate::Run's setup: the run's configuration checked, the padded state, d and beta, the sub-cycled patches'
// grids, the scale tables of the fused pass, the sensors and the result's arrays.
#include <algorithm>
#include <cmath>
#include <memory>
#include <stdexcept>
#include <string>

#include "run.h"

namespace impactsim {

void Plate::Run::validate() const {
  const RunConfig& c = c_;
  need(c.dt_s > 0 && std::isfinite(c.dt_s), "time step must be positive");
  need(c.n_steps >= 0, "n_steps must be >= 0");
  need(c.record_every >= 1, "record_every must be >= 1");
  need(c.load_delay_s >= 0, "load_delay_s must be >= 0");
  need(c.load_lowpass_s >= 0 && std::isfinite(c.load_lowpass_s), "load_lowpass_s must be finite and >= 0");
  need(c.n_record >= 0, "n_record must be >= 0");
  need(c.load.node.size() == c.load.wx.size() && c.load.node.size() == c.load.wy.size(),
       "functional arrays differ in size");
  for (const auto& fn : c.sensors) {
    need(fn.node.size() == fn.wx.size() && fn.node.size() == fn.wy.size(), "functional arrays differ in size");
    for (auto k : fn.node) need(k >= 0 && static_cast<size_t>(k) < nn_, "functional node out of range");
  }
  for (auto k : c.load.node) need(k >= 0 && static_cast<size_t>(k) < nn_, "load node out of range");
  if (c.ball.enabled) need(c.ball.mass_kg > 0 && c.ball.k_hertz > 0, "ball mass and Hertz constant must be positive");
  for (size_t r = 0; r < p_.spring_node_.size(); ++r)
    need(p_.spring_c_[r] * c.dt_s <= p_.s_.mass_w[static_cast<size_t>(p_.spring_node_[r])],
         "node dashpot too strong for the explicit step: c_w dt / m_w must be <= 1");
}

Plate::Run::Run(const Plate& plate, const RunConfig& c)
    : p_(plate), c_(c), nn_(static_cast<size_t>(plate.nodes())), nx_(plate.s_.nx), ny_(plate.s_.ny),
      rl_(nx_ + 1), rs_(16 * ((nx_ + 15) / 16 + 1)), np_(static_cast<size_t>(ny_ + 1) * rs_), u_buf_(3 * np_),
      db_buf_(static_cast<size_t>(ny_ + 1) * 6 * rs_), mass_buf_(3 * np_), edge_(static_cast<size_t>(12) * rs_),
      u_(u_buf_.p), db_(db_buf_.p), mass_(mass_buf_.p), acc_(nx_), nblocks_((nx_ + 15) / 16),
      frow_(static_cast<size_t>(3) * rl_), vb_(c.ball.v0_m_s) {
  validate();
  if (c.ball.enabled) cp_ = detail::locate(p_.s_, c.ball.x_m, c.ball.y_m);
  init_state();
  // sub-cycled patches: msub sub-steps of dt / msub
  msub_ = (!p_.patches_.empty() && p_.fine_dt_ > 0)
              ? std::max(1, static_cast<int>(std::ceil(c.dt_s / p_.fine_dt_ - 1e-9))) : 1;
  dts_ = c.dt_s / msub_;
  const double cds = 0.5 * p_.s_.damping_per_s * dts_;
  alpha_s_ = Real((1 - cds) / (1 + cds));
  if (msub_ > 1)
    for (const Patch& pt : p_.patches_) init_patch(pt);
  init_outputs();
  init_scale_tables();
  cone_ = msub_ == 1 && c.w0.empty() && c.bx0.empty() && c.by0.empty() && c.vw0.empty() && c.vbx0.empty() &&
          c.vby0.empty();
  if (!cone_) rest_lo_ = 0, rest_hi_ = ny_, rest_clo_ = 0, rest_chi_ = nx_;
  args_ = StepArgs{nx_, ny_, rs_, np_, &p_.base_f_, p_.special_.data(), p_.row_start_.data(), u_, db_, alpha_,
                   &acc_, edge_.p, scaled_row_.data(), scaled_block_.data(), scale_.data(), nblocks_};
}

// Initial state, d and beta = dt^2 / ((1 + cd) m) (0 at fixed dofs), the masses (energy steps).
void Plate::Run::init_state() {
  const RunConfig& c = c_;
  auto load_init = [&](const std::vector<double>& src, size_t field, double scale, float* dst, const char* name) {
    if (src.empty()) return;
    need(src.size() == nn_, std::string(name) + " needs one value per node");
    for (size_t k = 0; k < nn_; ++k)
      dst[dst == u_ ? field * np_ + at(k) : d_at(int(field), k)] = Real(scale * src[k]);
  };
  load_init(c.w0, 0, 1.0, u_, "w0");
  load_init(c.bx0, 1, 1.0, u_, "bx0");
  load_init(c.by0, 2, 1.0, u_, "by0");
  load_init(c.vw0, 0, c.dt_s, db_, "vw0");
  load_init(c.vbx0, 1, c.dt_s, db_, "vbx0");
  load_init(c.vby0, 2, c.dt_s, db_, "vby0");
  const double cd = 0.5 * p_.s_.damping_per_s * c.dt_s;
  alpha_ = Real((1 - cd) / (1 + cd));
  for (size_t k = 0; k < nn_; ++k) {
    const size_t o = at(k);
    const Real inv_m[3] = {p_.inv_mw_[k], p_.inv_mr_[k], p_.inv_mr_[nn_ + k]};
    const Real m_k[3] = {Real(p_.s_.mass_w[k]), Real(p_.s_.mass_r[k]), Real(p_.s_.mass_r[k])};
    for (int f = 0; f < 3; ++f) {
      db_[d_at(f, k) + kDbBeta] = Real(c.dt_s * c.dt_s / (1 + cd) * inv_m[f]);
      mass_[f * np_ + o] = m_k[f];
      if (inv_m[f] == 0) u_[f * np_ + o] = db_[d_at(f, k)] = 0;  // fixed dofs stay at zero
    }
  }
}

// One sub-cycled patch's grid: its special elements (corrections for the portable pass, per-block scale
// tables for the fused pass), its ring and patch nodes, their state, d and beta at dt / msub.
void Plate::Run::init_patch(const Patch& pt) {
  const int lnx = pt.ei1 - pt.ei0, lny = pt.ej1 - pt.ej0;  // elements of the local grid
  grids_.push_back(std::make_unique<PatchGrid>(lnx, lny));
  PatchGrid& g = *grids_.back();
  g.pt = &pt;
  const int64_t lrs = g.rs;
  const int64_t nb = (lnx + 15) / 16;
  g.row_start.assign(static_cast<size_t>(lny) + 1, 0);
  g.scaled_row.assign(static_cast<size_t>(lny), -1);
  for (int lj = 0, n_rows = 0; lj < lny; ++lj) {
    const int j = pt.ej0 + lj;
    g.row_start[lj] = static_cast<int64_t>(g.special.size());
    bool any = false;
    for (int64_t k = p_.row_start_[j]; k < p_.row_start_[j + 1]; ++k) {
      if (p_.special_[k].i < pt.ei0 || p_.special_[k].i >= pt.ei1) continue;
      g.special.push_back(p_.special_[k]);
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
      const size_t e = static_cast<size_t>(j) * nx_ + pt.ei0 + li;
      ds[li] = Real(p_.s_.d_elem[e] / p_.d0_);
      ss[li] = Real(p_.s_.s_elem[e] / p_.s0_);
      if (p_.s_.d_elem[e] != p_.d0_ || p_.s_.s_elem[e] != p_.s0_) g.scaled_block[(n_rows - 1) * nb + li / 16] = 1;
    }
  }
  g.row_start[lny] = static_cast<int64_t>(g.special.size());
  const double cds = 0.5 * p_.s_.damping_per_s * dts_;
  for (int lj = 0; lj <= lny; ++lj)
    for (int li = 0; li <= lnx; ++li) {
      const int i = pt.ei0 + li, j = pt.ej0 + lj;
      const int64_t k = static_cast<int64_t>(j) * rl_ + i, gl = static_cast<int64_t>(at(k)), ll = lj * lrs + li;
      for (int f = 0; f < 3; ++f) g.u.p[f * g.np + ll] = u_[f * np_ + gl];
      if (!p_.sub_[static_cast<size_t>(k)]) {
        g.ring_l.push_back(ll);
        g.ring_g.push_back(gl);
        continue;
      }
      g.in_l.push_back(ll);
      g.in_g.push_back(gl);
      const Real inv_m[3] = {p_.inv_mw_[k], p_.inv_mr_[k], p_.inv_mr_[nn_ + k]};
      const std::vector<double>* v0[3] = {&c_.vw0, &c_.vbx0, &c_.vby0};
      for (int f = 0; f < 3; ++f) {
        float* const dl = g.db.p + lj * 6 * lrs + db_index(li, f);
        dl[kDbBeta] = Real(dts_ * dts_ / (1 + cds) * inv_m[f]);
        if (!v0[f]->empty() && inv_m[f] != 0) dl[0] = Real(dts_ * (*v0[f])[k]);
        db_[d_at(f, k)] = db_[d_at(f, k) + kDbBeta] = 0;
      }
    }
  const size_t nr = g.ring_l.size(), ni = g.in_l.size();
  g.ring0.assign(3 * nr, Real(0));
  g.ring1.assign(3 * nr, Real(0));
  g.d_old.assign(3 * ni, Real(0));
  g.mass.resize(3 * ni);
  for (int f = 0; f < 3; ++f)
    for (size_t r = 0; r < ni; ++r) g.mass[f * ni + r] = mass_[f * np_ + g.in_g[r]];
  g.args = StepArgs{lnx, lny, lrs, g.np, &p_.base_f_, g.special.data(), g.row_start.data(), g.u.p, g.db.p,
                    alpha_s_, &g.acc, g.edge.p, g.scaled_row.data(), g.scaled_block.data(), g.scale.data(), nb};
}

// Rows holding elements unlike the base one: stiffness ratios per element, flags per 16-element block.
void Plate::Run::init_scale_tables() {
  scaled_row_.assign(static_cast<size_t>(ny_), -1);
  for (int j = 0, n_rows = 0; j < ny_; ++j) {
    if (p_.row_start_[j + 1] == p_.row_start_[j]) continue;
    scaled_row_[j] = n_rows++;
    scaled_block_.resize(static_cast<size_t>(n_rows * nblocks_), 0);
    scale_.resize(static_cast<size_t>(2 * n_rows * rs_), 1.0f);
    float* ds = scale_.data() + 2 * (n_rows - 1) * rs_;
    float* ss = ds + rs_;
    for (int i = 0; i < nx_; ++i) {
      const size_t e = static_cast<size_t>(j) * nx_ + i;
      ds[i] = Real(p_.s_.d_elem[e] / p_.d0_);
      ss[i] = Real(p_.s_.s_elem[e] / p_.s0_);
      if (p_.s_.d_elem[e] != p_.d0_ || p_.s_.s_elem[e] != p_.s0_) scaled_block_[(n_rows - 1) * nblocks_ + i / 16] = 1;
    }
  }
}

// Sensors and the hat load on the padded rows, the contact point's nodes, the result's arrays.
void Plate::Run::init_outputs() {
  for (Functional fn : c_.sensors) {
    for (auto& k : fn.node) k = static_cast<int64_t>(at(k));
    sensors_.emplace_back(fn);
  }
  hat_ = c_.load;
  for (auto& k : hat_.node) k = static_cast<int64_t>(at(k));
  if (c_.ball.enabled) {
    cp_jlo_ = cp_ilo_ = 1 << 30;
    cp_jhi_ = cp_ihi_ = -1;
    for (int a = 0; a < 4; ++a) {
      cp_at_[a] = static_cast<int64_t>(at(cp_.node[a]));
      const int j = static_cast<int>(cp_.node[a] / rl_), i = static_cast<int>(cp_.node[a] % rl_);
      cp_jlo_ = std::min(cp_jlo_, j), cp_jhi_ = std::max(cp_jhi_, j);
      cp_ilo_ = std::min(cp_ilo_, i), cp_ihi_ = std::max(cp_ihi_, i);
    }
  }
  const int64_t nrec = c_.n_record;
  res_.sensors.assign(sensors_.size() * nrec, 0.0);
  if (c_.record_field) res_.field.assign(static_cast<size_t>(nrec) * nn_, 0.0f);
  if (c_.record_energy) res_.energy.assign(static_cast<size_t>(nrec) * 4, 0.0);
  if (c_.ball.enabled) res_.force_n.reserve(static_cast<size_t>(c_.n_steps));
}

}  // namespace impactsim
