"""The streaming trigger recovers from a wrong starting baseline (a hit during warm-up, a drifting bias).

The board arms its trigger with the mean of its first pre-trigger window. If the plate is hit inside that
window the mean is off; the trigger must still re-arm once the plate is quiet, and fire on the next hit."""

import numpy as np

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
    assert fired[0] == 0                      # the stale baseline fires at once: one spurious event ...
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
    assert len(fired) == 1 and 100 <= fired[0] <= 102  # one event: hold-off and re-arm ride out the ringing
    assert abs(trig.baseline(0) - 2048.0) < 3.0  # zero-mean ringing averages out of the tracked baseline
