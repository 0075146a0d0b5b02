"""The "elastic_rim" support (free edges on a rubber rim: a spring and a dashpot on w along every edge) against
physics: a soft rim lets the plate bounce and rock on it as a rigid body at the frequencies the rim's stiffness
and the plate's mass and inertia give, a stiff rim is the simply supported plate, the springs store energy and
the dashpots only take it away. Coarse meshes; seconds each."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from impactsense.errors import ConfigError
from impactsense.sim import SimParams, dispersion
from impactsense.sim.model import assembled_dt_crit, rim_springs, support_masks, uniform_plate

from test_sim_physics import PMMA, assembled_stiffness

A, B, T = 0.320, 0.317, 4.2e-3


def frequencies(p, nx, ny, n=10, masks=None):
    """The n lowest natural frequencies (Hz) of the bare plate with p's support (the C++ operator, springs
    included, probed into K; fixed dofs removed)."""
    plate, mw, mr, _ = uniform_plate(nx, ny, A / nx, B / ny, p, masks=masks)
    k = assembled_stiffness(plate, nx, ny)
    held = np.concatenate([m.ravel() for m in (masks or support_masks(nx, ny, p.support))]).astype(bool)
    keep = np.flatnonzero(~held)
    dm = sp.diags(1 / np.sqrt(np.concatenate([mw, mr, mr])[keep]))
    lam = spla.eigsh(dm @ k[keep][:, keep] @ dm, k=n, sigma=-1.0, which="LM", return_eigenvectors=False)
    return np.sort(np.sqrt(np.clip(lam, 0, None))) / (2 * np.pi)


def test_rim_springs_share_the_perimeter():
    p = SimParams(support="elastic_rim", rim_stiffness_n_m2=2.0e6, rim_damping_n_s_m2=30.0, **PMMA)
    k, c = rim_springs(8, 6, A / 8, B / 6, p)
    assert k.sum() == pytest.approx(2.0e6 * 2 * (A + B), rel=1e-12)
    assert c.sum() == pytest.approx(30.0 * 2 * (A + B), rel=1e-12)
    assert np.all(k[1:-1, 1:-1] == 0)                       # interior nodes rest on nothing
    k_ss, _ = rim_springs(8, 6, A / 8, B / 6, SimParams(support="simply_supported", **PMMA))
    assert not k_ss.any()


def test_soft_rim_bounce_and_rocking_at_the_rigid_body_frequencies():
    """k = 100 N/m per m: the plate bounces and rocks on the rim as a rigid body (its first bending mode is
    ~40x higher; at k = 1e4, 4x higher, the bounce already bends the plate and sits 6 % lower): omega^2 = k * perimeter / (rho t a b) for the bounce, k * int x^2 ds / (rho t int x^2 dA)
    for the rocking about each axis; the bending modes are the free plate's."""
    k_rim = 100.0
    p = SimParams(support="elastic_rim", rim_stiffness_n_m2=k_rim, damping_per_s=0.0, **PMMA)
    f = frequencies(p, 24, 24, n=6)
    rho_t = p.rho_kg_m3 * T
    bounce = math.sqrt(k_rim * 2 * (A + B) / (rho_t * A * B))
    rock_y = math.sqrt(k_rim * (A ** 2 * B / 2 + A ** 3 / 6) / (rho_t * B * A ** 3 / 12))   # about the y axis
    rock_x = math.sqrt(k_rim * (B ** 2 * A / 2 + B ** 3 / 6) / (rho_t * A * B ** 3 / 12))
    expect = np.sort([bounce, rock_y, rock_x]) / (2 * np.pi)
    assert np.allclose(f[:3], expect, rtol=0.01), (f[:3], expect)
    f_free = frequencies(SimParams(support="free", damping_per_s=0.0, **PMMA), 24, 24, n=6)
    assert f_free[:3].max() < 1e-3 * f_free[3]              # the free plate's rigid-body modes sit at zero
    assert np.allclose(f[3:], f_free[3:], rtol=0.005), (f[3:], f_free[3:])


