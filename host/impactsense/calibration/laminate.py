"""A laminate's plate: E1, E2 and G12 from the calibration drops' DToA (docs/method.md, Calibration).

The isotropic plate grid (`plate`) fits one modulus; a laminate's flexural waves run at a speed that depends on
the direction, so its twin needs the shape of its stiffness too. This stage fits E1, E2 and G12 (nu12 and the
fibre angle held: the rig's material, `materials.material_for_rig`) by the same delay misfit (Eq. 16) of the
same fast first-arrival model, each drop-to-sensor path given the plate it sees along its ray:

  a straight-crested flexural wave travelling at angle phi feels the bending stiffness D(phi) = D11 c^4 +
  4 D16 c^3 s + 2 (D12 + 2 D66) c^2 s^2 + 4 D26 c s^3 + D22 s^4 and the shear stiffness S(phi) = n^T S n,
  so its Mindlin wavenumber is k(phi, omega). A point source's far field along the ray at angle theta is the
  stationary phase of those plane waves: k_ray(theta, omega) = max_phi k(phi, omega) cos(phi - theta) (the
  wave surface; for Kirchhoff k ~ D(phi)^(-1/4), exact). The path's Green function is the isotropic one
  (`arrival.synth_unit_paths`) with k_ray, and D, S of the stationary direction.

Search: a first guess from the calibration drops' picks (an elliptical ray slowness s(theta)^2 = s1^2 cos^2 +
s2^2 sin^2 in the material axes fitted to the DToA: E1 / E2 ~ (s2 / s1)^4, Kirchhoff's D11 / D22), the scale
from the isotropic grid's modulus (`materials.equivalent_isotropic_ratio` of that shape), then a log grid of
(E1, E1 / E2, G12) within the material's priors around the guess, refined once around its minimum.

The twin carries the fitted laminate as `fem.LAMINATE_FIELDS` (E2 / E1, G12 / E1) next to e_pa, the
isotropic-equivalent modulus every later stage scales (`fem.sim_fields`).
"""

from __future__ import annotations

import math
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..materials import Material, equivalent_isotropic_ratio
from ..sim import dispersion
from ..sim.material import rotated_q
from . import arrival, plate

KAPPA = arrival.KAPPA
DELTA_DEG = np.arange(-60.0, 60.5, 1.0)   # plane-wave directions around each ray (stationary phase search)
COARSE = (9, 9, 4)                        # grid points of (E1, E1 / E2, G12) over the search box
REFINE = (5, 5, 3)                        # and around the coarse minimum, one coarse step either side


@dataclass(frozen=True)
class Laminate:
    """E1, E2, G12 [Pa], nu12, the fibre angle from x [deg]."""

    e1_pa: float
    e2_pa: float
    g12_pa: float
    nu12: float
    axis_deg: float

    def equivalent_ratio(self) -> float:
        """E_eq / E1 (`materials.equivalent_isotropic_ratio`)."""
        from ..materials import ORTHOTROPIC, Prior
        p = lambda v: Prior(v, v, v)   # noqa: E731
        mat = Material("fit", ORTHOTROPIC, p(1.0), e1_pa=p(self.e1_pa), e2_pa=p(self.e2_pa),
                       g12_pa=p(self.g12_pa), nu12=p(self.nu12))
        return equivalent_isotropic_ratio(mat)

    def to_dict(self) -> dict:
        return {"E1_mpa": self.e1_pa / 1e6, "E2_mpa": self.e2_pa / 1e6, "G12_mpa": self.g12_pa / 1e6,
                "nu12": self.nu12, "E1_over_E2": self.e1_pa / self.e2_pa, "axis_deg": self.axis_deg,
                "E_equivalent_mpa": self.e1_pa * self.equivalent_ratio() / 1e6}


def _stiffness(lam: Laminate, thickness_m: float, shear_factor: float = KAPPA):
    """(D 3x3, S 2x2) in the plate's axes (G13 = G23 = G12, as the twin's default)."""
    b11, b22, b12, b66, b16, b26 = rotated_q(lam.e1_pa, lam.e2_pa, lam.g12_pa, lam.nu12, lam.axis_deg)
    dm = thickness_m ** 3 / 12 * np.array([[b11, b12, b16], [b12, b22, b26], [b16, b26, b66]])
    return dm, shear_factor * thickness_m * lam.g12_pa * np.eye(2)


def _directional(dm, sm, phi):
    c, s = np.cos(phi), np.sin(phi)
    d = (dm[0, 0] * c ** 4 + 4 * dm[0, 2] * c ** 3 * s + 2 * (dm[0, 1] + 2 * dm[2, 2]) * c ** 2 * s ** 2
         + 4 * dm[1, 2] * c * s ** 3 + dm[1, 1] * s ** 4)
    sh = sm[0, 0] * c * c + 2 * sm[0, 1] * c * s + sm[1, 1] * s * s
    return d, sh


