"""Position members from the core's picks at other onset thresholds (host only).

A threshold crossing catches one cycle of a slowly growing, dispersive arrival or the next from drop to drop, and
which one depends on the threshold: the physics positions the core gives at a few multiples of the trained onset
threshold err partly independently. Each becomes a position member with its forest pair (position_members.py), and
the reported position is the mean over every member that placed the drop; on a stiff plate the drops' own pick
noise, not the site, dominates the error, and the mean takes part of it away (docs/findings.md "Picks at other
onset thresholds"). The localiser's constants stay the trained ones (the forests learn each level's bias); kept
by the training drops' out-of-fold positions (correction_scale.choose_level_members).
"""

from __future__ import annotations

import numpy as np

from . import _core
from .signal import SignalConfig

# Multiples of the trained onset threshold: one below it, two above (a priori, not tuned on a rig).
LEVEL_FACTORS = (0.6, 1.5, 2.0)
LEVEL_MEMBERS = tuple(f"onset_x{f:g}" for f in LEVEL_FACTORS)
LEVEL_KEY = "level_xy_mm"      # Features.raw: [R, len(LEVEL_FACTORS), 2], NaN where a level placed no drop


def level_signal(signal: SignalConfig, factor: float) -> SignalConfig:
    """signal with its onset threshold times factor (nothing else changed)."""
    out = SignalConfig.from_dict(signal.to_dict())
    out.onset_threshold_counts = float(signal.onset_threshold_counts) * float(factor)
    return out


def level_xy(adc: np.ndarray, signal: SignalConfig) -> np.ndarray:
    """[R, len(LEVEL_FACTORS), 2] the core's physics position of each recording at each level (process_event)."""
    from .pipeline import as_int16

    a16 = as_int16(adc, signal)
    out = []
    for factor in LEVEL_FACTORS:
        trial = level_signal(signal, factor)
        ev = _core.process_batch(a16, trial.core(), trial.localiser())
        xy = np.asarray(ev["phys_xy_mm"], float)
        ok = (np.asarray(ev["status"]) == _core.STATUS_OK) & np.isfinite(xy).all(1)
        out.append(np.where(ok[:, None], xy, np.nan))
    return np.stack(out, 1)


def add_level_positions(features, adc: np.ndarray, signal: SignalConfig, members=LEVEL_MEMBERS):
    """features (pipeline.Features of adc under signal) with raw[LEVEL_KEY] set, in place, when members names a
    level member (a model's members: only a model that has them pays the extra core runs); returns features."""
    if any(n in members for n in LEVEL_MEMBERS):
        features.raw[LEVEL_KEY] = level_xy(adc, signal)
    return features


def level_positions(features) -> dict[str, np.ndarray] | None:
    """LEVEL_MEMBERS' positions [R, 2] (NaN where that level did not place the drop); None when the features carry
    none (featurize alone: ImpactModel.featurize adds them)."""
    xy = features.raw.get(LEVEL_KEY)
    if xy is None:
        return None
    xy = np.asarray(xy, float)
    return {name: xy[:, k] for k, name in enumerate(LEVEL_MEMBERS)}