def test_stiff_rim_is_the_simply_supported_plate():
    """k = 1e12 N/m per m holds w on the edges: the frequencies are the plate's with w held there (tangential
    rotation free) to 0.1 %, and the analytic simply supported Mindlin plate's to 1 %."""
    nx = ny = 48
    p = SimParams(support="elastic_rim", rim_stiffness_n_m2=1.0e12, damping_per_s=0.0, **PMMA)
    f = frequencies(p, nx, ny, n=8)
    fix_w = support_masks(nx, ny, "simply_supported")[0]
    soft_ss = (fix_w, np.zeros_like(fix_w), np.zeros_like(fix_w))
    f_w_held = frequencies(SimParams(support="free", damping_per_s=0.0, **PMMA), nx, ny, n=8, masks=soft_ss)
    assert np.allclose(f, f_w_held, rtol=1e-3), (f, f_w_held)
    f_an, _ = dispersion.ss_plate_frequencies(A, B, p.e_pa, p.nu, p.rho_kg_m3, T, p.shear_factor)
    assert np.allclose(f, np.sort(f_an)[:8], rtol=0.01), (f, np.sort(f_an)[:8])
    f_free = frequencies(SimParams(support="free", damping_per_s=0.0, **PMMA), nx, ny, n=4)
    f_mid = frequencies(p.replace(rim_stiffness_n_m2=1.0e6), nx, ny, n=4)
    assert f_free[3] < f_mid[0] < f[0]                       # in between, the first bending mode is in between


def test_soft_simply_supported_holds_w_only():
    """"simply_supported_soft": w held on the edges, both rotations free. It is the stiff rim's limit (1e12 N/m
    per m, 1e-4); with fewer constraints every frequency lies below the hard support's, by the Mindlin
    boundary layer: clearly (> 0.4 %) for a thick plate (16 mm on 320 mm), within 0.5 % for the rig's 4.2 mm,
    where both are the Kirchhoff simply supported plate."""
    nx = ny = 32
    fix_w, fix_bx, fix_by = support_masks(nx, ny, "simply_supported_soft")
    assert np.array_equal(fix_w, support_masks(nx, ny, "simply_supported")[0])
    assert not fix_bx.any() and not fix_by.any()
    for t_mm, lo, hi in ((16.0, 0.004, 0.03), (4.2, 0.0, 0.005)):
        mat = {**PMMA, "thickness_mm": t_mm}
        soft = frequencies(SimParams(support="simply_supported_soft", damping_per_s=0.0, **mat), nx, ny, n=6)
        hard = frequencies(SimParams(support="simply_supported", damping_per_s=0.0, **mat), nx, ny, n=6)
        rim = frequencies(SimParams(support="elastic_rim", rim_stiffness_n_m2=1.0e12, damping_per_s=0.0, **mat),
                          nx, ny, n=6)
        assert np.allclose(rim, soft, rtol=1e-4), (t_mm, rim, soft)
        drop = 1 - soft / hard
        assert np.all((drop > lo) & (drop < hi)), (t_mm, drop)
    with pytest.raises(ConfigError, match="only with support 'elastic_rim'"):
        SimParams(support="simply_supported_soft", rim_stiffness_n_m2=1e9)


def test_stiff_inset_rim_holds_w_on_its_line_and_the_overhang_is_free():
    """rim_inset_mm: the rim under the plate 40 mm inside the edges (3 node lines of a 24 x 24 mesh, 13.3 mm
    elements): a stiff rim there is w held on that ring with the overhang free, to 0.1 %."""
    nx = ny = 24
    p = SimParams(support="elastic_rim", rim_stiffness_n_m2=1.0e12, rim_inset_mm=40.0, damping_per_s=0.0, **PMMA)
    k, _ = rim_springs(nx, ny, A / nx, B / ny, p)
    ring = k > 0
    assert ring[3, 3:-3].all() and ring[3:-3, 3].all() and not ring[:3].any() and not ring[:, :3].any()
    assert k.sum() == pytest.approx(1.0e12 * 2 * (A + B) * 18 / 24, rel=1e-12)   # the inner ring's perimeter
    held = (ring.astype(np.uint8), np.zeros((ny + 1, nx + 1), np.uint8), np.zeros((ny + 1, nx + 1), np.uint8))
    f_held = frequencies(SimParams(support="free", damping_per_s=0.0, **PMMA), nx, ny, n=6, masks=held)
    assert np.allclose(frequencies(p, nx, ny, n=6), f_held, rtol=1e-3)
    with pytest.raises(ConfigError, match="leaves no plate inside the rim"):
        rim_springs(nx, ny, A / nx, B / ny, p.replace(rim_inset_mm=200.0))


