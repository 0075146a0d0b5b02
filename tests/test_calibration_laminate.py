"""A laminate's calibration (issue 15): the ray model of the fast first-arrival model, the first guess from the
picks, and E1 / E2 of a laminate recovered from the DToA of FEM drops (another model and mesh)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from impactsense.calibration import arrival, laminate, plate
from impactsense.data import bundled_session_path, read_json, rig_from_dict
from impactsense.materials import material_for_rig
from impactsense.sim import dispersion

SENSORS = [(50.0, 45.0), (400.0, 55.0), (395.0, 300.0), (60.0, 290.0)]


def laminate_rig(material="carbon-fibre laminate, fibres along x"):
    raw = read_json(bundled_session_path() / "rig.json")
    sensors = [dict(s, x_mm=x, y_mm=y) for s, (x, y) in zip(raw["sensors"], SENSORS)]
    return rig_from_dict({**raw, "plate_material": material, "plate_x_mm": 450.0, "plate_y_mm": 350.0,
                          "thickness_mm": 2.5, "density_kg_m3": 1550.0, "sensors": sensors})


XY = np.array([[120.0, 90.0], [330.0, 170.0], [380.0, 200.0], [220.0, 260.0]])
HEIGHT = np.array([120.0, 80.0, 160.0, 140.0])


def test_ray_model_isotropic_limit_is_the_isotropic_model():
    """A laminate with E1 = E2 and G12 = E / 2 (1 + nu) is the isotropic plate: every ray's signal equals the
    isotropic model's (the same Green function, the same wavenumbers)."""
    rig = laminate_rig()
    setup = arrival.setup_from_rig(rig, XY[:, 0], XY[:, 1], HEIGHT, n_fft=1024)
    theta = laminate.ray_angles(rig, XY[:, 0], XY[:, 1])
    e, nu = 40e9, 0.3
    lam = laminate.Laminate(e, e, e / (2 * (1 + nu)), nu, 25.0)
    iso = arrival.synth_unit(setup, [e], [nu])[0]
    ray = laminate.synth_laminates(setup, theta, [lam])[0]
    assert np.abs(ray - iso).max() <= 1e-9 * np.abs(iso).max()


def test_ray_wavenumber_along_the_axes_and_between():
    """Along a principal axis the stationary direction is the axis itself (k_ray = that axis's Mindlin
    wavenumber); between them the wave surface runs ahead of the plane wave along the ray (k_ray >= k(theta)),
    and fibres at 90 deg swap the axes."""
    rig = laminate_rig()
    setup = arrival.setup_from_rig(rig, [0.0], [0.0], [100.0], n_fft=1024)
    f = arrival.band_hz(setup)
    rho, t = setup.density_kg_m3, setup.thickness_m
    lam = laminate.Laminate(100e9, 20e9, 5e9, 0.3, 0.0)
    theta = np.radians([[0.0, 90.0, 45.0, 30.0]])
    k_ray, _, _ = laminate.ray_plate(setup, theta, lam)
    dm, sm = laminate._stiffness(lam, t)
    k = lambda phi: dispersion.a0_wavenumber_ds(f, *laminate._directional(dm, sm, np.radians(phi)),  # noqa: E731
                                                rho * t ** 3 / 12, rho * t)
    assert k_ray[0, 0] == pytest.approx(k(0.0), rel=1e-9)
    assert k_ray[0, 1] == pytest.approx(k(90.0), rel=1e-9)
    assert np.all(k_ray[0, 2] >= k(45.0) * (1 - 1e-12)) and np.all(k_ray[0, 3] >= k(30.0) * (1 - 1e-12))
    assert np.all(k_ray[0, 2] > k(0.0)) and np.all(k_ray[0, 2] < k(90.0))   # between the axes' speeds
    turned = laminate.Laminate(100e9, 20e9, 5e9, 0.3, 90.0)
    k_turned, _, _ = laminate.ray_plate(setup, theta[:, [1, 0]], turned)
    assert k_turned[0, 0] == pytest.approx(k(0.0), rel=1e-6)


def test_first_guess_recovers_an_elliptical_slowness():
    """DToA made by an elliptical ray slowness (s1 = 0.5 us/mm along fibres at 30 deg, s2 / s1 = 1.4) give
    back s1 and the ratio (1 %), i.e. Kirchhoff's E1 / E2 = 1.4^4."""
    rig = laminate_rig()
    x, y = np.array([100.0, 330.0, 380.0, 220.0, 200.0]), np.array([90.0, 170.0, 80.0, 260.0, 120.0])
    r = np.hypot(rig.sensor_x_mm[None] - x[:, None], rig.sensor_y_mm[None] - y[:, None])
    t = laminate.ray_angles(rig, x, y) - math.radians(30.0)
    toa = 0.5 * r * np.sqrt(np.cos(t) ** 2 + (1.4 * np.sin(t)) ** 2)
    dtoa = toa[:, plate.PAIR_I] - toa[:, plate.PAIR_J]
    g = laminate.pick_anisotropy(rig, x, y, dtoa, 30.0)
    assert g["slowness_ratio"] == pytest.approx(1.4, rel=0.01)
    assert g["s1_us_per_mm"] == pytest.approx(0.5, rel=0.01)
    assert g["E1_over_E2_kirchhoff"] == pytest.approx(1.4 ** 4, rel=0.04)


