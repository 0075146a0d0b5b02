"""Self-calibration of the channels' ToA constants from unlabelled picks (benchmarks/selfcal_study.py: a measured study, not in the package).

Picks made by the localiser's own travel law (the default rig's four corner discs, its velocity) at random
positions with a per-pick noise, so what is asserted is the joint fit's identifiability, not the core's picks.
"""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from selfcal_study import MODE_SE_US, offsets_from_picks  # noqa: E402
from impactsense.signal import SignalConfig  # noqa: E402
from impactsense.travel import travel_distances  # noqa: E402


def _picks(rng, cfg, n, noise_us, delay_us=(0.0, 0.0, 0.0, 0.0)):
    """(ToA, slowness factors, start positions) of n drops: the law plus an origin time, the delays, noise;
    the start is the truth plus 5 mm of scatter (a localiser's first answer)."""
    xy = np.column_stack([rng.uniform(20, cfg.plate_x_mm - 20, n), rng.uniform(20, cfg.plate_y_mm - 20, n)])
    toa = (travel_distances(xy, cfg.sensor_xy_mm) / cfg.velocity_mm_per_us + rng.uniform(50, 80, (n, 1))
           + np.asarray(delay_us)[None] + rng.normal(0, noise_us, (n, 4)))
    return toa, np.ones((n, 4)), xy + rng.normal(0, 5.0, (n, 2))


def test_a_constant_delay_on_one_channel_is_recovered_without_labels():
    cfg = SignalConfig()
    rng = np.random.default_rng(3)
    delay = np.array([0.0, 0.0, 5.0, 0.0])
    out = offsets_from_picks(_picks(rng, cfg, 300, 1.0), _picks(rng, cfg, 300, 1.0, delay), cfg)
    want = delay - delay.mean()          # a constant on every channel is an origin time: centred
    assert out.n_modes == 3              # at 1 us of noise and 300 drops every combination is determined
    assert np.max(np.abs(np.asarray(out.offset_us) - want)) < 1.0
    assert out.applied


def test_no_offset_applied_on_an_unchanged_session_and_poorly_determined_combinations_left_out():
    cfg = SignalConfig()
    rng = np.random.default_rng(4)
    out = offsets_from_picks(_picks(rng, cfg, 120, 5.0), _picks(rng, cfg, 120, 5.0), cfg)
    assert not out.applied
    assert np.all(np.asarray(out.se_us) < 2 * MODE_SE_US)   # what is kept is well determined
    assert np.max(np.abs(out.offset_us)) < 3 * MODE_SE_US
