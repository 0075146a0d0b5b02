"""A delay's size (`effects.channel_delay.ChannelDelay.fit`) on the threshold and band picks together.

On a plate whose first cycles arrive near the Nyquist rate the threshold picks do not follow a delay that is
not a whole number of samples on every drop: measured on the second rig's FEM twin, picks within 60 mm of the
delayed disc read +1.0 / +1.6 us for a -7.5 us delay and single drops scatter by -17 .. +15 us (docs/findings.md,
"Sub-sample delays" and "Session 18: delaysize"). The band picks (a well-sampled band: `band_timing`) follow
the delay whole. Synthetic drops of `test_move_or_delay` (four corner discs, 40 cases x 3): the delayed
channel's threshold picks do not follow the delay within 100 mm of the disc nor on one drop in ten elsewhere,
and scatter with heavy tails (Student t, 3 dof, scale 4 us); the band picks carry it whole."""

from __future__ import annotations

import numpy as np

from impactsense.effects import channel_delay
from test_move_or_delay import SENSORS, _band_reference, _features, _with_band

DELAY_US = -7.5


def _session(seed: int):
    rng = np.random.default_rng(seed)
    F = _with_band(rng, _features(rng), delay_us=DELAY_US)
    d = np.hypot(F.x_mm - SENSORS[2, 0], F.y_mm - SENSORS[2, 1])
    follows = (d > 100.0) & (rng.uniform(size=len(d)) >= 0.1)
    F.toa_us[:, 2] += np.where(follows, DELAY_US, 0.0) + 4.0 * rng.standard_t(3, len(d))
    ref = _band_reference()
    ref.band["sigma_us"] = float(np.hypot(4.0, 4.0))   # the band picks' reference scale (case + drop noise)
    return ref, F


def _sizes(both: bool, monkeypatch) -> np.ndarray:
    monkeypatch.setattr(channel_delay, "BOTH_PICK_SETS", both)
    out = []
    for seed in range(12):
        ref, F = _session(seed)
        out.append(channel_delay.ChannelDelay().fit(ref, F, 2)["delay_us"])
    return np.array(out)


def test_a_sub_sample_delay_is_sized_on_both_pick_sets(monkeypatch):
    """The threshold picks alone under-read the delay by more than the 1 us tolerance on average over 12 draws
    (measured 1.24 us); both pick sets together read it within it (0.91 us) and closer on at least 9 of the 12
    draws (measured 10)."""
    old = np.abs(_sizes(False, monkeypatch) - DELAY_US)
    new = np.abs(_sizes(True, monkeypatch) - DELAY_US)
    assert old.mean() > 1.0, old
    assert new.mean() < 1.0, new
    assert np.sum(new < old) >= 9, (old, new)


def test_a_whole_delay_is_read_without_bias_on_both_pick_sets(monkeypatch):
    """Where every threshold pick follows the delay, both pick sets together read it without bias: the mean
    error over 12 draws within 0.5 us (measured -0.12; the draws' own scatter ~0.7 us at this noise) and the
    mean absolute error under 1 us (measured 0.59; the threshold picks alone 0.69)."""
    monkeypatch.setattr(channel_delay, "BOTH_PICK_SETS", True)
    err = []
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        F = _with_band(rng, _features(rng, delay_us=DELAY_US), delay_us=DELAY_US)
        ref = _band_reference()
        ref.band["sigma_us"] = float(np.hypot(4.0, 4.0))
        err.append(channel_delay.ChannelDelay().fit(ref, F, 2)["delay_us"] - DELAY_US)
    assert abs(np.mean(err)) < 0.5, err
    assert np.mean(np.abs(err)) < 1.0, err
