"""From (SimParams, Rig) to a ready-to-step finite-element model: mesh (Eq. 1), masses, supports, disc
sensing functionals, Hertz constant and time step (Eq. 2 + stability). All SI inside; `_mm`/`_us` at the edges.

Sensing law (open circuit, thin disc perfectly bonded to the plate's top surface, strain-charge form of
docs/method.md): the disc takes the plate's in-plane surface strain S1, S2; with E3 small compared to the
strain-driven stress (first order in the coupling), sigma1 + sigma2 = E11 (S1 + S2) / (1 - nu12), and
open circuit (integral of D3 over the electrode = 0) gives E3 = -d31 (sigma1 + sigma2) / eps33, so
    U = -E3 t_p = t_p d31 E11 / ((1 - nu12) eps33) * <S1 + S2>_disc,      S1 + S2 = z_s (beta_x,x + beta_y,y)
at the bonded surface z_s = -t/2 (w and z point into the plate, away from the ball). The fully coupled
law divides by (1 - k_p^2), k_p^2 = 2 d31^2 / ((s11 + s12) eps33); it is not used because the
calibration box (d31 up to -800 pC/N, eps33 down to 500) makes k_p^2 > 1, i.e. non-physical.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import _sim
from ..errors import ConfigError
from . import dispersion, material
from .params import SimParams

EPS0 = 8.8541878128e-12
SUBCYCLE_LAYER = 0   # rings of bare-plate nodes added around each disc's elements in its sub-cycled patch
#                      (the interface error grows with the patch's perimeter: 0 is the most accurate)


def hertz_k(params: SimParams, ball_radius_m: float) -> float:
    """Hertz constant k of F = k delta^1.5 for the ball on the plate (both materials elastic)."""
    e_plate, nu_plate = material.contact_modulus(params)
    e_star = 1.0 / ((1 - nu_plate ** 2) / e_plate + (1 - params.ball_nu ** 2) / params.ball_e_pa)
    return 4.0 / 3.0 * e_star * math.sqrt(ball_radius_m)


def hertz_duration_s(k: float, mass_kg: float, v_m_s: float) -> float:
    """Contact duration of a sphere on a rigid-backed elastic half space: 2.94 delta_max / v (Hertz)."""
    delta_max = (5 * mass_kg * v_m_s ** 2 / (4 * k)) ** 0.4
    return 2.9432 * delta_max / v_m_s


def impact_velocity(params: SimParams, height_mm) -> np.ndarray:
    return np.sqrt(2 * params.g_m_s2 * np.asarray(height_mm, float) * 1e-3)


@dataclass
class Model:
    params: SimParams
    plate: object            # _sim.Plate
    nx: int
    ny: int
    hx_m: float
    hy_m: float
    lx_m: float
    ly_m: float
    dt_s: float
    dt_crit_s: float
    record_every: int        # steps per ADC sample
    n_record: int            # simulated samples after the impact
    sensors: list            # functionals (node, wx, wy), output in volts
    sensor_xy_m: np.ndarray
    disc_radius_m: float
    ball_radius_m: float
    ball_mass_kg: float
    k_hertz: float
    f_max_hz: float
    fs_hz: float
    mass_w: np.ndarray | None = None     # lumped nodal mass on w [kg] (discs included), [nodes]
    mass_r: np.ndarray | None = None     # lumped nodal rotary inertia on beta_x, beta_y [kg m^2], [nodes]

    @property
    def nodes(self) -> int:
        return (self.nx + 1) * (self.ny + 1)

    @property
    def elements(self) -> int:
        return self.nx * self.ny

    def node_xy_m(self):
        x = np.arange(self.nx + 1) * self.hx_m
        y = np.arange(self.ny + 1) * self.hy_m
        return np.meshgrid(x, y)  # [ny+1, nx+1]

    def bilinear(self, x_m: float, y_m: float):
        """Nodes and weights of a point (the same interpolation the contact uses)."""
        i = min(int(x_m / self.hx_m), self.nx - 1)
        j = min(int(y_m / self.hy_m), self.ny - 1)
        xi, eta = x_m / self.hx_m - i, y_m / self.hy_m - j
        r = self.nx + 1
        nodes = np.array([j * r + i, j * r + i + 1, (j + 1) * r + i + 1, (j + 1) * r + i])
        wts = np.array([(1 - xi) * (1 - eta), xi * (1 - eta), xi * eta, (1 - xi) * eta])
        return nodes, wts

    def describe(self) -> dict:
        return dict(nx=self.nx, ny=self.ny, element_mm=(self.hx_m * 1e3, self.hy_m * 1e3),
                    elements=self.elements, nodes=self.nodes, dt_us=self.dt_s * 1e6,
                    dt_crit_us=self.dt_crit_s * 1e6, f_max_hz=self.f_max_hz, record_every=self.record_every,
                    n_record=self.n_record, subcycles=self.subcycles)

    @property
    def subcycles(self) -> int:
        """Sub-steps per step in the disc patches (1: not sub-cycled)."""
        fine = float(self.plate.fine_dt_s)
        if fine <= 0 or not self.plate.subcycled_nodes:
            return 1
        return max(1, math.ceil(self.dt_s / fine - 1e-9))


def plate_constants(p: SimParams):
    """(t, d, s): thickness and the reference bending and shear stiffness (isotropic: D and kappa G t;
    orthotropic: D11 and S_xx in the plate's axes, the rest as `material.element_constants` ratios)."""
    d, s, _ = material.element_constants(p)
    return p.thickness_mm * 1e-3, d, s


def element_dt_crit(hx, hy, d, nu, s, m_node, i_node, ratios=None) -> float:
    """Stability limit 2 / omega_max with omega_max from the element eigenproblem (an upper bound on the
    assembled one for lumped mass: Irons' theorem), i.e. a conservative dt."""
    k = np.asarray(_sim.element_stiffness(hx, hy, d, nu, s, ratios), float)
    m = np.tile([m_node, i_node, i_node], 4)
    lam = np.linalg.eigvalsh(k / np.sqrt(np.outer(m, m)))
    return 2.0 / math.sqrt(lam.max())


def assembled_dt_crit(plate) -> float:
    """Stability limit 2 / omega_max of the assembled plate (free dofs, discs included), omega_max^2 the
    largest eigenvalue of M^-1 K by Lanczos with the stepper's own kernel (a few tens of kernel calls; the
    Ritz value converges from below to 1e-7 and the limit is sharp: tests/test_sim_physics.py). On a uniform
    mesh it is about 15 % above the element bound (`element_dt_crit`), which Irons' theorem makes
    conservative. The Hertz contact is left to `cfl_safety` (0.97, and dt snaps down to divide the ADC
    period): its tangent stiffness k_t = 1.5 k delta^0.5 on the struck node can raise omega_max^2 by at most
    k_t / m_node (rank-one bound), 3.8 % for a 200 mm drop on an interior node (1.9 % in omega), 5 % at 1 m
    (delta^0.5 grows as h^0.2), so omega_max dt / 2 stays below 0.97 x 1.026 < 1. The real shift is far
    smaller: the highest plate mode is spread over the whole mesh. A blow-up is still caught by the stepper's
    NaN check."""
    lam = float(plate.max_eigenvalue())
    return 2.0 / math.sqrt(lam)


def support_masks(nx: int, ny: int, support: str):
    """fix_w, fix_bx, fix_by [ny+1, nx+1] for "free", "simply_supported" (hard: w and the tangential
    rotation held on every edge), "simply_supported_soft" (w held, both rotations free: the Mindlin plate's
    soft simple support, the limit of a stiff "elastic_rim") or "clamped"; "elastic_rim" holds nothing (its
    springs: `rim_springs`)."""
    fix_w = np.zeros((ny + 1, nx + 1), np.uint8)
    fix_bx = np.zeros_like(fix_w)
    fix_by = np.zeros_like(fix_w)
    if support in ("simply_supported", "simply_supported_soft", "clamped"):
        fix_w[0, :] = fix_w[-1, :] = 1
        fix_w[:, 0] = fix_w[:, -1] = 1
    if support in ("simply_supported", "clamped"):
        fix_by[:, 0] = fix_by[:, -1] = 1   # edges x = 0, Lx: rotation about x (w,y along the edge) held
        fix_bx[0, :] = fix_bx[-1, :] = 1   # edges y = 0, Ly
    if support == "clamped":
        fix_bx[:, 0] = fix_bx[:, -1] = 1
        fix_by[0, :] = fix_by[-1, :] = 1
    return fix_w, fix_bx, fix_by


def rim_springs(nx: int, ny: int, hx: float, hy: float, params: SimParams):
    """Per-node spring k_w [N/m] and dashpot c_w [N s/m] [ny+1, nx+1] of an "elastic_rim" support: the rim's
    stiffness and damping per metre of edge times each rim node's share of the rim (h / 2 per adjacent rim
    element: a corner node gets hx / 2 + hy / 2). The rim runs along the edges, or along the node lines nearest
    rim_inset_mm inside them (the plate overhanging the rim). Zeros for the other supports."""
    length = np.zeros((ny + 1, nx + 1))
    if params.support == "elastic_rim":
        # the rim's line: the node lines nearest rim_inset_mm inside the edges (0: the edges)
        i0 = int(round(params.rim_inset_mm * 1e-3 / hx))
        j0 = int(round(params.rim_inset_mm * 1e-3 / hy))
        if 2 * i0 >= nx or 2 * j0 >= ny:
            raise ConfigError(f"rim_inset_mm = {params.rim_inset_mm:g} leaves no plate inside the rim")
        ring = length[j0:ny + 1 - j0, i0:nx + 1 - i0]
        ring[0, :] += hx
        ring[-1, :] += hx
        ring[:, 0] += hy
        ring[:, -1] += hy
        for edge in (ring[0, :], ring[-1, :]):
            edge[0] -= hx / 2
            edge[-1] -= hx / 2
        for edge in (ring[:, 0], ring[:, -1]):
            edge[0] -= hy / 2
            edge[-1] -= hy / 2
    return params.rim_stiffness_n_m2 * length, params.rim_damping_n_s_m2 * length


def _set_rim(plate, nx, ny, hx, hy, params: SimParams) -> None:
    if params.support == "elastic_rim":
        k_w, c_w = rim_springs(nx, ny, hx, hy, params)
        plate.set_node_springs(np.ascontiguousarray(k_w.ravel()), np.ascontiguousarray(c_w.ravel()))


def node_areas(nx: int, ny: int, hx: float, hy: float) -> np.ndarray:
    """Lumping: a quarter of each element to each of its nodes."""
    a = np.zeros((ny + 1, nx + 1))
    a[:-1, :-1] += 0.25
    a[1:, :-1] += 0.25
    a[:-1, 1:] += 0.25
    a[1:, 1:] += 0.25
    return a * hx * hy


def uniform_plate(nx: int, ny: int, hx: float, hy: float, params: SimParams, masks=None):
    """A bare plate (no discs) with params' material and support (or explicit masks (fix_w, fix_bx,
    fix_by)); returns (_sim.Plate, mass_w, mass_r, dt_crit_s). Used by the validation tests."""
    t = params.thickness_mm * 1e-3
    d, s, ratios = material.element_constants(params)
    rho = params.rho_kg_m3
    i_rot = rho * t ** 3 / 12 * params.rotary_inertia_scale
    area = node_areas(nx, ny, hx, hy)
    masks = support_masks(nx, ny, params.support) if masks is None else masks
    mass_w, mass_r = rho * t * area, i_rot * area
    plate = _sim.Plate(nx, ny, hx, hy, params.nu, np.full(nx * ny, d), np.full(nx * ny, s), mass_w.ravel(),
                       mass_r.ravel(), *(np.ascontiguousarray(m, np.uint8).ravel() for m in masks),
                       params.damping_per_s, ratios)
    _set_rim(plate, nx, ny, hx, hy, params)
    dt_crit = element_dt_crit(hx, hy, d, params.nu, s, rho * t * hx * hy / 4, i_rot * hx * hy / 4, ratios)
    return plate, mass_w.ravel(), mass_r.ravel(), dt_crit


def _disc_fraction(model_h, centre, radius, n_sub=8):
    """Area fraction of each element inside a disc (sub-cell sampling), as a sparse dict {(i, j): frac}."""
    hx, hy, nx, ny = model_h
    cx, cy = centre
    i0, i1 = max(int((cx - radius) / hx), 0), min(int((cx + radius) / hx) + 1, nx)
    j0, j1 = max(int((cy - radius) / hy), 0), min(int((cy + radius) / hy) + 1, ny)
    if i1 <= i0 or j1 <= j0:
        return {}
    sub = (np.arange(n_sub) + 0.5) / n_sub
    xs = (np.arange(i0, i1)[:, None] + sub[None]) * hx          # [elements in x, samples]
    ys = (np.arange(j0, j1)[:, None] + sub[None]) * hy
    inside = (xs[None, :, None, :] - cx) ** 2 + (ys[:, None, :, None] - cy) ** 2 <= radius ** 2
    frac = inside.sum(axis=(2, 3)) / n_sub ** 2                 # [j, i]
    return {(int(i), int(j)): float(frac[j - j0, i - i0])
            for j in range(j0, j1) for i in range(i0, i1) if frac[j - j0, i - i0] > 0}


def mesh_element_m(p: SimParams, f_max_hz: float) -> float:
    """Eq. 1: a tenth of the shortest A0 wavelength at f_max_hz (an orthotropic plate: along its softest
    direction, `material.softest`)."""
    t = p.thickness_mm * 1e-3
    if not material.orthotropic(p):
        return float(dispersion.a0_wavelength(f_max_hz, p.e_pa, p.nu, p.rho_kg_m3, t, p.shear_factor)) / 10
    d_min, s_min = material.softest(p)
    k = dispersion.a0_wavenumber_ds(f_max_hz, d_min, s_min, p.rho_kg_m3 * t ** 3 / 12, p.rho_kg_m3 * t)
    return float(2 * np.pi / k) / 10


def _mesh(p: SimParams, rig, k: float, ball_m: float) -> tuple:
    """Eq. 1: (f_max, nx, ny, hx, hy), the element size from the shortest A0 wavelength in the contact's
    spectrum (or SimParams f_max_hz / element_mm)."""
    lx, ly, fs = rig.plate_x_mm * 1e-3, rig.plate_y_mm * 1e-3, float(rig.fs_hz)
    if p.f_max_hz is not None:
        f_max = float(p.f_max_hz)
    else:
        tc = hertz_duration_s(k, ball_m, float(impact_velocity(p, p.max_height_mm)))
        f_max = min(p.f_max_factor / tc, fs / 2)   # no finer than the logger's band can tell
    if p.element_mm is not None:
        le = p.element_mm * 1e-3
    else:
        le = mesh_element_m(p, f_max)
    nx, ny = max(int(math.ceil(lx / le - 1e-9)), 2), max(int(math.ceil(ly / le - 1e-9)), 2)
    if nx * ny > 4_000_000:
        raise ConfigError(f"mesh of {nx} x {ny} elements is too large (element_mm = {le * 1e3:.3g})")
    return f_max, nx, ny, lx / nx, ly / ny


def mesh_size(p: SimParams, rig) -> tuple:
    """Eq. 1's mesh of the plate `p` on the rig: (f_max, nx, ny, hx, hy) as `build_model` makes it."""
    return _mesh(p, rig, hertz_k(p, rig.ball_diameter_mm * 0.5e-3), rig.ball_mass_g * 1e-3)


def _disc_masses(p: SimParams, patches, d_elem, d: float, grid: tuple) -> tuple:
    """Lumped masses (w, rotations) per node: a quarter of each element's mass to each of its nodes, plus the
    ceramic's under the disc patches."""
    nx, ny, hx, hy = grid
    t, tp = p.thickness_mm * 1e-3, p.pzt_thickness_mm * 1e-3
    area_node = node_areas(nx, ny, hx, hy)
    i_rot = p.rho_kg_m3 * t ** 3 / 12 * p.rotary_inertia_scale
    mass_w = p.rho_kg_m3 * t * area_node
    mass_r = i_rot * area_node
    mp = p.pzt_rho_kg_m3 * tp * p.disc_mass_scale if p.disc_mass else 0.0
    ip = mp * (t / 2 + tp / 2) ** 2
    for fr in patches:
        for (i, j), f in fr.items():
            # rotary inertia under the disc raised by disc_inertia_factor (default 1.06), or (opt-in
            # disc_inertia_scaling) until its D / I is the bare plate's, so the stiffer disc sets a larger
            # stable step or no longer sets it; never past the plate's D / I
            i_el = i_rot + f * ip
            extra = 0.0
            if p.disc_stiffness:
                need = max(0.0, d_elem[j, i] / d * i_rot / i_el - 1.0)   # the raise to the plate's D / I
                extra = (need if p.disc_inertia_scaling else min(need, p.disc_inertia_factor - 1.0)) * i_el
            for dj in (0, 1):
                for di in (0, 1):
                    mass_w[j + dj, i + di] += 0.25 * f * hx * hy * mp
                    mass_r[j + dj, i + di] += 0.25 * hx * hy * (f * ip + extra)
    return mass_w, mass_r


def _time_step(p: SimParams, plate, hx: float, hy: float, f_max: float, fs: float) -> tuple:
    """(dt, dt_crit, steps per ADC sample): the assembled plate's stability limit and Eq. 2, snapped to divide
    1/fs; sub-cycled (fine meshes, see SimParams.subcycle), the disc patches take sub-steps under cfl_safety x
    the whole plate's limit and dt is bound by the rest of the plate."""
    dt_crit = assembled_dt_crit(plate)
    if p.subcycle and max(hx, hy) <= p.subcycle_max_element_mm * 1e-3:
        plate.set_subcycling(p.cfl_safety * dt_crit, SUBCYCLE_LAYER)
        if plate.subcycled_nodes:
            dt_crit = 2.0 / math.sqrt(float(plate.max_eigenvalue(coarse=True)))
    dt_eq2 = 1.0 / (20 * f_max)
    t_sample = 1.0 / fs
    if p.dt_us is not None:
        dt_req = p.dt_us * 1e-6
        if dt_req > dt_crit:
            raise ConfigError(f"dt_us = {p.dt_us:g} is above the stability limit {dt_crit * 1e6:.4g} us "
                              f"for this mesh ({hx * 1e3:.3g} x {hy * 1e3:.3g} mm elements)")
    else:
        dt_req = min(p.cfl_safety * dt_crit, dt_eq2)
    m = max(int(math.ceil(t_sample / dt_req - 1e-9)), 1)
    return t_sample / m, dt_crit, m


def _sensing_functionals(p: SimParams, fractions, grid: tuple) -> list:
    """Per disc (nodes, weights on beta_x, weights on beta_y): U = C <beta_x,x + beta_y,y>_disc, gradients at
    element centres."""
    nx, ny, hx, hy = grid
    t, tp, e11 = p.thickness_mm * 1e-3, p.pzt_thickness_mm * 1e-3, p.pzt_e11_mpa * 1e6
    z_s = -t / 2
    c_volt = tp * (p.pzt_d31_pc_n * 1e-12) * e11 / ((1 - p.pzt_nu12) * p.pzt_eps33_rel * EPS0) * z_s
    r = nx + 1
    sensors = []
    for fr in fractions:
        a_disc = sum(fr.values()) * hx * hy
        acc: dict[int, list] = {}
        for (i, j), f in fr.items():
            wgt = c_volt * f * hx * hy / a_disc
            n1, n2, n3, n4 = j * r + i, j * r + i + 1, (j + 1) * r + i + 1, (j + 1) * r + i
            # beta_x,x = (-b1 + b2 + b3 - b4) / (2 hx); beta_y,y = (-b1 - b2 + b3 + b4) / (2 hy)
            for node, sx, sy in ((n1, -1, -1), (n2, 1, -1), (n3, 1, 1), (n4, -1, 1)):
                e = acc.setdefault(node, [0.0, 0.0])
                e[0] += wgt * sx / (2 * hx)
                e[1] += wgt * sy / (2 * hy)
        nodes = np.array(sorted(acc), dtype=np.int64)
        sensors.append((nodes, np.array([acc[k][0] for k in nodes]), np.array([acc[k][1] for k in nodes])))
    return sensors


def build_model(params: SimParams, rig, *, duration_ms: float | None = None) -> Model:
    p = params
    lx, ly = rig.plate_x_mm * 1e-3, rig.plate_y_mm * 1e-3
    t = p.thickness_mm * 1e-3
    d, s, ratios = material.element_constants(p)
    fs = float(rig.fs_hz)
    ball_r = rig.ball_diameter_mm * 0.5e-3
    ball_m = rig.ball_mass_g * 1e-3
    k = hertz_k(p, ball_r)
    disc_r = rig.sensor_diameter_mm * 0.5e-3
    f_max, nx, ny, hx, hy = _mesh(p, rig, k, ball_m)

    # per-element stiffness; discs add their bending stiffness about the plate's mid-plane
    d_elem = np.full((ny, nx), d)
    s_elem = np.full((ny, nx), s)
    tp = p.pzt_thickness_mm * 1e-3
    d_disc = p.pzt_e11_mpa * 1e6 / (1 - p.pzt_nu12 ** 2) * ((t / 2 + tp) ** 3 - (t / 2) ** 3) / 3
    sensors_xy = np.asarray(rig.sensor_xy_mm, float) * 1e-3
    fractions = [_disc_fraction((hx, hy, nx, ny), c, disc_r) for c in sensors_xy]   # the sensing circles
    # the plate the ceramic loads mechanically (SimParams.disc_patch_diameter_mm; None: the sensing disc)
    patches = fractions if p.disc_patch_diameter_mm is None else \
        [_disc_fraction((hx, hy, nx, ny), c, p.disc_patch_diameter_mm * 0.5e-3) for c in sensors_xy]
    if p.disc_stiffness:
        d_disc = d_disc * p.disc_stiffness_scale
        for fr in patches:
            for (i, j), f in fr.items():
                d_elem[j, i] += f * d_disc
    mass_w, mass_r = _disc_masses(p, patches, d_elem, d, (nx, ny, hx, hy))

    fix_w, fix_bx, fix_by = support_masks(nx, ny, p.support)
    plate = _sim.Plate(nx, ny, hx, hy, p.nu, np.ascontiguousarray(d_elem.ravel()),
                       np.ascontiguousarray(s_elem.ravel()), mass_w.ravel(), mass_r.ravel(),
                       fix_w.ravel(), fix_bx.ravel(), fix_by.ravel(), p.damping_per_s, ratios)
    _set_rim(plate, nx, ny, hx, hy, p)
    dt, dt_crit, m = _time_step(p, plate, hx, hy, f_max, fs)
    dur = (p.duration_ms if duration_ms is None else duration_ms) * 1e-3
    return Model(params=p, plate=plate, nx=nx, ny=ny, hx_m=hx, hy_m=hy, lx_m=lx, ly_m=ly, dt_s=dt,
                 dt_crit_s=dt_crit, record_every=m, n_record=int(round(dur * fs)),
                 sensors=_sensing_functionals(p, fractions, (nx, ny, hx, hy)),
                 sensor_xy_m=sensors_xy, disc_radius_m=disc_r, ball_radius_m=ball_r, ball_mass_kg=ball_m,
                 k_hertz=k, f_max_hz=f_max, fs_hz=fs, mass_w=mass_w.ravel(), mass_r=mass_r.ravel())
