"""The streaming trigger recovers from a wrong starting baseline (a hit during warm-up, a drifting bias).

The board arms its trigger with the mean of its first pre-trigger window. If the plate is hit inside that
window the mean is off; the trigger must still re-arm once the plate is quiet, and fire on the next hit."""

import numpy as np
import pytest

from impactsense import _core


def _config():
    cfg = _core.TriggerConfig()
    cfg.threshold_counts = 60
    cfg.rearm_counts = 20
    cfg.rearm_quiet_frames = 200
    cfg.holdoff_frames = 500
    cfg.baseline_alpha = 1.0 / 256.0
    return cfg


def _feed(trig, frames):
    return [i for i, f in enumerate(frames) if trig.feed([int(v) for v in f])]


def test_a_baseline_spoiled_by_a_hit_during_warm_up_recovers_and_the_next_hit_fires():
    rng = np.random.default_rng(3)
    n = 12000
    dc = np.array([2010, 2060, 2035, 2080])
    frames = dc + rng.normal(0.0, 2.0, size=(n, 4))
    t = np.arange(n - 8000)
    frames[8000:, 1] += 400.0 * np.exp(-t / 300.0) * np.sin(2 * np.pi * t / 25.0)  # the second hit, ringing down
    trig = _core.Trigger(_config(), 2300.0)  # the warm-up mean of a window that held the first hit
    fired = _feed(trig, np.rint(frames))
    assert fired[0] <= 2                      # the stale baseline fires at once: one spurious event ...
    assert 8000 <= fired[-1] <= 8005          # ... but the trigger re-arms and catches the real hit
    assert len(fired) == 2
    for c in range(4):                        # and its baseline has converged to each channel's bias
        assert abs(trig.baseline(c) - dc[c]) < 5.0 or c == 1


def test_ringing_does_not_drag_the_baseline_or_fire_again_during_hold_off():
    n = 6000
    frames = np.full((n, 4), 2048.0)
    t = np.arange(n - 100)
    frames[100:, 0] += 800.0 * np.exp(-t / 400.0) * np.sin(2 * np.pi * t / 20.0)
    trig = _core.Trigger(_config(), 2048.0)
    fired = _feed(trig, np.rint(frames))
    assert len(fired) == 1 and 100 <= fired[0] <= 104  # one event (its 3rd frame above): hold-off and re-arm ride out the ringing
    assert abs(trig.baseline(0) - 2048.0) < 3.0  # zero-mean ringing averages out of the tracked baseline


def _lab_frames(n, rng, hum=150.0, hz=60.0, noise=4.0, fs=50000.0):
    t = np.arange(n) / fs
    phase = rng.uniform(0, 2 * np.pi, 4)
    return 2048 + rng.normal(0, 25, 4) + hum * np.sin(2 * np.pi * hz * t[:, None] + phase) + rng.normal(0, noise, (n, 4))


def test_hum_noise_and_glitches_never_fire_an_arrival_does():
    """A second of 150-count 60 Hz hum (any phase per channel), 4 counts of noise, per-channel offsets and
    a 1-2 sample glitch of 200..2000 counts every 20 ms on some channel: no firing. The same stream with a
    ringing arrival of 150 counts (2.5 kHz, a 3 ms rise) fires once its envelope passes the threshold."""
    rng = np.random.default_rng(5)
    n = 50000
    frames = _lab_frames(n, rng)
    for i in range(500, n - 2, 1000):
        w = 1 + int(rng.integers(2))
        frames[i:i + w, int(rng.integers(4))] += rng.choice([-1, 1]) * rng.uniform(200, 2000)
    cfg = _core.TriggerConfig()
    start = list(np.rint(frames[:8]).mean(0))      # the board arms with each channel's last frames' mean
    trig = _core.Trigger(cfg, start)
    assert _feed(trig, np.rint(frames[8:])) == []
    t = np.arange(n - 30000)
    frames[30000:, 2] += 150 * np.sin(2 * np.pi * 2500 * t / 50000) * np.minimum(1, t / 150) * np.exp(-t / 5000)
    trig = _core.Trigger(cfg, start)
    fired = _feed(trig, np.rint(frames[8:]))
    assert len(fired) == 1 and 30000 + 60 <= fired[0] + 8 <= 30000 + 90   # 150 t / 150 frames x 0.86 > 60


def test_the_threshold_follows_the_noise_floor():
    """8 x the tracked rms once the noise exceeds threshold / 8; the configured threshold below that."""
    rng = np.random.default_rng(1)
    for sd, want in ((2.0, 60.0), (12.0, 96.0)):
        frames = 2048 + rng.normal(0, sd, (60000, 4))
        trig = _core.Trigger(_core.TriggerConfig(), 2048.0)
        assert _feed(trig, np.rint(frames)) == []
        assert trig.threshold == pytest.approx(want, rel=0.1)
