"""retrain's training data for a moved disc: with a twin, DATA_REF's recordings with the move put in or DATA_REF's
drops simulated by the corrected twin (the disc moved in the FEM: its channel's arrivals later by the path it
gained, the other channels as before), whichever's model places DATA_NEW's labelled drops better; without a twin,
or without a move, the recordings (docs/findings.md "Session 22: loopmove2")."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from impactsense import residuals as R
from impactsense.commands.retrain import training_session
from impactsense.data import load_session
from impactsense.diagnose import Candidate
from impactsense.pipeline import SignalConfig, featurize
from impactsense.sitemap import resolve_site_map
from impactsense.sim import SimParams


def _cand(effect, sensor, params):
    return Candidate(effect, sensor, params, 20.0, 0.0, True, True, [])


@pytest.fixture(scope="module")
def base():
    s = load_session("bundled:session-1")
    # six drops in the plate's middle band, well away from disc 0 (its arrivals are clean first cycles)
    far = np.flatnonzero(np.hypot(s.x_mm - 30.0, s.y_mm - 33.0) > 150.0)
    return s.subset(far[::max(1, len(far) // 6)][:6])


@pytest.fixture(scope="module")
def twin(base):
    src = resolve_site_map("auto", base.rig).source["sim_params"]
    return dataclasses.replace(SimParams.from_dict(src), element_mm=3.0, method="fast", duration_ms=6.0)


class _Placer:
    """A stand-in model: places every drop of the session it is given `off_mm` off in x."""

    def __init__(self, off_mm, class_accuracy=1.0):
        self.off_mm, self.class_accuracy = off_mm, class_accuracy

    def featurize(self, adc):
        return adc

    def predict(self, adc):
        return {"xy_mm": self.xy_mm + [self.off_mm, 0.0]}


def _fits(base, twin_off, measured_off, twin_class=1.0):
    """fit(session, effects): a _Placer whose error (and class accuracy) depends on which training data it was
    given (the corrected twin's drops are written to twin-training-data)."""
    def fit(session, effects):
        twin = session.path.name == "twin-training-data"
        m = _Placer(twin_off if twin else measured_off, twin_class if twin else 1.0)
        m.xy_mm = base.xy_mm
        return m
    return fit


@pytest.fixture(autouse=True)
def _stub_class(monkeypatch):
    import impactsense.commands.retrain as RT
    monkeypatch.setattr(RT, "class_accuracy", lambda model, session: model.class_accuracy)


def test_a_moved_disc_with_a_twin_trains_on_the_data_whose_model_places_data_new_better(base, twin, tmp_path,
                                                                                        monkeypatch):
    import impactsense.loop as L
    ref = R.fit_reference(R.extract(base))
    details = {"ref": ref}
    cases = len(np.unique(base.case_id))
    monkeypatch.setattr(L, "TWIN_TRAINING_POSITIONS", cases + 3)   # the twin's drops at 3 new positions too
    # disc 0 (at a corner) moved 8 mm further into its corner: every impact is ~8 mm further from it
    move = _cand("sensor_position", 0, {"dx_mm": -5.66, "dy_mm": -5.66, "offset_mm": 8.0})
    card = {"retrain": {}}
    moved, added = training_session(base, base, details, [move], twin, tmp_path / "a" / "training-data", 0, card,
                                     fit=_fits(base, twin_off=1.0, measured_off=3.0))
    assert card["retrain"]["training_data"] == "corrected twin"
    assert card["retrain"]["training_choice"]["mae_mm"] == pytest.approx({"measured": 1.5, "corrected twin": 0.5})
    assert [c.effect for c in added] == ["sensor_position"]
    assert moved.path.name == "training-data" and (tmp_path / "a" / "measured-training-data").is_dir()
    n = len(base)   # DATA_REF's declared drops first, then the twin's at new positions (each its own case)
    assert np.allclose(moved.xy_mm[:n], base.xy_mm) and len(moved) == n + 3
    assert len(np.unique(moved.case_id)) == cases + 3 and np.all(moved.case_id[n:] > base.case_id.max())
    assert np.hypot(moved.x_mm[n:, None] - base.x_mm, moved.y_mm[n:, None] - base.y_mm).min() > 0.1   # new positions
    assert np.array_equal(moved.rig.sensor_xy_mm, base.rig.sensor_xy_mm)   # the declared rig (retrain's --moved-rig off)
    card = {"retrain": {}}
    kept, _ = training_session(base, base, details, [move], twin, tmp_path / "b" / "training-data", 0, card,
                               fit=_fits(base, twin_off=3.0, measured_off=1.0))
    assert card["retrain"]["training_data"] == "reference recordings with the effects put in"
    assert card["retrain"]["training_choice"]["chosen"] == "measured" and np.array_equal(kept.adc[:, 1:], base.adc[:, 1:])
    card = {"retrain": {}}   # the twin's model places better but classes worse by more than its standard error
    kept, _ = training_session(base, base, details, [move], twin, tmp_path / "d" / "training-data", 0, card,
                               fit=_fits(base, twin_off=1.0, measured_off=3.0, twin_class=0.8))
    assert card["retrain"]["training_choice"]["chosen"] == "measured"
    assert np.array_equal(kept.adc[:, 1:], base.adc[:, 1:])
    still, _ = training_session(base, base, details, [_cand("sensor_gain", 1, {"gain": 1.0})], twin,
                                tmp_path / "c" / "training-data", 0, {"retrain": {}}, fit=_fits(base, 1.0, 3.0))
    assert np.array_equal(still.adc, base.adc)   # no move: the reference recordings (a unit gain changes nothing)
    from impactsense.loop import twin_training_session
    none = twin_training_session(base, twin, [], tmp_path / "none", ref.slowness_us_per_mm, 0)
    cfg = SignalConfig.for_rig(base.rig)
    assert len(none) == n   # no move: the twin's drops at DATA_REF's positions only
    dt = featurize(moved.adc[:n], cfg).toa_us - featurize(none.adc, cfg).toa_us
    d0 = np.hypot(base.x_mm - 30.0, base.y_mm - 33.0)
    gained = np.hypot(base.x_mm - 30.0 + 5.66, base.y_mm - 33.0 + 5.66) - d0
    # the moved disc's picks later by its path change at about the picks' slowness; the other discs' as before
    assert np.nanmedian(dt[:, 0] / gained) == pytest.approx(ref.slowness_us_per_mm, rel=0.5)
    assert np.nanmax(np.abs(dt[:, 1:])) < 0.5


def test_without_a_twin_a_move_is_put_into_the_reference_recordings(base, tmp_path):
    ref = R.fit_reference(R.extract(base))
    move = _cand("sensor_position", 0, {"dx_mm": -5.66, "dy_mm": -5.66, "offset_mm": 8.0})
    card = {"retrain": {}}
    out, _ = training_session(base, base, {"ref": ref}, [move], None, tmp_path / "measured", 0, card,
                              fit=_fits(base, 1.0, 3.0))
    assert card["retrain"]["training_data"] == "reference recordings with the effects put in"
    assert np.array_equal(out.adc[:, 1:], base.adc[:, 1:]) and not np.array_equal(out.adc[:, 0], base.adc[:, 0])


def test_the_training_choice_is_one_rule_that_the_loop_benchmark_shares(base):
    """`choose_training_data` is retrain's choice between the two training sets (bench_loop's after for a moved
    disc uses it too: it had kept the twin's model whatever placed the session better, docs/findings.md
    "Session 25: moverows"): the better placer, unless the twin's classes worse by more than one SE."""
    import inspect
    import sys
    from pathlib import Path

    from impactsense.commands.retrain import choose_training_data

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import bench_loop

    def placer(off, acc=1.0):
        m = _Placer(off, acc)
        m.xy_mm = base.xy_mm
        return m

    got = choose_training_data({"measured": placer(3.0), "corrected twin": placer(1.0)}, base)
    assert got["chosen"] == "corrected twin" and got["mae_mm"] == pytest.approx({"measured": 1.5, "corrected twin": 0.5})
    assert choose_training_data({"measured": placer(1.0), "corrected twin": placer(3.0)}, base)["chosen"] == "measured"
    assert choose_training_data({"measured": placer(3.0), "corrected twin": placer(1.0, 0.8)}, base)["chosen"] == "measured"
    assert "choose_training_data(" in inspect.getsource(bench_loop.one_changed)


def test_the_loop_benchmark_trains_a_moved_disc_on_the_drops_retrain_simulates(base, twin, tmp_path):
    """bench_loop's cached twin session with new positions (the declared drops from its cache, the new ones
    appended) holds the drops `loop.twin_training_session` simulates for retrain, bit for bit; a move adds
    `twin_move_positions` new positions, anything else none."""
    import sys
    from pathlib import Path

    from impactsense.loop import TWIN_TRAINING_POSITIONS, twin_move_positions, twin_training_session

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import bench_loop

    ref = R.fit_reference(R.extract(base))
    move = {"effect": "sensor_position", "sensor": 0, "params": {"dx_mm": -5.66, "dy_mm": -5.66}, "significant": True}
    cases = len(np.unique(base.case_id))
    assert twin_move_positions(base, [move]) == TWIN_TRAINING_POSITIONS - cases
    assert twin_move_positions(base, [{**move, "significant": False}]) == 0
    assert twin_move_positions(base, [{"effect": "sensor_gain", "sensor": 0, "params": {"gain": 0.8}}]) == 0
    slow = ref.slowness_us_per_mm
    ours = twin_training_session(base, twin, [move], tmp_path / "retrain", slow, 0, workers=1, new_positions=2)
    bench = bench_loop.cached_twin_session(base, twin, [move], tmp_path / "bench", slow, 0, 1, new_positions=2)
    assert len(ours) == len(bench) == len(base) + 2
    assert np.array_equal(ours.adc, bench.adc) and np.allclose(ours.xy_mm, bench.xy_mm)
    assert np.array_equal(ours.case_id, bench.case_id)
    again = bench_loop.cached_twin_session(base, twin, [move], tmp_path / "bench", slow, 0, 1, new_positions=2)
    assert np.array_equal(again.adc, bench.adc)   # read from its cache
