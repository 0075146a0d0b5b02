"""The cold zero-shot chain's batches side by side (issue 20): the same results as one after the other.

- the calibration's FEM points side by side (`fem.points_concurrently`): the same records, each point's drops
  in one thread;
- the PZT design's surrogate tunings in processes (`design.fit_surrogates`): the same R2 table and winners;
- `simulate-dataset --calibration` makes the twin's site map beside the virtual drops: the map `train --site-map
  auto` would build, cached in the folder and found there (train builds none)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from impactsense.calibration import design, fem, surrogates
from impactsense.data import load_session

COARSE_MM = 12.0     # a coarse twin: cheap FEM runs, the same code paths


def test_points_side_by_side_give_the_same_records_with_one_thread_each(monkeypatch):
    rig = load_session("bundled").rig
    simulate = fem.fem_simulator(workers=2, element_mm=COARSE_MM, duration_ms=2.0)
    base = fem.base_params(rig, 5000.0, 0.32)
    base["damping_per_s"] = 800.0
    points = [dict(base, e_pa=e * 1e6) for e in (4500.0, 5000.0, 5600.0)]
    x, y, h = np.array([60.0, 150.0, 230.0]), np.array([70.0, 160.0, 90.0]), np.array([150.0, 120.0, 180.0])
    serial = [simulate(p, rig, x, y, h) for p in points]

    import impactsense.calibration.fem as fem_module
    seen = []
    real = fem_module.simulate_drops

    def spy(*a, **k):
        seen.append(k["workers"])
        return real(*a, **k)
    monkeypatch.setattr(fem_module, "simulate_drops", spy)
    side = fem.points_concurrently(lambda p: simulate(p, rig, x, y, h), points, workers=2)
    assert sorted(seen[:2]) == [1, 1]           # side by side, each point's drops one after the other
    assert seen[2:] == [2]                      # the odd one out alone, its drops spread over the workers
    for a, b in zip(serial, side):
        np.testing.assert_array_equal(a, b)
    seen.clear()
    simulate(points[0], rig, x, y, h)          # outside: the simulator's own workers again
    assert seen == [2]


def test_surrogate_tunings_in_processes_give_the_same_table_and_winners():
    rng = np.random.default_rng(3)
    n, d = 24, len(fem.FACTORS)
    x = rng.random((n, d))
    outputs = {"sensor_energies_log10": np.stack([np.sin(3 * x[:, k % d]) + x[:, 0] for k in range(16)], 1),
               "residual_ratios": np.stack([x[:, k % d] * x[:, 1] for k in range(16)], 1)}
    split = surrogates.split_indices(n, 0)
    opts = SimpleNamespace(surrogate_trials=1, seed=0, progress=False, workers=1)
    table1, best1 = design.fit_surrogates(opts, x, outputs, split)
    table2, best2 = design.fit_surrogates(SimpleNamespace(**{**vars(opts), "workers": 2}), x, outputs, split)
    assert json.dumps(table1, sort_keys=True) == json.dumps(table2, sort_keys=True)
    assert {o: b.kind for o, b in best1.items()} == {o: b.kind for o, b in best2.items()}
    for o in best1:
        np.testing.assert_array_equal(best1[o].predict(x), best2[o].predict(x))


@pytest.fixture
def coarse_calibration(tmp_path):
    """The bundled twin's CAL.json on a coarse mesh (so not the bundled twin: its site map is not shipped)."""
    from impactsense.chain import calibration_record
    from impactsense.zeroshot import read_calibration

    src = tmp_path / "src.json"
    bundled = __import__("impactsense.sitemap", fromlist=["BUNDLED"]).BUNDLED
    cal_path = bundled.parent / "calibration.json"
    cal = read_calibration(cal_path)
    cal["sim_params"] = dict(cal["sim_params"], element_mm=COARSE_MM)
    src.write_text(json.dumps(cal))
    json.loads(calibration_record(src))          # a readable calibration
    return src


def test_simulate_dataset_makes_the_site_map_train_uses(coarse_calibration, tmp_path, monkeypatch):
    from impactsense import sitemap, zeroshot
    from impactsense.chain import measured_session, site_map
    from impactsense.cli import main
    from impactsense.outputs import MANIFEST
    from impactsense.sim import SimParams

    import functools
    monkeypatch.setattr(zeroshot, "build_site_map", functools.partial(sitemap.build_site_map, step_mm=30.0))
    out = tmp_path / "V"                          # (a 30 mm grid: the same code, fewer drops)
    assert main(["simulate-dataset", "--calibration", str(coarse_calibration), "--n", "6", "--out", str(out),
                 "--solver", "direct"]) == 0
    path = out / "site-map.npz"
    assert path.is_file() and "site-map.npz" in json.loads((out / MANIFEST).read_text())["files"]
    made = sitemap.SiteMap.load(path)
    session, _ = measured_session(coarse_calibration)
    fresh = zeroshot.build_twin_site_map(SimParams.from_json(coarse_calibration), session, progress=False)
    assert made.fingerprint() == fresh.fingerprint()        # the map train would build itself
    assert made.step_mm == 30.0 and made.present.sum() > 40

    def no_build(*a, **k):
        raise AssertionError("train rebuilt the site map")
    monkeypatch.setattr(zeroshot, "build_site_map", no_build)
    virtual = load_session(str(out))
    assert site_map(virtual, out / "calibration.json", progress=False).fingerprint() == made.fingerprint()

    bare = tmp_path / "W"
    assert main(["simulate-dataset", "--calibration", str(coarse_calibration), "--n", "6", "--out", str(bare),
                 "--solver", "direct", "--no-site-map"]) == 0
    assert not (bare / "site-map.npz").exists()


def test_site_map_chunks_featurized_beside_the_next_chunks_drops_give_the_same_map():
    from impactsense.signal import SignalConfig
    from impactsense.sim import SimParams
    from impactsense.sitemap import build_site_map

    rig = load_session("bundled").rig
    params = SimParams.from_rig(rig, element_mm=COARSE_MM)
    kw = dict(step_mm=30.0, progress=False, solver="direct")
    one = build_site_map(params, rig, SignalConfig.for_rig(rig), chunk=10_000, **kw)
    chunked = build_site_map(params, rig, SignalConfig.for_rig(rig), chunk=7, **kw)
    assert chunked.present.sum() > 40 and chunked.fingerprint() == one.fingerprint()
