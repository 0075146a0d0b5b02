"""Each channel's arrival pick corrected by what its own signal says, for the three-sensor position (host only).

With one channel out the localiser has three picks for three unknowns: a pick that catches a later cycle moves the
position by centimetres, and the same drop site repeats that error on every drop (docs/findings.md "Session 18:
threesens"). Four picks of the training drops at their known positions give each pick's error (its travel
residual at the truth, less the median over the four channels: the origin time); a forest per pick set learns it
from the channel's own signal alone (`channel_inputs`: its picks at the other onset levels relative to its pick,
its first peak and peak, its energy, pick period, band-minus-threshold lag, AIC-minus-threshold lag, and its
distance from the drop's physics position). Nothing reads another channel, so the same forest corrects the picks
of any three channels. The three-sensor path then has two more candidate positions per pick set (the localiser
re-run on the corrected picks) that three_channel_position.py weighs against its others (`stack_weights`).
"""

from __future__ import annotations

import numpy as np
from sklearn.ensemble import RandomForestRegressor
from sklearn.model_selection import GroupKFold

from .edge_travel import _localise, _metric, pick_set_arrivals
from .three_level_positions import PREFIX, THREE_LEVEL_FACTORS
from .travel import travel_distances

PICK_SETS = ("threshold", "band")
PICK_TREES = 100
PICK_LEAF = 3
PICK_FOLDS = 5
N_INPUTS = len(THREE_LEVEL_FACTORS) + 7   # channel_inputs' columns
MISSING = -99.0   # a missing input (no band pick, no level pick): a value no real one takes


def channel_inputs(raw: dict, signal, xy_mm: np.ndarray, pick_set: str) -> np.ndarray:
    """[R, 4, N_INPUTS] each channel's inputs, from its own picks and signal and the drop's position xy_mm
    (the physics position the row has): the level picks (raw's three_level_toa_us) less its pick, log first
    peak, log peak / first peak, log energy, pick period, band pick less its pick, AIC pick less the threshold
    crossing, its distance from xy_mm in the pick set's travel metric."""
    toa = np.asarray(raw["toa_us"], float)
    levels = np.asarray(raw[PREFIX + "toa_us"], float) - toa[:, None]
    first = np.log(np.maximum(np.asarray(raw["first_peak"], float), 1.0))
    peak = np.log(np.maximum(np.asarray(raw["peak"], float), 1.0))
    energy = np.log(np.maximum(np.asarray(raw["energy"], float), 1e-9))
    period = np.asarray(raw["pick_period"], float)
    lag = np.asarray(raw["toa_band_us"], float) - toa
    aic = np.asarray(raw["toa_aic"], float) - np.asarray(raw["toa_threshold"], float)
    dist = travel_distances(np.nan_to_num(np.asarray(xy_mm, float)), signal.sensor_xy_mm, _metric(signal, pick_set))
    own = np.stack([first, peak - first, energy, period, lag, aic, dist], 2)
    X = np.concatenate([levels.transpose(0, 2, 1), own], 2)
    return np.where(np.isfinite(X), X, MISSING)


def pick_errors(raw: dict, signal, xy_mm: np.ndarray, pick_set: str) -> np.ndarray:
    """[R, 4] each pick's travel residual at the true positions xy_mm less the drop's median over its picks
    (NaN where a channel has no pick)."""
    toa, use, scale, v = pick_set_arrivals(raw, signal, pick_set)
    resid = toa - travel_distances(np.asarray(xy_mm, float), signal.sensor_xy_mm, _metric(signal, pick_set)) * scale / v
    resid = np.where(use, resid, np.nan)
    centre = np.full((len(resid), 1), np.nan)
    some = np.isfinite(resid).any(1)   # a drop with no pick in this set (e.g. no band pick on a low drop): NaN
    centre[some] = np.nanmedian(resid[some], 1, keepdims=True)
    return resid - centre


def _forest(X: np.ndarray, y: np.ndarray, seed: int, trees: int = PICK_TREES):
    return RandomForestRegressor(trees, min_samples_leaf=PICK_LEAF, max_features=0.5, random_state=seed,
                                 n_jobs=1).fit(X, y)


def fit_pick_corrections(raw: dict, xy_mm: np.ndarray, signal, position_xy_mm: np.ndarray, sites: np.ndarray,
                         seed: int = 0) -> tuple[dict, dict]:
    """({pick set: forest} learning each pick's error from channel_inputs, {pick set: [R, 4] the training drops'
    out-of-fold corrections (folds grouped by site)}) from drops at known positions xy_mm with four picks;
    position_xy_mm: their physics position (channel_inputs' distance). A pick set without picks is left out."""
    forests, oof = {}, {}
    for ps in PICK_SETS:
        if ps == "band" and not (float(signal.band_pick_hz) > 0 and float(signal.band_velocity_mm_per_us) > 0):
            continue
        X = channel_inputs(raw, signal, position_xy_mm, ps)
        y = pick_errors(raw, signal, xy_mm, ps)
        flat_x, flat_y, groups = X.reshape(-1, X.shape[2]), y.ravel(), np.repeat(sites, 4)
        ok = np.isfinite(flat_y)
        if ok.sum() < 40:
            continue
        out = np.zeros(len(flat_y))
        for fit_rows, held in GroupKFold(PICK_FOLDS).split(flat_x, groups=groups):
            fit_rows = fit_rows[ok[fit_rows]]
            out[held] = _forest(flat_x[fit_rows], flat_y[fit_rows], seed, PICK_TREES // 2).predict(flat_x[held])
        forests[ps] = _forest(flat_x[ok], flat_y[ok], seed)
        oof[ps] = out.reshape(y.shape)
    return forests, oof


def pick_corrections(forests: dict, raw: dict, signal, xy_mm: np.ndarray) -> dict:
    """{pick set: [R, 4] each pick's predicted error} (xy_mm: the rows' physics position)."""
    out = {}
    for ps, forest in forests.items():
        X = channel_inputs(raw, signal, xy_mm, ps)
        out[ps] = forest.predict(X.reshape(-1, X.shape[2])).reshape(X.shape[:2])
    return out


def corrected_three_positions(raw: dict, signal, channel: int, corrections: dict) -> list[np.ndarray]:
    """[each pick set's [R, 2] position without `channel` from its picks less their corrections] (NaN where the
    localiser does not place the drop), in PICK_SETS order of those corrected."""
    return [_localise(raw, signal, ps, corrections[ps], without=channel) for ps in PICK_SETS if ps in corrections]
