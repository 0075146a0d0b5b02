"""One channel against the other three, without a site map: the label-free check that finds a partly debonded disc
on a model of any rig (docs/findings.md "A debonded channel on a model without a twin").

A debonded disc passes the plate's wave through a low-pass with a gain loss, so at a drop's position its arrival
is weaker than the other three channels' and duller (less of its energy in the third difference). For each
channel c of a drop with four onsets:
- the position: the core's physics localiser on the other three channels' picks (edge_travel.three_sensor_positions;
  a late, filtered pick on c does not move it);
- level_c = log10 E_c - mean over the other three of log10 E_k (E the arrival energy);
- tilt_c = (log10 D3_c - log10 E_c) - the same mean over the other three (D3 the third-difference energy; a gain
  cancels in it, a low-pass does not);
- each less a cubic in that position fitted on the training drops, over the training residuals' robust sd
  (1.4826 MAD, at least SCALE_FLOOR): z_level, z_tilt. The card's "channel_check" keeps the fits and the scales.
The channel's score is the larger of min(-z_level, -z_tilt), large when it is both weaker and duller than the
other three say it should be, and LEVEL_ALONE x -z_level: a channel far weaker than the rest whatever its spectrum
(a bond whose cut-off lies above the plate's band, on a thick soft plate, is a gain loss there). Another channel's
debond moves c's ratios up (the mean it is compared with falls); a moderate gain change (x0.75-0.85, the loop's)
moves z_level only and stays under the thresholds, a delay moves neither.

A channel is flagged on an event when its score is the event's largest and exceeds EVENT_SCORE, and over a run when
the median of its last RUN_EVENTS scores (the events in the order given, this one included) exceeds RUN_SCORE. A
flagged event takes the model's three-sensor path: the physics position without the channel and the class of the
other three channels' energies (models.ImpactModel.predict), the report's flag on the channel.
"""

from __future__ import annotations

import warnings

import numpy as np

from . import _core
from .edge_travel import three_sensor_positions

EVENT_SCORE = 5.0     # robust sd: clean held-out drops of the measured sessions score <= 2.5 (findings)
RUN_SCORE = 3.0
RUN_EVENTS = 8
LEVEL_ALONE = 1.0 / 3.0   # the level alone flags from 15 robust sd on an event, 9 over a run
SCALE_FLOOR = 0.02    # log10: ~5 % in energy, below which a residual's spread is not taken as the rig's
MIN_DROPS = 30        # training drops with four onsets needed to fit the check
CHECK_VERSION = 1


def _basis(xy_mm: np.ndarray, plate_x_mm: float, plate_y_mm: float) -> np.ndarray:
    """The cubic in the position (scaled to -1..1 over the plate): [R, 10]."""
    x = np.asarray(xy_mm, float)[:, 0] / plate_x_mm * 2.0 - 1.0
    y = np.asarray(xy_mm, float)[:, 1] / plate_y_mm * 2.0 - 1.0
    return np.stack([x ** i * y ** j for i in range(4) for j in range(4 - i)], 1)


def _ratios(raw: dict) -> tuple[np.ndarray, np.ndarray]:
    """level, tilt [R, 4] (log10, each channel against the mean of the other three)."""
    log_e = np.log10(np.maximum(np.asarray(raw["energy"], float), 1e-30))
    log_t = np.log10(np.maximum(np.asarray(raw["diff_energy"], float)[:, :, -1], 1e-30)) - log_e

    def against_others(a):
        return a - (a.sum(1, keepdims=True) - a) / 3.0

    return against_others(log_e), against_others(log_t)


def checked_rows(raw: dict) -> np.ndarray:
    """Drops the check reads: processed, an onset on every channel (a channel without one takes the dead-channel path)."""
    flags = np.asarray(raw["flags"])
    return (np.asarray(raw["status"]) == _core.STATUS_OK) & ((flags & (_core.FLAG_NO_ONSET | _core.FLAG_DEAD)) == 0).all(1)


