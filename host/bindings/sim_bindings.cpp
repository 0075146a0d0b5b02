// Python binding of the finite-element simulator (sim/). Only glue: array plumbing, GIL release.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <stdexcept>
#include <vector>

#include "impactsim.h"

namespace nb = nanobind;
using namespace nb::literals;
namespace is = impactsim;

using InD = nb::ndarray<const double, nb::c_contig, nb::device::cpu>;
using InI = nb::ndarray<const int64_t, nb::c_contig, nb::device::cpu>;
using InU8 = nb::ndarray<const uint8_t, nb::c_contig, nb::device::cpu>;
using InF = nb::ndarray<const float, nb::c_contig, nb::device::cpu>;

namespace {

template <typename T, typename A>
std::vector<T> vec(const A& a) {
  return std::vector<T>(a.data(), a.data() + a.size());
}

template <typename T>
nb::ndarray<nb::numpy, T> to_numpy(std::vector<T>&& v, std::vector<size_t> shape) {
  auto* heap = new std::vector<T>(std::move(v));
  nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
  return nb::ndarray<nb::numpy, T>(heap->data(), shape.size(), shape.data(), owner);
}

is::Functional functional(nb::handle t) {
  // (node int64[k], wx float64[k], wy float64[k])
  auto tup = nb::cast<nb::tuple>(t);
  if (tup.size() != 3) throw std::invalid_argument("a functional is (node, wx, wy)");
  is::Functional f;
  f.node = vec<int64_t>(nb::cast<InI>(tup[0]));
  f.wx = vec<double>(nb::cast<InD>(tup[1]));
  f.wy = vec<double>(nb::cast<InD>(tup[2]));
  return f;
}

std::vector<double> opt(nb::handle h) {
  if (h.is_none()) return {};
  return vec<double>(nb::cast<InD>(h));
}

}  // namespace

