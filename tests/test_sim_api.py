"""The simulator's public API, its bad-input errors and its CLI commands (coarse meshes, seconds)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from impactsense import cli
from impactsense.data import bundled_session_path, load_rig, load_session
from impactsense.errors import ConfigError
from impactsense.sim import SimParams, SimulationError, simulate_drops
from impactsense.sim import simulate as simmod
from impactsense.sim.model import build_model


@pytest.fixture(scope="module")
def rig():
    return load_rig(bundled_session_path())


@pytest.fixture(scope="module")
def coarse(rig):
    return SimParams.from_rig(rig, element_mm=8.0, duration_ms=3.0, taper_ms=0.5)


def test_params_json_round_trip_and_calibration_file(tmp_path, coarse):
    path = coarse.to_json(tmp_path / "p.json")
    assert SimParams.from_json(path) == coarse
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"plate": {"e_mpa": 4800}, "sim_params": dict(coarse.to_dict(), e_pa=4.8e9)}))
    assert SimParams.from_json(cal).e_pa == 4.8e9


@pytest.mark.parametrize("change, words", [
    (dict(e_pa=0.0), "e_pa"), (dict(e_pa=-5e9), "e_pa"), (dict(nu=0.5), "nu"), (dict(nu=0.7), "nu"),
    (dict(rho_kg_m3=0.0), "rho"), (dict(support="glued"), "support"), (dict(damping_per_s=-1.0), "damping"),
    (dict(pzt_eps33_rel=0.0), "eps33"), (dict(thickness_mm=float("nan")), "thickness"),
])
def test_non_physical_parameters_fail_clearly(change, words):
    with pytest.raises(ConfigError, match=words):
        SimParams(**change)


def test_unknown_key_in_json_fails(tmp_path):
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"E": 5e9}))
    with pytest.raises(ConfigError, match="unknown key"):
        SimParams.from_json(path)


def test_time_step_above_stability_limit_fails_before_stepping(rig, coarse):
    with pytest.raises(ConfigError, match="stability limit"):
        build_model(coarse.replace(dt_us=50.0), rig)


@pytest.mark.parametrize("x, y, words", [(-5.0, 100.0, "off the"), (160.0, 400.0, "off the"),
                                         (31.0, 34.0, "on sensor S1"), (289.0, 285.0, "on sensor S3")])
def test_bad_impacts_fail_before_any_stepping(rig, coarse, monkeypatch, x, y, words):
    def boom(*a, **k):
        raise AssertionError("stepped before validating the input")

    monkeypatch.setattr(simmod, "_run", boom)
    with pytest.raises(ConfigError, match=words):
        simulate_drops(coarse, rig, [160.0, x], [150.0, y], [150.0, 150.0], progress=False)


def test_blow_up_is_caught_with_its_step(rig, coarse):
    model = build_model(coarse, rig)
    with pytest.raises(SimulationError, match=r"step \d+"):
        simmod._run(model, dt_s=model.dt_crit_s * 1.5, n_steps=20000, n_record=0, nan_check_every=25,
                    ball=[0.16, 0.15, model.ball_mass_kg, model.k_hertz, 1.7, 9.81])


def test_simulate_drops_shape_bias_and_pretrigger(rig, coarse):
    adc = simulate_drops(coarse, rig, [120.0, 200.0], [100.0, 220.0], [150.0, 110.0], progress=False)
    assert adc.shape == (2, 4, rig.samples) and adc.dtype == np.uint16
    pre = coarse.pretrigger_samples
    assert np.all(adc[:, :, :pre] == rig.bias_counts)             # noise-free: flat before the touch
    dev = np.abs(adc.astype(int) - rig.bias_counts)
    assert dev.max() > 100                                       # a real signal arrives
    onset = np.argmax(dev > 40, axis=2)
    assert np.all(onset > pre)
    # nearer sensor first (drop 0 is nearest S1, drop 1 nearest S3)
    assert onset[0].argmin() == 0 and onset[1].argmin() == 2
    noisy = simulate_drops(coarse, rig, [120.0], [100.0], [150.0], noise=True, seed=3, progress=False)
    assert 0.8 < np.std(noisy[0, :, :pre].astype(float)) < 2.5


def test_cli_simulate_and_dataset(tmp_path, rig, coarse):
    params = coarse.to_json(tmp_path / "p.json")
    out = tmp_path / "one.npz"
    assert cli.main(["simulate", "--x", "150", "--y", "140", "--height", "150", "--params", str(params),
                     "--out", str(out)]) == 0
    with np.load(out) as z:
        assert z["adc"].shape == (1, 4, rig.samples) and z["adc"].dtype == np.uint16
    ds = tmp_path / "virtual"
    assert cli.main(["simulate-dataset", "--n", "6", "--params", str(params), "--out", str(ds)]) == 0
    s = load_session(ds)
    assert len(s) == 6
    assert np.all((s.height_mm >= 100) & (s.height_mm <= 200) & (s.height_mm % 5 == 0))
    d = np.hypot(s.x_mm[:, None] - rig.sensor_x_mm, s.y_mm[:, None] - rig.sensor_y_mm)
    assert d.min() >= 25.0


def test_cli_dataset_from_a_calibration_takes_its_rig(tmp_path, rig, coarse):
    """simulate-dataset --calibration CAL.json makes the drops on the rig of the session CAL.json was fitted
    on (its `data`), not the bundled one; --rig still overrides it."""
    other = tmp_path / "other-rig"
    other.mkdir()
    raw = json.loads((bundled_session_path() / "rig.json").read_text())
    raw.update(plate_x_mm=400.0, plate_y_mm=350.0)
    (other / "rig.json").write_text(json.dumps(raw))
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"data": str(other), "sim_params": coarse.to_dict()}))
    ds = tmp_path / "virtual"
    assert cli.main(["simulate-dataset", "--n", "2", "--calibration", str(cal), "--out", str(ds)]) == 0
    made = load_session(ds).rig
    assert (made.plate_x_mm, made.plate_y_mm) == (400.0, 350.0)
    ds2 = tmp_path / "virtual2"
    assert cli.main(["simulate-dataset", "--n", "2", "--calibration", str(cal), "--rig", "bundled",
                     "--out", str(ds2)]) == 0
    assert load_session(ds2).rig.plate_x_mm == rig.plate_x_mm


def test_cli_bad_inputs_exit_2(tmp_path):
    bad = tmp_path / "cal.json"
    bad.write_text(json.dumps({"plate": {}}))
    assert cli.main(["simulate-dataset", "--n", "3", "--calibration", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert cli.main(["simulate", "--x", "500", "--y", "100", "--height", "150", "--out",
                     str(tmp_path / "x.npz")]) == 2