def ray_angles(rig, x_mm, y_mm) -> np.ndarray:
    """Angle [rad] from x of each drop-to-sensor ray [D, 4]."""
    return np.arctan2(rig.sensor_y_mm[None, :] - np.asarray(y_mm, float)[:, None],
                      rig.sensor_x_mm[None, :] - np.asarray(x_mm, float)[:, None])


def ray_plate(setup: arrival.ArrivalSetup, theta: np.ndarray, lam: Laminate):
    """(k_ray [D, 4, F], d [D, 4, 1], s [D, 4, 1]) of one laminate along the rays theta [D, 4]."""
    f = arrival.band_hz(setup)
    dm, sm = _stiffness(lam, setup.thickness_m)
    phi = theta[..., None] + np.radians(DELTA_DEG)                       # [D, 4, A]
    d_phi, s_phi = _directional(dm, sm, phi)
    rho, t = setup.density_kg_m3, setup.thickness_m
    k = dispersion.a0_wavenumber_ds(f[None, None, None, :], d_phi[..., None], s_phi[..., None],
                                    rho * t ** 3 / 12, rho * t)          # [D, 4, A, F]
    proj = k * np.cos(np.radians(DELTA_DEG))[None, None, :, None]
    best = np.argmax(proj, axis=2)                                       # [D, 4, F]
    k_ray = np.take_along_axis(proj, best[:, :, None, :], axis=2)[:, :, 0, :]
    mid = best[..., best.shape[-1] // 2][..., None]                       # the stationary direction mid-band
    d = np.take_along_axis(d_phi, mid, axis=2)
    s = np.take_along_axis(s_phi, mid, axis=2)
    return k_ray, d, s


def synth_laminates(setup: arrival.ArrivalSetup, theta, laminates) -> np.ndarray:
    """Unit-gain synthetic signals [P, D, 4, n_fft] of the laminates along the rays theta [D, 4]."""
    rays = [ray_plate(setup, theta, lam) for lam in laminates]
    k1 = np.stack([r[0] for r in rays])
    d = np.stack([r[1] for r in rays])
    s = np.stack([r[2] for r in rays])
    # Hertz contact on the laminate: its indentation stiffness is set by the transverse modulus (~E2)
    e2 = np.array([lam.e2_pa for lam in laminates])[:, None, None]
    nu = np.array([lam.nu12 for lam in laminates])[:, None, None]
    tc = arrival.hertz_duration_s(e2, nu, setup.height_m[None, :, None], setup.ball_radius_m, setup.ball_mass_kg,
                                  setup.ball_e_pa, setup.ball_nu)
    return arrival.synth_unit_paths(setup, k1, d, s, tc)


def _loss_task(args):
    setup, theta, laminates, state, peak, dtoa_meas, noise = args
    unit = synth_laminates(setup, theta, laminates)
    return plate.picked_loss(unit, state, peak, dtoa_meas, *noise)[0]


def losses(setup, theta, laminates, cfg_state, peak, dtoa_meas, noise=(0.0, 1, 0), workers=1, chunk=8):
    """Eq. 16 of each laminate [P] (the rig's noise `noise` = (counts rms, realisations, seed))."""
    tasks = [(setup, theta, laminates[i:i + chunk], cfg_state, peak, dtoa_meas, noise)
             for i in range(0, len(laminates), chunk)]
    if workers > 1 and len(tasks) > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            parts = list(pool.map(_loss_task, tasks))
    else:
        parts = [_loss_task(t) for t in tasks]
    return np.concatenate(parts)


def pick_anisotropy(rig, x_mm, y_mm, dtoa_us, axis_deg: float) -> dict:
    """The cheap first guess: the elliptical ray slowness s(theta)^2 = s1^2 cos^2 + s2^2 sin^2 (theta from the
    fibres) whose DToA fit the measured ones best, s1 by least squares for each s2 / s1 on a log grid.
    Returns s1, s2 [us/mm], the ratio s2 / s1 and its Kirchhoff E1 / E2 = (s2 / s1)^4."""
    r = np.hypot(rig.sensor_x_mm[None, :] - np.asarray(x_mm, float)[:, None],
                 rig.sensor_y_mm[None, :] - np.asarray(y_mm, float)[:, None])
    t = ray_angles(rig, x_mm, y_mm) - math.radians(axis_deg)
    pi, pj = plate.PAIR_I, plate.PAIR_J
    ok = np.isfinite(dtoa_us)
    best = None
    for q in np.exp(np.linspace(np.log(0.5), np.log(2.5), 161)):
        path = r * np.sqrt(np.cos(t) ** 2 + (q * np.sin(t)) ** 2)       # travel time / s1
        a = (path[:, pi] - path[:, pj])[ok]
        s1 = float(a @ dtoa_us[ok] / (a @ a))
        rss = float(np.sum((dtoa_us[ok] - s1 * a) ** 2))
        if s1 > 0 and (best is None or rss < best[0]):
            best = (rss, q, s1)
    rss, q, s1 = best
    return {"s1_us_per_mm": s1, "s2_us_per_mm": s1 * q, "slowness_ratio": q, "E1_over_E2_kirchhoff": q ** 4,
            "rms_us": math.sqrt(rss / max(int(ok.sum()), 1))}


def _axis(lo, hi, n, centre=None, half=None):
    """A log-spaced axis over [lo, hi] (or centre x / half .. centre x half clipped to it) of n points."""
    if centre is not None:
        lo, hi = max(lo, centre / half), min(hi, centre * half)
    return np.exp(np.linspace(np.log(lo), np.log(hi), n)) if hi > lo else np.array([lo])


def _grid(e1_axis, ratio_axis, g_axis, nu12, axis_deg, e2_bounds):
    out = []
    for e1 in e1_axis:
        for ratio in ratio_axis:
            e2 = e1 / ratio
            if not (e2_bounds[0] <= e2 <= e2_bounds[1]) or nu12 ** 2 >= ratio:
                continue
            out += [Laminate(float(e1), float(e2), float(g), float(nu12), float(axis_deg)) for g in g_axis]
    return out


def fit(setup, theta, mat: Material, nu12: float, guess: dict, e_equivalent_pa: float, cfg_state, peak,
        dtoa_meas, noise=(0.0, 1, 0), workers=1, progress=None) -> dict:
    """E1, E2, G12 of the laminate by Eq. 16 over the calibration drops: a coarse log grid within the
    material's priors centred on the first guess (`pick_anisotropy`, the isotropic grid's modulus), refined
    once around its minimum. Returns the fit, the guess and the grids' sizes and losses."""
    e1p, e2p, gp = mat.e1_pa, mat.e2_pa, mat.g12_pa
    ratio_lo, ratio_hi = max(1.0, e1p.lo / e2p.hi), e1p.hi / e2p.lo
    ratio0 = float(np.clip(guess["E1_over_E2_kirchhoff"], ratio_lo, ratio_hi))
    g_ratio0 = gp.value / e1p.value * (e1p.value / e2p.value / ratio0) ** 0.5   # G12 ~ sqrt(E1 E2) scaling
    shape = Laminate(1.0, 1.0 / ratio0, g_ratio0, nu12, mat.axis_deg)
    e10 = float(np.clip(e_equivalent_pa / shape.equivalent_ratio(), e1p.lo, e1p.hi))
    g0 = float(np.clip(g_ratio0 * e10, gp.lo, gp.hi))
    evaluated = []

    def run(grid):
        loss = losses(setup, theta, grid, cfg_state, peak, dtoa_meas, noise, workers)
        evaluated.extend(zip(grid, loss))
        if progress:
            progress(len(grid))
        return grid[int(np.argmin(loss))], float(np.min(loss))

    n1, n2, n3 = COARSE
    coarse = _grid(_axis(e1p.lo, e1p.hi, n1, e10, 2.0), _axis(ratio_lo, ratio_hi, n2, ratio0, 2.5),
                   _axis(gp.lo, gp.hi, n3, g0, 2.0), nu12, mat.axis_deg, (e2p.lo, e2p.hi))
    best, best_loss = run(coarse)
    steps = (2.0 ** (2 / (n1 - 1)), 2.5 ** (2 / (n2 - 1)), 2.0 ** (2 / (n3 - 1)))
    m1, m2, m3 = REFINE
    fine = _grid(_axis(e1p.lo, e1p.hi, m1, best.e1_pa, steps[0]),
                 _axis(ratio_lo, ratio_hi, m2, best.e1_pa / best.e2_pa, steps[1]),
                 _axis(gp.lo, gp.hi, m3, best.g12_pa, steps[2]), nu12, mat.axis_deg, (e2p.lo, e2p.hi))
    best, best_loss = run(fine)
    lam, loss = min(evaluated, key=lambda item: item[1])
    typical = Laminate(e1p.value, e2p.value, gp.value, nu12, mat.axis_deg)
    loss_typical = float(losses(setup, theta, [Laminate(
        e_equivalent_pa / typical.equivalent_ratio(), e2p.value / e1p.value * e_equivalent_pa /
        typical.equivalent_ratio(), gp.value / e1p.value * e_equivalent_pa / typical.equivalent_ratio(), nu12,
        mat.axis_deg)], cfg_state, peak, dtoa_meas, noise, 1)[0])
    n = int(np.isfinite(dtoa_meas).sum())
    return {**lam.to_dict(), "loss_eq16_us2": float(loss), "rms_dtoa_error_us": math.sqrt(loss / n),
            "loss_eq16_us2_typical_shape": loss_typical,
            "rms_dtoa_error_us_typical_shape": math.sqrt(loss_typical / n),
            "guess": {**guess, "E1_mpa": e10 / 1e6, "E1_over_E2": ratio0, "G12_mpa": g0 / 1e6},
            "evaluations": len(evaluated),
            "model": "fast first-arrival model along each ray (stationary phase over plane-wave directions), "
                     "core picker; nu12 and the fibre angle held"}