def _ring_down(p, nx=20, ny=20, steps=6000):
    """Energy history of the bare plate released from a bent, lifted state (no ball)."""
    plate, _, _, _ = uniform_plate(nx, ny, A / nx, B / ny, p)
    dt = 0.9 * assembled_dt_crit(plate)
    xx, yy = np.meshgrid(np.linspace(0, 1, nx + 1), np.linspace(0, 1, ny + 1))
    w0 = (1e-5 * (np.sin(np.pi * xx) * np.sin(np.pi * yy) + 0.3 + 0.2 * xx)).ravel()
    out = plate.run(dt_s=dt, n_steps=steps, record_every=20, n_record=steps // 20, record_energy=True, w0=w0)
    e = np.asarray(out["energy"]).reshape(-1, 4)
    return e[1:, 0] + e[1:, 1]


def test_rim_springs_conserve_energy_and_the_dashpot_takes_it_away():
    p = SimParams(support="elastic_rim", rim_stiffness_n_m2=3.0e7, damping_per_s=0.0, **PMMA)
    e = _ring_down(p)
    assert np.ptp(e) < 2e-3 * e.mean()                       # springs store energy, give it back
    e_c = _ring_down(p.replace(rim_damping_n_s_m2=2000.0))
    assert np.all(np.diff(e_c) <= 1e-3 * e_c[0])             # the dashpot never adds energy ...
    assert e_c[-1] < 0.5 * e_c[0]                            # ... and takes a good part of it


def test_rim_fields_validated():
    with pytest.raises(ConfigError, match="rim_stiffness_n_m2"):
        SimParams(support="elastic_rim", rim_stiffness_n_m2=-1.0)
    with pytest.raises(ConfigError, match="rim_damping_n_s_m2"):
        SimParams(support="elastic_rim", rim_damping_n_s_m2=float("nan"))
    with pytest.raises(ConfigError, match="only with support 'elastic_rim'"):
        SimParams(support="simply_supported", rim_stiffness_n_m2=1e7)
    with pytest.raises(ConfigError, match="rim_inset_mm"):
        SimParams(support="free", rim_inset_mm=3.0)
    with pytest.raises(ConfigError, match="rim_stiffness_n_m2"):
        SimParams.from_dict({"support": "elastic_rim", "rim_stiffness_n_m2": "stiff"}, "P.json")


@pytest.mark.slow
def test_choose_support_finds_the_support_that_made_the_drops_same_model(tmp_path):
    """`calibrate --support auto`'s stage: four cases the FEM made on an elastic rim (1e8 N/m per m; 2
    repetitions, rig noise, 1 mm position jitter) are told from the simply supported, free and clamped plates
    and from a 100x stiffer rim by their band group delays: chi^2 / dof of the true rim within 10 (6 measured:
    the position fit's 6 steps do not all converge from 1 mm off), every other candidate's over 100x higher.
    The same 5 mm FEM makes the drops and scores the candidates (an inverse crime: chi^2 / dof < 10 is reached
    only so; the rig's own misfit is ~600, README "The closed loop")."""
    from test_calibrate import fem_calibration_drops

    from impactsense.calibration import fem, plate_nu
    from impactsense.data import load_session

    rig = load_session(Path(__file__).resolve().parents[1] / "host/impactsense/data/session-1").rig
    truth = dict(fem.base_params(rig, 4500.0, 0.35), damping_per_s=800.0, support="elastic_rim",
                 rim_stiffness_n_m2=1.0e8)
    drops = fem_calibration_drops(tmp_path, rig, truth, reps=2)
    candidates = ({"support": "simply_supported"}, {"support": "free"}, {"support": "clamped"},
                  {"support": "elastic_rim", "rim_stiffness_n_m2": 1.0e8},
                  {"support": "elastic_rim", "rim_stiffness_n_m2": 1.0e10})
    start = {k: v for k, v in truth.items() if not k.startswith("rim_") and k != "support"}
    out = plate_nu.choose_support(drops, start, candidates=candidates)
    chi = {c["label"]: c["chi2_dof"] for c in out["candidates"]}
    assert out["fields"] == {"support": "elastic_rim", "rim_stiffness_n_m2": 1.0e8}, chi
    assert chi[out["chosen"]] < 10.0, chi
    assert min(v for k, v in chi.items() if k != out["chosen"]) > 100 * chi[out["chosen"]], chi


def test_calibrate_support_option_validated():
    from impactsense.calibration.pipeline import CalibrateOptions
    with pytest.raises(ConfigError, match="--rim-stiffness"):
        CalibrateOptions(support="elastic_rim").validate()
    with pytest.raises(ConfigError, match="only with --support elastic_rim"):
        CalibrateOptions(support="free", rim_stiffness_n_m2=1e8).validate()
    with pytest.raises(ConfigError, match="--support must be one of"):
        CalibrateOptions(support="rubber").validate()
    with pytest.raises(ConfigError, match="needs the FEM"):
        CalibrateOptions(support="auto", fem=False).validate()
    CalibrateOptions(support="elastic_rim", rim_stiffness_n_m2=1e8).validate()
