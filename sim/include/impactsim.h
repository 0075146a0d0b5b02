// impactsim: explicit finite-element dynamics of a rectangular Mindlin-Reissner plate struck by a rigid
// Hertzian ball, sensed by surface-bonded PZT discs.
//
// Pieces (each a named part of the code, see docs/method.md):
//   Mesh       structured nx x ny grid of 4-node rectangles, node (i, j) at (i*hx_m, j*hy_m), row-major.
//   Element    MITC4 Mindlin-Reissner quad: bilinear w, beta_x, beta_y (u = z beta_x, v = z beta_y);
//              bending integrated exactly (2x2 Gauss, written as centre + hourglass terms), transverse shear
//              by assumed natural strains tied at edge midpoints (MITC4), so no shear locking and no
//              spurious zero-energy modes.
//   Mass       lumped: translational mass_w, rotary mass_r per node (may include disc mass / scaling).
//   Stepper    central differences with mass-proportional damping: a = M^-1 (P - F) - D_s v; optionally the
//              disc patches sub-cycled (m sub-steps of dt / m, see Plate::set_subcycling).
//   Contact    rigid sphere, Hertz F = k delta^1.5, delta = z_ball - w(x_c); bilinear load distribution.
//   Sensors    linear functionals of the rotations (disc-averaged surface strain, Python builds weights);
//              output sampled on a record grid with hat (linear B-spline) weights.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace impactsim {

int version();

// The plate's material as ratios to the per-element scalars of PlateSpec: element e's bending matrix (moments
// M_xx, M_yy, M_xy from the curvatures beta_x,x, beta_y,y, beta_x,y + beta_y,x) is
// d_elem[e] [[d11, d12, d16], [d12, d22, d26], [d16, d26, d66]] and its transverse shear matrix (Q_x, Q_y from
// gamma_xz, gamma_yz) s_elem[e] [[sxx, sxy], [sxy, syy]], in the plate's x, y axes. Isotropic (Poisson
// ratio nu): d11 = d22 = 1, d12 = nu, d66 = (1 - nu) / 2, sxx = syy = 1, the couplings d16, d26, sxy zero.
struct Material {
  double d11 = 1, d12 = 0.3, d22 = 1, d66 = 0.35, d16 = 0, d26 = 0;
  double sxx = 1, syy = 1, sxy = 0;
  static Material isotropic(double nu) {
    Material m;
    m.d12 = nu;
    m.d66 = (1 - nu) / 2;
    return m;
  }
  // bending-twisting (d16, d26) or shear (sxy) coupling: material axes not along x, y
  bool coupled() const { return d16 != 0 || d26 != 0 || sxy != 0; }
};

namespace detail {
// Constants of one MITC4 rectangle (see src/element.h): linear in the bending stiffness D and the shear
// stiffness S, so K(D, S) - K(D0, S0) = K(D - D0, S - S0) for one material.
template <typename Real>
struct Coef {  // element constants for bending stiffness d x material and shear stiffness s x material
  Real ka, kb;                // 1/a, 1/b
  Real sa, sa3;               // shear along x: S_xx ab / 4, S_xx ab / 12
  Real sb, sb3;               // shear along y: S_yy ab / 4, S_yy ab / 12
  Real b11, b12, b22;         // bending centre: g1x = b11 C1x + b12 C2y, g2y = b12 C1x + b22 C2y
  Real c11, c12, c22;         // twist: g2x += c22 C2x + c12 C1y, g1y += c12 C2x + c11 C1y
  Real h3x, h3y;              // hourglass: g3x = h3x C3x, g3y = h3y C3y
  // couplings (zero unless Material::coupled): shear qx0 += sc (gamma_yz part), qy0 += sc (gamma_xz part);
  // bending g1x += e16 C2x + f16 C1y, g2y += f26 C2x + e26 C1y, twist g2x += e16 C1x + f26 C2y,
  // g1y += f16 C1x + e26 C2y; hourglass g3x += h3c C3y, g3y += h3c C3x
  Real sc, e16, f16, e26, f26, h3c;
  bool coupled = false;
  Coef() = default;
  Coef(double hx, double hy, const Material& m, double d, double s) {
    const double a = hx / 2, b = hy / 2, h = m.d66;
    ka = Real(1 / a);
    kb = Real(1 / b);
    sa = Real(s * m.sxx * a * b / 4);
    sa3 = Real(s * m.sxx * a * b / 12);
    sb = Real(s * m.syy * a * b / 4);
    sb3 = Real(s * m.syy * a * b / 12);
    b11 = Real(d * m.d11 * b / (4 * a));
    b12 = Real(d * m.d12 / 4);
    b22 = Real(d * m.d22 * a / (4 * b));
    c11 = Real(d * h * b / (4 * a));
    c12 = Real(d * h / 4);
    c22 = Real(d * h * a / (4 * b));
    h3x = Real(d * a * b / 12 * (h / (b * b) + m.d11 / (a * a)));
    h3y = Real(d * a * b / 12 * (m.d22 / (b * b) + h / (a * a)));
    sc = Real(s * m.sxy * a * b / 4);
    e16 = Real(d * m.d16 / 4);
    f16 = Real(d * m.d16 * b / (4 * a));
    e26 = Real(d * m.d26 / 4);
    f26 = Real(d * m.d26 * a / (4 * b));
    h3c = Real(d * a * b / 12 * (m.d26 / (b * b) + m.d16 / (a * a)));
    coupled = m.coupled();
  }
};
}  // namespace detail

