"""The three-sensor position from the core's picks at several onset thresholds (host only).

With one channel out the localiser has three picks for three unknowns (x, y, the origin time): no redundancy,
so each pick's noise goes straight into the position. The picks at other onset thresholds (THREE_LEVEL_FACTORS x
the trained one: as for the level members, a threshold crossing catches one cycle or the next from drop to drop,
and which depends on the threshold) err partly independently; the mean of the three-sensor positions over the
trained threshold and those levels takes part of that noise away (docs/findings.md "A dead channel's three-sensor position from the picks at
several thresholds"). Whether a channel's three-sensor path uses it is chosen at training time by the drops'
out-of-fold positions (three_channel_position.fit_three_channel_positions).
"""

from __future__ import annotations

import numpy as np

from . import _core
from .edge_travel import three_sensor_positions
from .level_members import level_signal

# Multiples of the trained onset threshold (a priori, around level_members' 0.6 / 1.5 / 2, not tuned on a rig):
# more levels average more of the picks' noise; each costs one extract_batch run a drop (docs/findings.md).
THREE_LEVEL_FACTORS = (0.5, 0.6, 0.8, 1.25, 1.5, 2.0)
PICK_KEYS = ("flags", "toa_us", "pick_period", "toa_band_us", "energy")   # what edge_travel's localiser reads
PREFIX = "three_level_"   # Features.raw: PREFIX + key, [R, len(THREE_LEVEL_FACTORS), 4]


def add_level_picks(features, adc: np.ndarray, signal):
    """features with raw[PREFIX + key] set, in place: the core's picks (extract_batch) of each recording at each
    of THREE_LEVEL_FACTORS x the onset threshold; returns features."""
    from .pipeline import as_int16

    a16 = as_int16(adc, signal)
    runs = [_core.extract_batch(a16, level_signal(signal, f).core()) for f in THREE_LEVEL_FACTORS]
    for key in PICK_KEYS:
        features.raw[PREFIX + key] = np.stack([np.asarray(r[key]) for r in runs], 1)
    return features


def has_level_picks(raw: dict) -> bool:
    return all(PREFIX + key in raw for key in PICK_KEYS)


def level_three_positions(raw: dict, signal, channel: int, base_xy_mm: np.ndarray,
                          edge: dict | None = None) -> np.ndarray:
    """[R, 2] the mean of base_xy_mm (the three-sensor position without `channel` at the trained threshold) and
    the three-sensor positions at each level that places the drop (edge: with edge_travel's correction, as
    three_sensor_positions takes it); NaN where base_xy_mm is (the rows the core's three-sensor path places
    stay the same)."""
    base = np.asarray(base_xy_mm, float)
    stack = [base]
    for k in range(len(THREE_LEVEL_FACTORS)):
        level_raw = {key: np.asarray(raw[PREFIX + key])[:, k] for key in PICK_KEYS}
        stack.append(three_sensor_positions(level_raw, signal, channel, edge))
    stack = np.stack(stack, 1)
    placed = np.isfinite(stack).all(2)
    out = np.where(placed[:, :, None], stack, 0.0).sum(1) / np.maximum(placed.sum(1), 1)[:, None]
    out[~np.isfinite(base).all(1)] = np.nan
    return out
