"""benchmarks/bench_pick_relative.py's pieces: the read-back picks, the per-channel threshold through the core's
channel gain, the earliest edge image."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_pick_relative as bpr  # noqa: E402

from impactsense.signal import SignalConfig  # noqa: E402


def test_half_cycle_start_is_the_zero_before_the_crossing():
    """A 10-sample sine with its zeros at 3.3 + 5k: a crossing inside the positive half cycle after 13.3 reads
    back to 13.3 (linear interpolation of a sine across its zero: < 0.01 sample here)."""
    i = np.arange(60)
    x = 500.0 * np.sin(2 * np.pi * (i - 3.3) / 10.0)
    assert abs(bpr.half_cycle_start(x, 14.2) - 13.3) < 0.01
    assert abs(bpr.half_cycle_start(-x, 19.1) - 18.3) < 0.01     # a negative half cycle the same way


def test_first_extremum_is_a_quarter_period_after_the_onset(synth):
    """A 10 kHz burst (10 samples a period) starting at 300: the first peak is at 302.5 +- half a sample."""
    x = synth([300.0] * 4, n=1000, amp=600.0, freq_hz=10000.0)[0].astype(float) - 2048.0
    ip = bpr.first_extremum(x, 300.5)
    assert abs(ip - 302.5) <= 0.5


def test_per_channel_threshold_is_the_fixed_threshold_pick(synth):
    """The channel gain carries a per-channel threshold: 30 / 60 counts on alternate channels give the core's
    picks at 30 and at 60 counts on those channels (the same float: the threshold is threshold x gain)."""
    adc = synth([300.0, 340.0, 380.0, 420.0], n=2000, amp=300.0, freq_hz=15000.0, noise=1.0)[None]
    cfg = SignalConfig()
    toa, _ = bpr.per_channel_threshold(adc, cfg, np.array([[30.0, 60.0, 30.0, 60.0]]))
    at30 = bpr.core_raw(adc, cfg, onset_threshold_counts=30.0, aic_blend=0.0)["toa_us"][0]
    at60 = bpr.core_raw(adc, cfg, onset_threshold_counts=60.0, aic_blend=0.0)["toa_us"][0]
    assert at60[1] > at30[1]                                     # the two thresholds catch different samples
    np.testing.assert_allclose(toa[0], [at30[0], at60[1], at30[2], at60[3]], atol=1e-3)


def test_earliest_reflection_is_twice_the_impacts_edge_distance_behind_it():
    """An impact 50 mm from the left edge, on the line from a sensor at 100 mm to that edge: its image trails
    the direct path by 100 mm, 50 us at 2 mm/us (the other edges are further)."""
    gap = bpr.earliest_reflection_us(np.array([[50.0, 150.0]]), np.array([[100.0, 150.0]] * 4), 400.0, 300.0,
                                     (1.0, 0.0, 1.0), 2.0)
    np.testing.assert_allclose(gap, 50.0, atol=1e-9)