def _inputs(raw: dict, signal) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(rows checked [R], three-sensor positions [R, 4, 2], level, tilt)."""
    rows = checked_rows(raw)
    xy = np.stack([three_sensor_positions(raw, signal, c) for c in range(4)], 1)
    level, tilt = _ratios(raw)
    return rows, xy, level, tilt


def fit_channel_check(raw: dict, signal) -> dict | None:
    """The card's "channel_check" from training drops (the core's raw arrays), or None with fewer than MIN_DROPS
    drops the check can read or with a channel left out (three channels: too few to compare one with the rest)."""
    if any(signal.channel_left_out):
        return None
    rows, xy, level, tilt = _inputs(raw, signal)
    out = {"version": CHECK_VERSION, "event_score": EVENT_SCORE, "run_score": RUN_SCORE, "run_events": RUN_EVENTS,
           "level": [], "tilt": [], "n_drops": []}
    for c in range(4):
        ok = rows & np.isfinite(xy[:, c]).all(1) & np.isfinite(level[:, c]) & np.isfinite(tilt[:, c])
        if ok.sum() < MIN_DROPS:
            return None
        basis = _basis(xy[ok, c], signal.plate_x_mm, signal.plate_y_mm)
        for name, value in (("level", level), ("tilt", tilt)):
            coef = np.linalg.lstsq(basis, value[ok, c], rcond=None)[0]
            resid = value[ok, c] - basis @ coef
            med = float(np.median(resid))
            scale = max(1.4826 * float(np.median(np.abs(resid - med))), SCALE_FLOOR)
            out[name].append({"coef": [float(v) for v in coef], "median": med, "scale": scale})
        out["n_drops"].append(int(ok.sum()))
    scores = channel_scores(raw, signal, out)[0]
    out["training_score_max"] = [float(np.nanmax(s)) if np.isfinite(s).any() else None for s in scores.T]
    return out


def channel_scores(raw: dict, signal, check: dict) -> tuple[np.ndarray, np.ndarray]:
    """(scores [R, 4], NaN where a drop is not checked; the three-sensor positions [R, 4, 2])."""
    rows, xy, level, tilt = _inputs(raw, signal)
    scores = np.full(level.shape, np.nan)
    for c in range(4):
        ok = rows & np.isfinite(xy[:, c]).all(1)
        if not ok.any():
            continue
        basis = _basis(xy[ok, c], signal.plate_x_mm, signal.plate_y_mm)
        z = []
        for name, value in (("level", level), ("tilt", tilt)):
            fit = check[name][c]
            z.append((value[ok, c] - basis @ np.asarray(fit["coef"]) - fit["median"]) / fit["scale"])
        scores[ok, c] = np.maximum(np.minimum(-z[0], -z[1]), LEVEL_ALONE * -z[0])
    return scores, xy


def flagged_channel(scores: np.ndarray, check: dict) -> np.ndarray:
    """The channel each event flags [R] (-1: none): the event's largest score above event_score, or a channel whose
    median score over the last run_events events (this one included, in the order given) exceeds run_score."""
    n = len(scores)
    out = np.full(n, -1)
    filled = np.where(np.isfinite(scores), scores, -np.inf)
    top = np.argmax(filled, axis=1)
    top_score = filled[np.arange(n), top]
    event = np.isfinite(top_score) & (top_score > float(check["event_score"]))
    out[event] = top[event]
    window = int(check["run_events"])
    for k in np.flatnonzero(~event & checked_any(scores)):
        recent = scores[max(0, k - window + 1):k + 1]
        if len(recent) < (window + 1) // 2:
            continue
        with warnings.catch_warnings():   # a channel without a score in the window: NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(recent, axis=0)
        if np.isfinite(med).any() and np.nanmax(med) > float(check["run_score"]):
            c = int(np.nanargmax(med))
            if np.isfinite(scores[k, c]):
                out[k] = c
    return out


def checked_any(scores: np.ndarray) -> np.ndarray:
    return np.isfinite(scores).any(1)


def flag_events(raw: dict, phys_xy_mm: np.ndarray, use: np.ndarray, left_out: np.ndarray, signal,
                check: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ImpactModel.predict's check over the events in the order given: (flagged [R] bool, the positions of the
    three-sensor path [R, 2] (the core's physics position for a channel without an onset, the three-sensor
    position without the flagged channel otherwise), the channel each three-sensor row leaves out [R])."""
    scores, loo_xy = channel_scores(raw, signal, check)
    bad = flagged_channel(scores, check)
    rows = np.flatnonzero(use & (bad >= 0))
    rows = rows[np.isfinite(loo_xy[rows, bad[rows]]).all(1)]
    flagged = np.zeros(len(use), bool)
    flagged[rows] = True
    three_xy = np.array(phys_xy_mm, float, copy=True)
    three_xy[rows] = loo_xy[rows, bad[rows]]
    return flagged, three_xy, np.where(flagged, bad, left_out)