using Real = float;  // state precision (vectorised); energies and outputs are accumulated in double

struct PlateSpec {
  int nx = 0, ny = 0;                // elements along x and y
  double hx_m = 0, hy_m = 0;         // element size
  double nu = 0.3;                   // Poisson ratio (bending) of the isotropic material
  std::vector<double> material;      // empty: isotropic (nu); else Material's d11, d12, d22, d66, d16, d26,
                                     // sxx, syy, sxy (ratios to d_elem, s_elem)
  std::vector<double> d_elem;        // bending stiffness D per element [N m] (size nx*ny)
  std::vector<double> s_elem;        // shear stiffness kappa G t per element [N/m] (size nx*ny)
  std::vector<double> mass_w;        // lumped translational mass per node [kg]
  std::vector<double> mass_r;        // lumped rotary inertia per node [kg m^2]
  std::vector<uint8_t> fix_w, fix_bx, fix_by;  // 1 = dof held at zero (size nodes)
  double damping_per_s = 0;          // D_s
};

// A sparse linear functional over the rotation dofs: value = sum wx[k] beta_x[node[k]] + wy[k] beta_y[node[k]].
struct Functional {
  std::vector<int64_t> node;
  std::vector<double> wx, wy;
};

struct Ball {
  bool enabled = false;
  double x_m = 0, y_m = 0;       // contact point
  double mass_kg = 0;
  double k_hertz = 0;            // F = k delta^1.5 [N / m^1.5]
  double v0_m_s = 0;             // velocity at first touch (into the plate)
  double g_m_s2 = 9.81;
};

struct RunConfig {
  double dt_s = 0;
  int64_t n_steps = 0;
  int record_every = 1;          // record grid spacing in steps (Delta = record_every * dt)
  int64_t n_record = 0;          // record samples (hat weights centred on q * Delta, q = 0..n_record-1)
  Ball ball;
  // Prescribed load: load_functional (as forces/moments on beta dofs) times the hat phi_1(t) of unit peak
  // centred at t = Delta (reciprocity runs).
  bool hat_load = false;
  Functional load;
  double load_delay_s = 0;       // the hat centred at Delta + load_delay_s (>= 0): a disc's sub-sample delay
  // > 0: the hat through a first-order low-pass of this time constant (exact in continuous time): a disc's bond
  // transferring the plate's strain to the disc (docs/method.md, "The discs' bond"); 0: the hat itself
  double load_lowpass_s = 0;
  std::vector<Functional> sensors;  // recorded on the record grid
  bool record_field = false;        // record w of every node on the record grid (reciprocity)
  bool record_energy = false;       // energy at each record sample
  bool stop_after_contact = false;  // contact-window mode: stop once the ball has clearly left
  double quiet_after_contact_s = 100e-6;
  // ... for at least quiet_after_contact_s and this fraction of the contact's own duration (first to last touch)
  double quiet_after_contact_fraction = 1.0;
  // contact-window mode, only the force history wanted: once the ball has left, the nodes that cannot reach the
  // contact point before the window's end are no longer stepped (the final state w, bx, by is then NaN); the
  // force history is the same bit for bit (a touch that makes the window longer: the run is made again whole)
  bool force_only = false;
  int nan_check_every = 50;
  // initial state (optional; empty = at rest)
  std::vector<double> w0, bx0, by0, vw0, vbx0, vby0;
};

struct RunResult {
  int64_t steps_done = 0;
  std::vector<double> sensors;      // [n_sensors * n_record]
  std::vector<float> field;         // [n_record * nodes]
  std::vector<double> force_n;      // contact force per step
  std::vector<double> energy;       // [n_record * 4]: plate kinetic, plate strain, ball kinetic, contact
  double ball_z_m = 0, ball_v_m_s = 0;
  double contact_start_s = -1, contact_end_s = -1;
  int contacts = 0;                 // number of separate touches
  std::vector<double> w, bx, by;    // final displacement state
};

