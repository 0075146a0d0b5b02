"""One channel against the other three, without a site map: the label-free check that finds a partly debonded disc
on a model of any rig (docs/findings.md "A debonded channel on a model without a twin").

A debonded disc passes the plate's wave through a low-pass with a gain loss, so at a drop's position its arrival
is weaker than the other three channels' and duller (less of its energy in the third difference). For each
channel c of a drop with four onsets:
- the position: the core's four-channel physics position (what process_event gives; version 1 of the check read
  each channel's cubic at the physics position from the other three channels' picks, edge_travel.three_sensor_positions,
  four more localisations an event, which the board's event budget does not afford; both flag the same drops,
  docs/findings.md "The channel check on the board");
- level_c = log10 E_c - mean over the other three of log10 E_k (E the arrival energy);
- tilt_c = (log10 D3_c - log10 E_c) - the same mean over the other three (D3 the third-difference energy; a gain
  cancels in it, a low-pass does not);
- each less a cubic in that position fitted on the training drops, over the training residuals' robust sd
  (1.4826 MAD, at least SCALE_FLOOR): z_level, z_tilt. The card's "channel_check" keeps the fits and the scales.
The channel's score is the larger of min(-z_level, -z_tilt), large when it is both weaker and duller than the
other three say it should be, and kCheckLevelAlone (1/3) x -z_level: a channel far weaker than the rest whatever its spectrum
(a bond whose cut-off lies above the plate's band, on a thick soft plate, is a gain loss there). Another channel's
debond moves c's ratios up (the mean it is compared with falls); a moderate gain change (x0.75-0.85, the loop's)
moves z_level only and stays under the thresholds, a delay moves neither.

A channel is flagged on an event when its score is the event's largest and exceeds EVENT_SCORE, and over a run when
the median of its last RUN_EVENTS scores (the events in the order given, this one included) exceeds RUN_SCORE. A
flagged event takes the model's three-sensor path: the physics position without the channel and the class of the
other three channels' energies (models.ImpactModel.predict), the report's flag on the channel.

The arithmetic (the ratios, the cubic's terms, the scores, the event and run rule) is the core's (impactcore.h
"the channel check", channelcheck.cpp), which the board runs too; this module fits the cubics and gives it positions.
"""

from __future__ import annotations

import numpy as np

from . import _core
from .edge_travel import three_sensor_positions

EVENT_SCORE = 5.0     # robust sd: clean held-out drops of the measured sessions score <= 2.5 (findings)
RUN_SCORE = 3.0
RUN_EVENTS = 8
SCALE_FLOOR = 0.02    # log10: ~5 % in energy, below which a residual's spread is not taken as the rig's
SITES_PER_TERM = 5    # training sites per term of the cubic below which its own residuals' spread is not trusted
MIN_DROPS = 30        # training drops with four onsets needed to fit the check
CHECK_VERSION = 2     # 2: the cubics read at the four-channel physics position; 1: at the three-sensor ones


def _basis(xy_mm: np.ndarray, signal) -> np.ndarray:
    """The cubic's terms at the positions [R, 10] (the core's channel_check_terms)."""
    return _core.channel_check_terms_batch(np.ascontiguousarray(xy_mm, np.float32), float(signal.plate_x_mm),
                                           float(signal.plate_y_mm)).astype(float)


def _diff3(raw: dict) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(raw["diff_energy"], np.float32)[:, :, -1])


def _ratios(raw: dict) -> tuple[np.ndarray, np.ndarray]:
    """level, tilt [R, 4] (log10, each channel against the mean of the other three; the core's channel_check_ratios)."""
    level, tilt = _core.channel_check_ratios_batch(np.ascontiguousarray(raw["energy"], np.float32), _diff3(raw))
    return level.astype(float), tilt.astype(float)


