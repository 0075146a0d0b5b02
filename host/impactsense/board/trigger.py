"""The board's trigger threshold, chosen from the model's own training drops (export writes it for the firmware).

The firmware's default threshold (impactcore.h TriggerConfig, board counts) suits a plate whose first cycles are
large; on a plate whose first cycles are weak it fires on a later, larger cycle (a late capture: the earliest
arrival runs into the core's baseline segment) or not at all. choose_trigger keeps the default unless a lower
threshold captures more of the training drops on time, with a floor above the captures' quiet start (its noise
and hum) and the core's own arrival threshold (docs/method.md "The board's trigger threshold").
"""

from __future__ import annotations

import numpy as np

from .. import _core
from ..pipeline import featurize
from ..signal import counts_per_core_count
from .capture import LATE_TRIGGER_FRAMES, TRIGGER_KEY, board_captures

# Candidates: the default threshold x 2^(-k/2), rounded to whole board counts (what the link's set_threshold sends).
TRIGGER_STEPS = 9
# The floor: this many robust sd (1.4826 x MAD) of the quiet start of the captures (their baseline segment, noisiest
# channel, median drop) above which noise and hum do not reach; and never below the core's onset threshold.
TRIGGER_FLOOR_SD = 5.0


def quiet_sd(caps: np.ndarray, baseline_samples: int) -> float:
    """The captures' quiet-start noise (counts of the captures): per drop the largest channel's robust sd of its
    baseline segment, the median over drops."""
    q = np.asarray(caps, float)[:, :, :int(baseline_samples)]
    mad = np.median(np.abs(q - np.median(q, axis=2, keepdims=True)), axis=2)
    return float(np.median(1.4826 * mad.max(axis=1)))


def missed_or_late(rows: np.ndarray, caps: np.ndarray, sig, wanted: np.ndarray) -> dict:
    """Of the drops `wanted` (row indices): how many the captures (rows: their drop) miss, take late (the first
    onset within LATE_TRIGGER_FRAMES of the baseline segment's end) or take more than once (a second trigger)."""
    on = np.isin(rows, wanted)
    if not on.any():
        return {"missed": int(len(wanted)), "late": 0, "extra": 0}
    first = np.asarray(featurize(caps[on], sig).raw["toa_threshold"], float)
    first = np.where(np.isfinite(first) & (first >= 0), first, np.inf).min(1)
    late = np.isfinite(first) & (first < int(sig.baseline_samples) + LATE_TRIGGER_FRAMES)
    got = np.unique(rows[on])
    return {"missed": int(len(wanted) - len(got)), "late": int(np.count_nonzero(late)),
            "extra": int(np.count_nonzero(on) - len(got))}


def choose_trigger(session, train_rows, fs_hz: int = 50000, signal: dict | None = None, first=None):
    """(threshold in board counts or None for the firmware's default, record for the model card's board_trigger).

    The candidates run from the default down (TRIGGER_STEPS, halving every two) to the floor (TRIGGER_FLOOR_SD
    robust sd of the default captures' quiet start, and the core's onset threshold, in board counts); each is the
    emulated board's trigger on the session (board_captures). The chosen one has the fewest training drops missed,
    late or captured twice, the largest such; the search stops at the first with none. first: board_captures'
    output at the default (reused)."""
    default = float(_core.TriggerConfig().threshold_counts)
    scale = counts_per_core_count(session.rig)
    wanted = np.asarray(train_rows, int)
    caps, rows, sig = first if first is not None else board_captures(session, fs_hz, signal)
    floor = max(TRIGGER_FLOOR_SD * quiet_sd(caps, sig.baseline_samples), float(sig.onset_threshold_counts)) / scale
    trials = []
    for k in range(TRIGGER_STEPS):
        thr = default if k == 0 else float(np.round(default * 2.0 ** (-k / 2.0)))
        if k and thr < floor:
            break
        if k:
            caps, rows, sig = board_captures(session, fs_hz, {**(signal or {}), TRIGGER_KEY: thr})
        count = missed_or_late(rows, caps, sig, wanted)
        trials.append({"board_counts": thr, **count})
        if sum(count.values()) == 0:
            break
    bad = [t["missed"] + t["late"] + t["extra"] for t in trials]
    best = trials[int(np.argmin(bad))]   # argmin: the first (largest threshold) of the fewest
    record = {"default_counts": default, "floor_counts": round(floor, 2), "trials": trials}
    return (None if best["board_counts"] == default else best["board_counts"]), record


def captures_at_chosen_trigger(session, train_rows, fs_hz: int = 50000, capture=board_captures):
    """capture's (board_captures') output for the session at the threshold choose_trigger chooses on the training
    rows: (captures, rows, SignalConfig, the chosen threshold or None, choose_trigger's record)."""
    first = capture(session, fs_hz)
    chosen, record = choose_trigger(session, train_rows, fs_hz, first=first)
    caps, rows, sig = first if chosen is None else capture(session, fs_hz, {TRIGGER_KEY: chosen})
    return caps, rows, sig, chosen, record
