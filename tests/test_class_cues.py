"""The class-cue benchmark's measures (benchmarks/bench_class_cues.py): the second-hit search finds a ball's
second impact and not a glitch, the rebound's flight time, and the class accuracy a log-height error allows."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_class_cues as cues  # noqa: E402

FS = 100_000.0
N = 5000


def _hit(rng, start_s, amplitude, decay_s=2e-3):
    """A hit as four sensors see it: broadband ringing from start_s, decaying with decay_s."""
    t = np.arange(N) / FS
    on = t >= start_s
    ring = rng.normal(0.0, 1.0, (4, N)) * np.exp(-(t - start_s) / decay_s) * on
    return amplitude * ring


def _record(rng, hits):
    x = rng.normal(0.0, 2.0, (4, N))
    for start_s, amplitude in hits:
        x += _hit(rng, start_s, amplitude)
    return np.clip(np.round(2048 + x), 0, 4095).astype(np.uint16)


def test_second_hit_found_at_its_delay_and_a_glitch_is_not():
    rng = np.random.default_rng(0)
    double = _record(rng, [(2e-3, 400.0), (14e-3, 120.0)])    # a bounce 12 ms later, 30 % of the first
    single = _record(rng, [(2e-3, 400.0)])
    glitch = single.copy()
    glitch[2, 3000] = 4000                                      # a one-sample spike on one channel
    glitch[1, 150] = 300                                        # and one before the arrival
    delay = cues.later_burst_ms(np.stack([double, single, glitch]), FS)
    assert delay[0] == pytest.approx(12.0, abs=0.4)            # within two 0.2 ms blocks
    assert np.isnan(delay[1]) and np.isnan(delay[2])


def test_rebound_flight_time_matches_the_record():
    # 2 e v / g equals the window at e_max; a 200 mm drop rebounds inside 50 ms only if e < ~0.124
    for h in (50.0, 200.0):
        e = cues.rebound_e_max(h, 0.05)
        v = np.sqrt(2 * cues.G * h * 1e-3)
        assert 2 * e * v / cues.G == pytest.approx(0.05, rel=1e-12)
    assert cues.rebound_e_max(200.0, 0.05) == pytest.approx(0.124, abs=0.001)


def test_class_accuracy_falls_with_the_log_height_error():
    heights = np.repeat(np.arange(50.0, 251.0, 10.0), 5)
    b, thr = cues.class_boundary_log(heights)
    assert thr == 200.0 and b == pytest.approx(np.log(np.sqrt(190.0 * 200.0)))
    acc = [cues.accuracy_for_sigma(heights, s) for s in (1e-4, 0.03, 0.065, 0.1, 1000.0)]
    assert acc[0] == pytest.approx(1.0)
    assert all(a > b for a, b in zip(acc, acc[1:]))
    assert acc[-1] == pytest.approx(0.5, abs=0.01)
    # the nearest heights sit 0.0256 in log from the boundary: sigma 0.065 leaves each of them ~35 % wrong
    assert 0.93 < cues.accuracy_for_sigma(heights, 0.065) < 0.97