NB_MODULE(_sim, m) {
  m.doc() = "impactsense finite-element simulator (sim/): MITC4 Mindlin plate, Hertz ball, PZT functionals";
  m.def("version", &is::version);

  nb::class_<is::Plate>(m, "Plate")
      .def(
          "__init__",
          [](is::Plate* self, int nx, int ny, double hx_m, double hy_m, double nu, InD d_elem, InD s_elem,
             InD mass_w, InD mass_r, InU8 fix_w, InU8 fix_bx, InU8 fix_by, double damping_per_s,
             nb::object material) {
            is::PlateSpec s;
            s.nx = nx;
            s.ny = ny;
            s.hx_m = hx_m;
            s.hy_m = hy_m;
            s.nu = nu;
            s.d_elem = vec<double>(d_elem);
            s.s_elem = vec<double>(s_elem);
            s.mass_w = vec<double>(mass_w);
            s.mass_r = vec<double>(mass_r);
            s.fix_w = vec<uint8_t>(fix_w);
            s.fix_bx = vec<uint8_t>(fix_bx);
            s.fix_by = vec<uint8_t>(fix_by);
            s.damping_per_s = damping_per_s;
            s.material = opt(material);
            new (self) is::Plate(std::move(s));
          },
          "nx"_a, "ny"_a, "hx_m"_a, "hy_m"_a, "nu"_a, "d_elem"_a, "s_elem"_a, "mass_w"_a, "mass_r"_a,
          "fix_w"_a, "fix_bx"_a, "fix_by"_a, "damping_per_s"_a, "material"_a = nb::none(),
          "material: None (isotropic, nu) or float64[9] ratios d11, d12, d22, d66, d16, d26, sxx, syy, sxy: element "
          "e's bending matrix is d_elem[e] x [[d11, d12, d16], [d12, d22, d26], [d16, d26, d66]], its shear "
          "matrix s_elem[e] x [[sxx, sxy], [sxy, syy]] (plate axes).")
      .def_prop_ro("nodes", &is::Plate::nodes)
      .def_prop_ro("elements", &is::Plate::elements)
      .def(
          "internal_force",
          [](const is::Plate& p, InF u) {
            const size_t nn = static_cast<size_t>(p.nodes());
            if (u.size() != 3 * nn) throw std::invalid_argument("u must be float32 [3, nodes] (w, bx, by)");
            std::vector<float> f(3 * nn);
            p.internal_force(u.data(), u.data() + nn, u.data() + 2 * nn, f.data(), f.data() + nn,
                             f.data() + 2 * nn);
            return to_numpy(std::move(f), {3, nn});
          },
          "u"_a, "f = K u for u float32 [3, nodes] (w, beta_x, beta_y); no boundary conditions applied.")
      .def(
          "max_eigenvalue",
          [](const is::Plate& p, int max_iter, double rtol, bool coarse) {
            nb::gil_scoped_release release;
            return p.max_eigenvalue(max_iter, rtol, coarse);
          },
          "max_iter"_a = 300, "rtol"_a = 1e-7, "coarse"_a = false,
          "omega_max^2 of M^-1 K over the free dofs (Lanczos with the stepper's kernel); dt_crit = 2 / omega_max. "
          "coarse: the sub-cycled dofs held fixed (the large step's limit).")
      .def("set_subcycling", &is::Plate::set_subcycling, "fine_dt_s"_a, "layer"_a = 1,
           "Step the disc patches (elements unlike the base one, dilated by layer nodes) with dt / m, "
           "m = ceil(dt / fine_dt_s), the rest with dt; fine_dt_s <= 0 turns it off. Call before any run.")
      .def(
          "set_node_springs",
          [](is::Plate& p, InD k_w, InD c_w) { p.set_node_springs(vec<double>(k_w), vec<double>(c_w)); },
          "k_w"_a, "c_w"_a,
          "A spring k_w [N/m] and a dashpot c_w [N s/m] on w at every node (zeros: none), e.g. an elastic rim "
          "along the edges. The springs are part of K; the dashpots act on the half-step velocity.")
      .def_prop_ro("spring_nodes", [](const is::Plate& p) { return p.spring_nodes(); })
      .def_prop_ro("subcycled_nodes", &is::Plate::subcycled_nodes)
      .def_prop_ro("fine_dt_s", &is::Plate::fine_dt)
      .def(
          "internal_force_double",
          [](const is::Plate& p, InD u) {
            const size_t nn = static_cast<size_t>(p.nodes());
            if (u.size() != 3 * nn) throw std::invalid_argument("u must be float64 [3, nodes] (w, bx, by)");
            std::vector<double> f(3 * nn);
            p.internal_force_double(u.data(), u.data() + nn, u.data() + 2 * nn, f.data(), f.data() + nn,
                                    f.data() + 2 * nn);
            return to_numpy(std::move(f), {3, nn});
          },
          "u"_a, "internal_force with the same kernel in double precision (assembling K for checks).")
      .def(
          "run",
          [](const is::Plate& p, double dt_s, int64_t n_steps, int record_every, int64_t n_record,
             nb::object ball, nb::object load, nb::list sensors, bool record_field, bool record_energy,
             bool stop_after_contact, double quiet_after_contact_s, double quiet_after_contact_fraction,
             bool force_only, int nan_check_every, double load_delay_s, double load_lowpass_s, nb::object w0,
             nb::object bx0, nb::object by0, nb::object vw0, nb::object vbx0, nb::object vby0) {
            is::RunConfig c;
            c.dt_s = dt_s;
            c.n_steps = n_steps;
            c.record_every = record_every;
            c.n_record = n_record;
            if (!ball.is_none()) {
              // (x_m, y_m, mass_kg, k_hertz, v0_m_s, g_m_s2)
              auto b = nb::cast<std::vector<double>>(ball);
              if (b.size() != 6) throw std::invalid_argument("ball is (x_m, y_m, mass_kg, k_hertz, v0, g)");
              c.ball.enabled = true;
              c.ball.x_m = b[0];
              c.ball.y_m = b[1];
              c.ball.mass_kg = b[2];
              c.ball.k_hertz = b[3];
              c.ball.v0_m_s = b[4];
              c.ball.g_m_s2 = b[5];
            }
            if (!load.is_none()) {
              c.hat_load = true;
              c.load = functional(load);
            }
            c.load_delay_s = load_delay_s;
            c.load_lowpass_s = load_lowpass_s;
            for (auto s : sensors) c.sensors.push_back(functional(s));
            c.record_field = record_field;
            c.record_energy = record_energy;
            c.stop_after_contact = stop_after_contact;
            c.quiet_after_contact_s = quiet_after_contact_s;
            c.quiet_after_contact_fraction = quiet_after_contact_fraction;
            c.force_only = force_only;
            c.nan_check_every = nan_check_every;
            c.w0 = opt(w0);
            c.bx0 = opt(bx0);
            c.by0 = opt(by0);
            c.vw0 = opt(vw0);
            c.vbx0 = opt(vbx0);
            c.vby0 = opt(vby0);
            is::RunResult r;
            {
              nb::gil_scoped_release release;
              r = p.run(c);
            }
            const size_t nn = static_cast<size_t>(p.nodes());
            const size_t nrec = static_cast<size_t>(n_record);
            nb::dict out;
            out["steps_done"] = r.steps_done;
            out["sensors"] = to_numpy(std::move(r.sensors), {c.sensors.size(), nrec});
            if (record_field) out["field"] = to_numpy(std::move(r.field), {nrec, nn});
            const size_t nf = r.force_n.size();
            out["force_n"] = to_numpy(std::move(r.force_n), {nf});
            if (record_energy) out["energy"] = to_numpy(std::move(r.energy), {nrec, 4});
            out["ball_z_m"] = r.ball_z_m;
            out["ball_v_m_s"] = r.ball_v_m_s;
            out["contact_start_s"] = r.contact_start_s;
            out["contact_end_s"] = r.contact_end_s;
            out["contacts"] = r.contacts;
            out["w"] = to_numpy(std::move(r.w), {nn});
            out["bx"] = to_numpy(std::move(r.bx), {nn});
            out["by"] = to_numpy(std::move(r.by), {nn});
            return out;
          },
          "dt_s"_a, "n_steps"_a, "record_every"_a = 1, "n_record"_a = 0, "ball"_a = nb::none(),
          "load"_a = nb::none(), "sensors"_a = nb::list(), "record_field"_a = false, "record_energy"_a = false,
          "stop_after_contact"_a = false, "quiet_after_contact_s"_a = 100e-6,
          "quiet_after_contact_fraction"_a = 1.0, "force_only"_a = false, "nan_check_every"_a = 50,
          "load_delay_s"_a = 0.0, "load_lowpass_s"_a = 0.0,
          "w0"_a = nb::none(), "bx0"_a = nb::none(), "by0"_a = nb::none(), "vw0"_a = nb::none(),
          "vbx0"_a = nb::none(), "vby0"_a = nb::none(),
          "Explicit run; returns a dict (sensors [n_sensors, n_record] hat-sampled, field [n_record, nodes] "
          "of w if asked, force_n per step, energy [n_record, 4] if asked, final state).");

  m.def(
      "element_stiffness",
      [](double hx_m, double hy_m, double d, double nu, double s, nb::object material) {
        return to_numpy(is::element_stiffness(hx_m, hy_m, d, nu, s, opt(material)), {12, 12});
      },
      "hx_m"_a, "hy_m"_a, "d"_a, "nu"_a, "s"_a, "material"_a = nb::none(),
      "12x12 element stiffness (dofs node-major w, bx, by; nodes (-,-), (+,-), (+,+), (-,+)) from the stepper's kernel.");
}
