"""The calibration as a list of stages (issue 21): each stage's result cached under its key, the stages in
docs/method.md's order, the optional ones run only when asked, and a resumed run that gives the same CAL.json."""

from __future__ import annotations

import json
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from impactsense.calibration import pipeline
from impactsense.calibration.cache import StageClock
from impactsense.calibration.options import CalibrateOptions
from impactsense.calibration.stages import STAGES, Stage
from impactsense.data import load_session

from test_calibrate import SESSION1, _session, _small_opts, _standin_clean, _standin_noisy, _truth

DOCS = Path(__file__).resolve().parents[1] / "docs" / "method.md"


def _options(**opts):
    """calibrate's defaults (every field a stage may read) with these set; a stage's own test field may be added."""
    return SimpleNamespace(**{**vars(CalibrateOptions()), **opts})


def _problem(tmp_path, **opts):
    stem = tmp_path / "CAL"
    return SimpleNamespace(opts=_options(fem=True, **opts), clock=StageClock(), stage_results={},
                           cache=lambda tag: Path(f"{stem}.{tag}"), applied=[])


def test_a_cached_stage_is_read_under_its_key_and_computed_again_under_another(tmp_path):
    calls = []

    def run(problem, key):
        calls.append(key)
        return {"value": problem.opts.value * 2, "key_seen": key}

    stage = Stage("double", run, lambda problem, res: problem.applied.append(res),
                  key=lambda problem: f"k{problem.opts.value}", cache="double.json")
    first = _problem(tmp_path, value=3)
    stage(first)
    assert calls == ["k3"] and first.applied == [{"value": 6, "key_seen": "k3"}]
    assert json.loads((tmp_path / "CAL.double.json").read_text())["key"] == "k3"
    assert "double" in first.clock.seconds and first.stage_results["double"]["value"] == 6
    again = _problem(tmp_path, value=3)
    stage(again)
    assert calls == ["k3"] and again.applied == first.applied          # read back, not run
    other = _problem(tmp_path, value=4)
    stage(other)
    assert calls == ["k3", "k4"] and other.applied == [{"value": 8, "key_seen": "k4"}]
    # a stage the run does not want is neither run nor clocked; without the FEM only wanted-anyway stages run
    no_fem = _problem(tmp_path, value=5)
    no_fem.opts.fem = False
    stage(no_fem)
    assert calls == ["k3", "k4"] and no_fem.applied == [] and no_fem.clock.seconds == {}


def test_the_stages_are_docs_method_order_and_the_optional_ones_run_only_when_asked():
    section = DOCS.read_text().split("## 4. Calibration", 1)[1].split("\n## ", 1)[0]
    documented = re.findall(r"\*\*([a-z_]+)\*\*", section)
    assert [s.name for s in STAGES] == documented
    by_name = {s.name: s for s in STAGES}

    def wants(name, **opts):
        base = dict(fem=True, support="rig", disc_bond="off")
        return by_name[name].wanted(SimpleNamespace(opts=_options(**{**base, **opts})))
    assert not wants("support") and wants("support", support="auto") and not wants("support", support="clamped")
    assert not wants("disc_bond") and wants("disc_bond", disc_bond="fit")
    assert wants("plate_grid", fem=False) and not wants("plate_fem", fem=False) and not wants("design", fem=False)


@pytest.fixture(scope="module")
def standin_session(tmp_path_factory):
    rig = load_session(SESSION1).rig
    return _session(tmp_path_factory.mktemp("standin"), rig, _standin_noisy, _truth(rig), n_cases=8, reps=2)


def test_a_resumed_calibration_gives_the_same_cal_json(standin_session, tmp_path):
    """The plate grid alone (--no-fem, ~2 s): a second run reads the grid from its cache and writes the same
    CAL.json but for the wall and CPU times."""
    out = tmp_path / "cal" / "CAL.json"
    first = json.loads(json.dumps(pipeline.calibrate(standin_session, out, _small_opts(fem=False, e_step_mpa=100.0),
                                                     simulate=_standin_clean)))
    second = pipeline.calibrate(standin_session, out, _small_opts(fem=False, e_step_mpa=100.0), simulate=_standin_clean)
    assert second["wall_time_s"]["plate_grid"] < max(0.5 * first["wall_time_s"]["plate_grid"], 0.2)
    saved = json.loads(out.read_text())
    for cal in (first, saved):
        for k in ("wall_time_s", "cpu_time_s", "stage_compute_time_s"):
            cal.pop(k)
    assert saved == first
    assert list(first)[:3] == ["format", "data", "data_sha256"] and first["pzt_damping"]["skipped"]
    assert first["fitted"]["e_pa"] == pytest.approx(first["plate"]["E_mpa"] * 1e6)


def test_the_stage_clock_counts_cpu_seconds_not_waiting():
    """A stage that computes is charged its CPU seconds; one that waits (a loaded machine, a sleep) is not:
    CAL.json's cpu_time_s is what the stage costs whatever else runs."""
    import time

    clock = StageClock()

    def busy(seconds):
        t = time.process_time()
        while time.process_time() - t < seconds:
            sum(range(1000))

    clock.run("busy", busy, 0.3)
    clock.run("idle", time.sleep, 0.3)
    assert clock.cpu["busy"] >= 0.25 and clock.seconds["busy"] >= 0.25
    assert clock.cpu["idle"] < 0.1 <= 0.25 <= clock.seconds["idle"]
