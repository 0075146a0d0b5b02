"""The plate_fem stage's E scan reads only the AIC DToA, so its runs stop once the picks have what they need
(`plate_fem.onset_observables`): a short run's picks are the whole window's bit for bit, and when a pick lies too
late for the short run (or is missing) the whole window is run instead."""

import numpy as np
import pytest

from impactsense.calibration import fem, pipeline, plate_fem
from impactsense.data import load_session

MESH = {"element_mm": 5.0}          # a coarse twin: the rule is the same on any mesh


@pytest.fixture(scope="module")
def setup():
    rig = load_session("bundled:session-1").rig
    cfg_sim = pipeline.sim_core_config(rig, pipeline.CalibrateOptions())
    flat = {**fem.base_params(rig, 4500.0, 0.36), **MESH}
    simulate = fem.fem_simulator(workers=2)
    x, y, h = np.array([40.0, 270.0, 160.0]), np.array([60.0, 250.0, 120.0]), np.array([60.0, 120.0, 200.0])
    runs = []

    def run(duration_ms=None):
        runs.append(duration_ms)
        return simulate(flat if duration_ms is None else dict(flat, duration_ms=duration_ms), rig, x, y, h)
    whole = plate_fem.sim_observables(run(), cfg_sim, 1.5, 4, 0)
    return run, runs, fem.sim_params(flat, rig), cfg_sim, whole


def test_short_runs_give_the_whole_windows_aic_dtoa_bit_for_bit(setup):
    run, runs, sim, cfg_sim, whole = setup
    del runs[:]
    obs = plate_fem.onset_observables(run, sim, cfg_sim, whole.shape[1], 1.5, 4, 0)
    assert runs == [sim.taper_ms + plate_fem.ONSET_WINDOW_MS]         # one short run was enough ...
    assert runs[0] < sim.duration_ms / 2                               # ... less than half the whole window
    assert np.isfinite(obs[:, 0]).all() and np.isnan(obs[:, 1:]).all()
    assert np.array_equal(obs[:, 0], whole[:, 0])


def test_a_pick_too_late_for_the_short_run_runs_the_whole_window(setup, monkeypatch):
    run, runs, sim, cfg_sim, whole = setup
    # a window that ends before the far channels' crossings (+ the AIC window): their picks would be missing or
    # cut short, so the whole window is run and gives its own figures
    monkeypatch.setattr(plate_fem, "ONSET_WINDOW_MS", 0.3)
    del runs[:]
    obs = plate_fem.onset_observables(run, sim, cfg_sim, whole.shape[1], 1.5, 4, 0)
    assert runs == [sim.taper_ms + 0.3, sim.duration_ms]
    assert np.array_equal(obs[:, 0], whole[:, 0])