class Plate {
 public:
  explicit Plate(PlateSpec spec);
  const PlateSpec& spec() const { return s_; }
  int64_t nodes() const { return static_cast<int64_t>(s_.nx + 1) * (s_.ny + 1); }
  int64_t elements() const { return static_cast<int64_t>(s_.nx) * s_.ny; }

  // f = K u (internal nodal forces, node springs included), boundary conditions not applied (fixed dofs are
  // handled by the stepper).
  void internal_force(const Real* w, const Real* bx, const Real* by, Real* fw, Real* fbx, Real* fby) const;
  // The same kernel in double precision (for assembling K in validation tests).
  void internal_force_double(const double* w, const double* bx, const double* by, double* fw, double* fbx,
                             double* fby) const;
  double strain_energy(const Real* w, const Real* bx, const Real* by) const;
  // Largest eigenvalue omega_max^2 of M^-1 K over the free dofs (the explicit stability limit is
  // dt = 2 / omega_max), by Lanczos with the stepper's kernel; iterates until the largest Ritz value changes
  // by less than rtol (relative) between checks every 5 iterations, at most max_iter. A Ritz value never
  // exceeds the eigenvalue: callers keep a safety factor.
  // coarse: the sub-cycled dofs (set_subcycling) held fixed, i.e. the limit of the large step.
  double max_eigenvalue(int max_iter = 300, double rtol = 1e-7, bool coarse = false) const;

  // Sub-cycling (nodal-partition multi-time-step central differences, Belytschko-Yen-Mullen): the nodes of
  // the elements unlike the base one (the discs), dilated by `layer` nodes and grown to rectangular
  // patches, are stepped m times per step with dt / m, m = ceil(dt / fine_dt_s); over the sub-steps the
  // patch's outer ring (large-step nodes) moves linearly from u_n to u_{n+1}. A run with dt <= fine_dt_s
  // is the plain single-step scheme. fine_dt_s <= 0 turns it off.
  void set_subcycling(double fine_dt_s, int layer);
  int64_t subcycled_nodes() const;
  double fine_dt() const { return fine_dt_; }

  // Elastic support: a spring k_w [N/m] and a dashpot c_w [N s/m] per node on w (e.g. the plate's edge nodes
  // resting on a rubber rim, the rim's stiffness per length x the node's share of the edge). The springs are
  // part of K (internal_force, strain_energy, max_eigenvalue); the dashpots act on the velocity at the half
  // step before (explicit: c_w dt / m_w must stay well below 1, checked by run()). Empty vectors = none. Not
  // allowed on sub-cycled or w-held nodes.
  void set_node_springs(std::vector<double> k_w, std::vector<double> c_w);
  const std::vector<int64_t>& spring_nodes() const { return spring_node_; }
  double spring_k(size_t r) const { return spring_k_[r]; }

  // One explicit run: Run's setup (validated config, padded state, sub-cycled patches, sensors), then its
  // step per time step (contact and loads, outputs on the record grid, the central-difference update), then
  // its result.
  RunResult run(const RunConfig& cfg) const;

  // Elements whose (D, S) differ from the base (most common) pair: stepped as the base element plus
  // K(D - D0, S - S0).
  struct Special {
    int i;  // column; the row is given by row_start()
    detail::Coef<float> kf;
    detail::Coef<double> kd;
  };
  const std::vector<Special>& special() const { return special_; }
  const std::vector<int64_t>& row_start() const { return row_start_; }  // special()[row_start[j]..row_start[j+1])

 private:
  class Run;  // the state of one run (src/run.h)
  PlateSpec s_;
  detail::Coef<Real> coef_f(double d, double s) const;
  detail::Coef<double> coef_d(double d, double s) const;
  Material material_;
  double d0_ = 0, s0_ = 0;             // base element
  detail::Coef<Real> base_f_;
  detail::Coef<double> base_d_;
  std::vector<Special> special_;
  std::vector<int64_t> row_start_;
  std::vector<Real> inv_mw_, inv_mr_;  // 0 at fixed dofs
  struct Patch {  // sub-cycled nodes i0..i1 x j0..j1; with its ring of large-step nodes, ei0..ei1 x ej0..ej1
    int i0, i1, j0, j1, ei0, ei1, ej0, ej1;
  };
  std::vector<Patch> patches_;
  std::vector<uint8_t> sub_;           // per node: 1 if sub-cycled
  double fine_dt_ = 0;
  std::vector<int64_t> spring_node_;   // nodes with a spring or dashpot on w (set_node_springs)
  std::vector<double> spring_k_, spring_c_;
};

// 12 x 12 stiffness of one element (dof order: node-major w, bx, by for nodes 1..4 counter-clockwise from
// (-,-)), built by probing the same kernel the stepper uses.
std::vector<double> element_stiffness(double hx_m, double hy_m, double d, double nu, double s,
                                      const std::vector<double>& material = {});

}  // namespace impactsim
