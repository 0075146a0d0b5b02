"""White noise and the core's onset (docs/findings.md "Session 22: noiseonset"): a threshold crossing well above
the noise repeats under it (the arrival rises by hundreds of counts a sample there), while the noise-relative
threshold moves the pick to a later cycle. The bundled rig's recorded drops, with loop_sessions' white noise."""

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_noise_picks  # noqa: E402

WHITE = {"effect": "noise", "sensor": None, "params": {"noise_counts_rms": 6.4}}


def _drops(n=40):
    from impactsense.data import bundled_session_path, load_session

    s = load_session(bundled_session_path("session-1"))
    return SimpleNamespace(adc=np.asarray(s.adc)[:n], rig=s.rig)


def test_a_crossing_well_above_the_noise_repeats_and_the_noise_floor_threshold_catches_a_later_cycle():
    drops = _drops()
    held = bench_noise_picks.scatter(drops, WHITE, 1, {"onset_threshold_counts": 50.0, "aic_blend": 0.0}, same=True)
    rig = bench_noise_picks.scatter(drops, WHITE, 1, {})
    # 50 counts is ~8 x the added noise: the crossing moves by a fraction of a 10 us sample (2.0 us DToA spread
    # on the session's 240 drops); the rig's threshold rides up to 5 x the noise rms (~32 counts) from its 10
    assert np.all(np.abs(rig["shift_us"]) > 10.0)
    assert np.all(np.abs(held["shift_us"]) < 2.0)
    assert np.mean(held["dtoa_sd_us"]) < 6.0
    assert np.mean(rig["dtoa_sd_us"]) > 2.0 * np.mean(held["dtoa_sd_us"])
    assert rig["threshold_counts"] > 25.0 and held["threshold_counts"] == 50.0
