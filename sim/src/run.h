// Plate::Run, the state of one explicit run (Plate::run): set up in run.cpp, stepped in step.cpp.
#pragma once

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include "impactsim.h"
#include "stepper.h"
#include "sweep.h"

namespace impactsim {
namespace detail {

struct Bilinear {  // node indices and weights of a point inside the mesh
  int64_t node[4];
  double wt[4];
};

inline Bilinear locate(const PlateSpec& s, double x, double y) {
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

}  // namespace detail

// The helpers Plate::Run's setup (run.cpp) and step (step.cpp) both use, by their short names.
using detail::Accumulators;
using detail::AlignedFloats;
using detail::db_index;
using detail::kDbBeta;
using detail::need;
using detail::StepArgs;

// The state of one run. Layout: u = [w | bx | by], d = dt * v at half steps, likewise; rows padded to rs
// floats (64-byte aligned), so node k = j * rl + i lives at j * rs + i; d and beta block-interleaved
// (stepper.h db_index).
class Plate::Run {
 public:
  Run(const Plate& plate, const RunConfig& c);  // setup
  bool step(int64_t n);                         // one time step; false: the run is over (contact window)
  RunResult result();
  bool inexact() const { return inexact_; }     // force_only: the window outran the backward cone

 private:
  struct Load {  // an external load of the step: padded node, field, value
    int64_t node;
    int field;
    Real value;
  };
  // A sub-cycled patch (Plate::set_subcycling) with its ring of large-step nodes: a small grid of its own,
  // stepped msub times per step with dt / msub by the same stepper; the ring has beta = d = 0 there and is set
  // before each sub-step to u_n + theta (u_{n+1} - u_n), theta = k / msub. The patch's nodes get beta = d = 0
  // in the global pass, which so leaves them alone; they are copied back after the sub-steps.
  struct PatchGrid {
    const Patch* pt;
    int64_t rs;                  // local row stride (padded like the plate's)
    size_t np;                   // local field stride
    detail::AlignedFloats u, db, edge;   // local state, d and beta (db_index layout), edge arrays of the fused pass
    detail::Accumulators<Real> acc;      // portable pass
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
    detail::StepArgs args;
    PatchGrid(int lnx, int lny)
        : rs(16 * ((lnx + 15) / 16 + 1)), np(static_cast<size_t>(lny + 1) * rs), u(3 * np),
          db(static_cast<size_t>(lny + 1) * 6 * rs), edge(static_cast<size_t>(12) * rs), acc(lnx) {}
    size_t d_of(int64_t l, int f) const { return static_cast<size_t>((l / rs) * 6 * rs) + detail::db_index(l % rs, f); }
  };

  const Plate& p_;
  const RunConfig& c_;
  const size_t nn_;
  const int nx_, ny_, rl_;
  const int64_t rs_;
  const size_t np_;
  detail::AlignedFloats u_buf_, db_buf_, mass_buf_, edge_;
  float* const u_;
  float* const db_;  // d = dt * v and beta, see db_index
  float* const mass_;
  Real alpha_ = 0, alpha_s_ = 0;
  int msub_ = 1;
  double dts_ = 0;
  std::vector<std::unique_ptr<PatchGrid>> grids_;
  std::vector<detail::Segmented> sensors_;  // node indices into the padded rows
  Functional hat_;
  detail::Bilinear cp_{};
  int64_t cp_at_[4] = {0, 0, 0, 0};
  detail::Accumulators<Real> acc_;
  int64_t nblocks_;
  std::vector<int64_t> scaled_row_;
  std::vector<uint8_t> scaled_block_;
  std::vector<float> scale_;
  detail::StepArgs args_{};
  std::vector<Real> frow_;  // energy steps: explicit forces of one node row
  std::vector<Load> loads_;
  // The light cone: nodes that may be off rest lie in rows rest_lo_..rest_hi_ and columns rest_clo_..rest_chi_
  // (empty when lo > hi). A step moves a node's neighbours only, so the fused pass steps one row and column
  // more on each side (StepArgs j_lo, j_hi, b_lo, b_hi).
  // Tracked only without initial state and sub-cycled patches (cone_); else every row is stepped.
  bool cone_ = false;
  int rest_lo_ = 0, rest_hi_ = -1, rest_clo_ = 0, rest_chi_ = -1;  // rows, then columns (nodes)
  // The backward cone (RunConfig force_only, with cone_): once the ball has left, the window's last step
  // end_step_ is known (no further touch), and step n need only update the nodes within end_step_ - n - 1 rows
  // and columns of the contact nodes (rows cp_jlo_..cp_jhi_, columns cp_ilo_..cp_ihi_) for the contact point's
  // displacement to be exact up to end_step_. shrunk_: a step was shrunk; inexact_: the window went on past
  // end_step_ after that (a new touch), so its force history is not the whole run's.
  int64_t n_ = 0, end_step_ = -1;
  bool shrunk_ = false, inexact_ = false;
  int cp_jlo_ = 0, cp_jhi_ = 0, cp_ilo_ = 0, cp_ihi_ = 0;
  RunResult res_;
  double zb_ = 0, vb_ = 0;  // ball: position (down = into the plate), velocity at half step
  bool in_contact_ = false;
  double t_first_ = -1, t_last_ = -1;

  size_t at(int64_t k) const { return static_cast<size_t>((k / rl_) * rs_ + k % rl_); }
  size_t d_at(int f, int64_t k) const { return static_cast<size_t>((k / rl_) * 6 * rs_) + detail::db_index(k % rl_, f); }
  void validate() const;
  void init_state();
  void init_patch(const Patch& pt);
  void init_scale_tables();
  void init_outputs();
  double contact(double t, double& delta);
  void add_loads(double t);
  void record(int64_t q, int r);
  void patch_loads();
  void advance_plate(bool energy, int64_t q);
  void widen_cone();
  void backward_cone(int& j_lo, int& j_hi, int& c_lo, int& c_hi);
  void predict_end(int64_t n);
  double advance_patches(bool energy);
  void check(int64_t n) const;
};

}  // namespace impactsim