@pytest.mark.slow
def test_laminate_recovered_from_fem_drops():
    """Four FEM drops (2.5 mm mesh, the explicit solver's fast path) on a laminate with E1 / E2 = 5 (fibres
    along x) picked by the core: the stage's fit (the analytic ray model, another model than the data's)
    recovers E1 / E2 within 30 % (measured: 5.46), and the table's typical shape (E1 / E2 = 3.5) at its best
    scale fits the same DToA worse. Tolerance: whole-sample picks (10 us at 100 kHz over ~300 mm paths) on
    four drops. The scale is not asserted: the fast model reads the FEM's picks as a softer plate (its
    isotropic-equivalent modulus 18.5 GPa for the FEM's 35.9 GPa, 22-24 GPa by the isotropic grid, on a 2.5
    and a 1.6 mm mesh alike; docs/findings.md), which the FEM's own E scan (stage plate_fem) is there for."""
    from impactsense.calibration.problem import sim_features
    from impactsense.signal import core_config
    from impactsense.sim import SimParams, simulate_drops

    rig = laminate_rig()
    mat = material_for_rig(rig)
    truth = laminate.Laminate(100e9, 20e9, 5e9, 0.3, 0.0)
    p = SimParams.from_rig(rig, e_pa=truth.e1_pa, e2_pa=truth.e2_pa, g12_pa=truth.g12_pa, nu=0.3, element_mm=2.5,
                           method="fast")
    adc = simulate_drops(p, rig, XY[:, 0], XY[:, 1], HEIGHT, noise=False, seed=None, workers=1, progress=False)
    cfg = core_config(rig, rig_delay_us=[0.0] * 4)
    noise = (1.5, 2, 0)
    dtoa = sim_features(adc, cfg, *noise)["dtoa_us"]
    peak = np.abs(adc.astype(float) - rig.bias_counts).max(axis=-1)
    setup = arrival.setup_from_rig(rig, XY[:, 0], XY[:, 1], HEIGHT, n_fft=1024)
    theta = laminate.ray_angles(rig, XY[:, 0], XY[:, 1])
    state = plate.cfg_state(cfg, int(rig.bias_counts))
    e_axis = np.arange(20e3, 80e3, 2e3)                       # the isotropic grid's modulus, coarse
    e_grid = e_axis[np.argmin(plate.fast_loss(setup, state, peak, dtoa, e_axis, np.full(e_axis.size, 0.3),
                                              *noise)[0])] * 1e6
    guess = laminate.pick_anisotropy(rig, XY[:, 0], XY[:, 1], dtoa, 0.0)
    res = laminate.fit(setup, theta, mat, 0.3, guess, e_grid, state, peak, dtoa, noise=noise)
    assert res["E1_over_E2"] == pytest.approx(5.0, rel=0.30)
    assert res["loss_eq16_us2"] < res["loss_eq16_us2_typical_shape"]


def test_twin_keeps_the_fitted_shape_and_scales_its_equivalent_modulus():
    """With the laminate's shape in the calibration's parameters, e_pa is the isotropic-equivalent modulus:
    the simulator's E1, E2, G12 keep the shape and their equivalent modulus is e_pa (the later stages' E
    scans scale every modulus alike)."""
    from impactsense.calibration import fem

    rig = laminate_rig()
    flat = {"e_pa": 30e9, "nu": 0.3, "laminate_e2_over_e1": 0.2, "laminate_g12_over_e1": 0.05}
    sp = fem.sim_params_json(flat, rig)
    assert sp["e2_pa"] / sp["e_pa"] == pytest.approx(0.2) and sp["g12_pa"] / sp["e_pa"] == pytest.approx(0.05)
    lam = laminate.Laminate(sp["e_pa"], sp["e2_pa"], sp["g12_pa"], 0.3, 0.0)
    assert sp["e_pa"] * lam.equivalent_ratio() == pytest.approx(30e9, rel=1e-9)
    doubled = fem.sim_params_json(dict(flat, e_pa=60e9), rig)
    assert all(doubled[k] == pytest.approx(2 * sp[k]) for k in ("e_pa", "e2_pa", "g12_pa"))


def test_twin_mesh_cap():
    """The chain's twin mesh is Eq. 1's unless it has more than max_elements elements; then the square element
    that puts max_elements on the plate (from the rig's plate size, nothing else)."""
    from impactsense.calibration import fem
    from impactsense.sim import SimParams
    from impactsense.sim.model import mesh_size

    rig = laminate_rig()
    flat = {"e_pa": 30e9, "nu": 0.3, "laminate_e2_over_e1": 0.2, "laminate_g12_over_e1": 0.05}
    _, nx, ny, _, _ = mesh_size(SimParams.from_rig(rig, **fem._fields(flat)), rig)
    assert fem.capped_mesh(flat, rig, nx * ny) == {}
    cap = fem.capped_mesh(flat, rig, nx * ny // 2)["element_mm"]
    assert cap == pytest.approx(math.sqrt(450.0 * 350.0 / (nx * ny // 2)), abs=0.01)
    _, nx2, ny2, _, _ = mesh_size(SimParams.from_rig(rig, **fem._fields(dict(flat, element_mm=cap))), rig)
    assert nx2 * ny2 <= nx * ny // 2
    assert fem.capped_mesh(dict(flat, element_mm=5.0), rig, 100) == {}    # a given mesh is kept