def checked_rows(raw: dict) -> np.ndarray:
    """Drops the check reads: processed, an onset on every channel (a channel without one takes the dead-channel path)."""
    flags = np.asarray(raw["flags"])
    return (np.asarray(raw["status"]) == _core.STATUS_OK) & ((flags & (_core.FLAG_NO_ONSET | _core.FLAG_DEAD)) == 0).all(1)


def check_positions(raw: dict, signal, check_version: int, phys_xy_mm: np.ndarray | None) -> np.ndarray:
    """The position each channel's cubic reads [R, 4, 2]: the four-channel physics position (version 2), or the
    three-sensor position without that channel (version 1)."""
    if check_version >= 2:
        if phys_xy_mm is None:
            raise ValueError("the channel check (version 2) reads the physics positions: give phys_xy_mm")
        return np.repeat(np.asarray(phys_xy_mm, float)[:, None, :], 4, 1)
    return np.stack([three_sensor_positions(raw, signal, c) for c in range(4)], 1)


def site_ids(xy_mm: np.ndarray) -> np.ndarray:
    """A label per drop, equal for the drops of one site (the training positions to 0.1 mm) [R]."""
    _, ids = np.unique(np.round(np.asarray(xy_mm, float), 1), axis=0, return_inverse=True)
    return ids.ravel()


def robust_sd(resid: np.ndarray) -> float:
    """1.4826 MAD, at least SCALE_FLOOR."""
    return max(1.4826 * float(np.median(np.abs(resid - np.median(resid)))), SCALE_FLOOR)


def out_of_fold_by_site(basis: np.ndarray, value: np.ndarray, sites: np.ndarray) -> np.ndarray:
    """Each drop's residual from the cubic fitted without its site's drops [R]."""
    out = np.empty(len(value))
    for g in np.unique(sites):
        m = sites == g
        out[m] = value[m] - basis[m] @ np.linalg.lstsq(basis[~m], value[~m], rcond=None)[0]
    return out


def check_scale(basis: np.ndarray, value: np.ndarray, resid: np.ndarray, sites: np.ndarray) -> tuple[float, bool]:
    """A ratio's scale and whether it is the out-of-fold one: the training residuals' robust sd, or, when the
    training drops come from fewer than SITES_PER_TERM sites per term of the cubic (the cubic can bend to each
    site's misfit, so its own residuals understate a new site's), the larger of it and the robust sd of the
    residuals out of fold by site (docs/method.md "The channel check's scale")."""
    scale = robust_sd(resid)
    if len(np.unique(sites)) >= SITES_PER_TERM * basis.shape[1]:
        return scale, False
    return max(scale, robust_sd(out_of_fold_by_site(basis, value, sites))), True


def fit_channel_check(raw: dict, signal, phys_xy_mm: np.ndarray, xy_mm: np.ndarray) -> dict | None:
    """The card's "channel_check" from training drops (the core's raw arrays and physics positions), or None with
    fewer than MIN_DROPS drops the check can read or with a channel left out (three channels: too few to compare
    one with the rest)."""
    if any(signal.channel_left_out):
        return None
    rows, xy = checked_rows(raw), check_positions(raw, signal, CHECK_VERSION, phys_xy_mm)
    level, tilt = _ratios(raw)
    sites = site_ids(xy_mm)
    out = {"version": CHECK_VERSION, "event_score": EVENT_SCORE, "run_score": RUN_SCORE, "run_events": RUN_EVENTS,
           "level": [], "tilt": [], "n_drops": [], "n_sites": []}
    for c in range(4):
        ok = rows & np.isfinite(xy[:, c]).all(1) & np.isfinite(level[:, c]) & np.isfinite(tilt[:, c])
        if ok.sum() < MIN_DROPS:
            return None
        basis = _basis(xy[ok, c], signal)
        for name, value in (("level", level), ("tilt", tilt)):
            coef = np.linalg.lstsq(basis, value[ok, c], rcond=None)[0]
            resid = value[ok, c] - basis @ coef
            med = float(np.median(resid))
            scale, oof = check_scale(basis, value[ok, c], resid, sites[ok])
            out[name].append({"coef": [float(v) for v in coef], "median": med, "scale": scale,
                              "scale_out_of_fold": oof})
        out["n_drops"].append(int(ok.sum()))
        out["n_sites"].append(int(len(np.unique(sites[ok]))))
    scores = channel_scores(raw, signal, out, phys_xy_mm)
    out["training_score_max"] = [float(np.nanmax(s)) if np.isfinite(s).any() else None for s in scores.T]
    return out


def _fit_table(check: dict, name: str) -> np.ndarray:
    """A ratio's fits as the core reads them: float32 [4, 12] (the cubic's 10 coefficients, median, scale)."""
    return np.array([list(f["coef"]) + [f["median"], f["scale"]] for f in check[name]], np.float32)


def scores_at(raw: dict, signal, check: dict, xy_mm: np.ndarray) -> np.ndarray:
    """The core's channel_check_scores [R, 4] with channel c's cubic read at xy_mm[:, c] ([R, 4, 2]); NaN where a
    drop is not checked (not processed, a channel without an onset or dead, the position not finite)."""
    flags = np.asarray(raw["flags"], np.uint8).copy()
    flags[np.asarray(raw["status"]) != _core.STATUS_OK] |= np.uint8(_core.FLAG_NO_ONSET)
    return _core.channel_check_scores_batch(
        np.ascontiguousarray(raw["energy"], np.float32), _diff3(raw), np.ascontiguousarray(flags),
        np.ascontiguousarray(xy_mm, np.float32), _fit_table(check, "level"), _fit_table(check, "tilt"),
        float(signal.plate_x_mm), float(signal.plate_y_mm)).astype(float)


def channel_scores(raw: dict, signal, check: dict, phys_xy_mm: np.ndarray | None = None) -> np.ndarray:
    """The scores [R, 4] of the drops (NaN where a drop is not checked), the cubics read where the check's version
    says (check_positions)."""
    return scores_at(raw, signal, check, check_positions(raw, signal, int(check.get("version", 1)), phys_xy_mm))


def flagged_channel(scores: np.ndarray, check: dict) -> np.ndarray:
    """The channel each event flags [R] (-1: none; the core's channel_check_flag over the events in the order
    given): the event's largest score above event_score, or a channel whose median score over the last
    run_events events (this one included) exceeds run_score."""
    return _core.channel_check_flags(np.ascontiguousarray(scores, np.float32), float(check["event_score"]),
                                     float(check["run_score"]), int(check["run_events"])).astype(int)


def flag_events(raw: dict, phys_xy_mm: np.ndarray, use: np.ndarray, left_out: np.ndarray, signal,
                check: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ImpactModel.predict's check over the events in the order given: (flagged [R] bool, the positions of the
    three-sensor path [R, 2] (the core's physics position for a channel without an onset, the three-sensor
    position without the flagged channel otherwise: the board's impactcore::localise_event), the channel each
    three-sensor row leaves out [R]). A flagged row's localiser runs take at most the core's FLAGGED_EVALUATIONS
    normal-equation evaluations (impactcore three_sensor_position)."""
    bad = flagged_channel(channel_scores(raw, signal, check, phys_xy_mm), check)
    three_xy = np.array(phys_xy_mm, float, copy=True)
    rows = np.flatnonzero(use & (bad >= 0))
    for c in np.unique(bad[rows]):
        sel = rows[bad[rows] == c]
        three_xy[sel] = three_sensor_positions({k: v[sel] for k, v in raw.items()}, signal, int(c),
                                               max_evaluations=_core.FLAGGED_EVALUATIONS)
    rows = rows[np.isfinite(three_xy[rows]).all(1)]
    flagged = np.zeros(len(use), bool)
    flagged[rows] = True
    three_xy[~flagged] = np.asarray(phys_xy_mm, float)[~flagged]
    return flagged, three_xy, np.where(flagged, bad, left_out)
