"""Which position a drop the channel check flags reports, per channel: the three-sensor path's or the four channels'.

A drop whose channel c the check flags (channel_check.py: c weaker and duller than the other three say it should
be, a loose or debonded disc) is placed without c by default (three_channel_position.three_sensor_path). That is
the better answer when the other three sensors surround the plate well; when they lie nearly on one line (a sensor
inside the triangle of the other three, two sensors close together with the third far off) the three-sensor
position is mirror-ambiguous across that line and lands centimetres off, while the four-channel position, which
still reads the loose disc's slightly late pick, is off by less.

At training time each channel is asked by a measurement on the training drops: their recordings with channel c
debonded as `impactsense inject --debond` does it (faults.FaultSpec: x0.4 through a first-order low-pass in
3..5 kHz), both positions out of fold (folds grouped by drop site, the forests fitted on the other folds' clean
drops): the three-sensor physics position without c plus a forest pair's correction on the three channels' inputs
(three_channel_position_inputs), and the four-channel physics position plus a forest pair's correction on the
model's location features. The four-channel position replaces the three-sensor one on that channel only when it
is better per drop site by more than CORRECTION_GAIN_SIGMAS standard errors (choose_by_gain, the project's
one-standard-error rule; the default is the three-sensor path, as before). The card's
channel_check["three_sensor_position"] (one bool per channel; absent: all true) and ["three_sensor_choice"]
(the out-of-fold MAEs and the gain in standard errors) record it. The flag is reported either way (`bad_channel`)
and the class stays the three-channel one. The forests here are plain pairs (no members, stack or level means,
for either side): the choice, not the positions reported.
"""

from __future__ import annotations

import numpy as np

MIN_SITES = 10   # drop sites needed to decide (fewer: the three-sensor path)
FOLDS = 5
TREES = 50


def _oof_positions(X_clean, X_new, base_new, xy, sites, seed) -> np.ndarray:
    """[R, 2] base_new + a forest pair's correction (truth - base on the clean drops' inputs X_clean, fitted
    on the other folds' drops) read at X_new, out of fold."""
    from sklearn.ensemble import RandomForestRegressor
    from sklearn.model_selection import GroupKFold

    out = np.full_like(base_new, np.nan)
    resid = xy - base_new
    ok = np.isfinite(X_clean).all(1) & np.isfinite(X_new).all(1) & np.isfinite(resid).all(1)
    for fit, held in GroupKFold(FOLDS).split(X_clean, groups=sites):
        fit, held = fit[ok[fit]], held[ok[held]]
        for k in range(2):
            rf = RandomForestRegressor(TREES, max_features=0.5, random_state=seed, n_jobs=1)
            out[held, k] = base_new[held, k] + rf.fit(X_clean[fit], resid[fit, k]).predict(X_new[held])
    return out


def choose_flagged_positions(model, adc: np.ndarray, xy_mm: np.ndarray, fs_hz: float, bias: float,
                             adc_max: int, seed: int = 0) -> None:
    """Sets model.card["channel_check"]["three_sensor_position"] / ["three_sensor_choice"] (in place) from the
    training drops' recordings `adc` and true positions `xy_mm`. A model without the channel check: nothing."""
    from .correction_scale import choose_by_gain, drop_sites
    from .edge_travel import three_sensor_positions
    from .faults import FaultSpec, inject
    from .host_columns import location_matrix
    from .pipeline import featurize
    from .three_channel_position import three_channel_position_inputs

    check = model.card.get("channel_check")
    xy = np.asarray(xy_mm, float)
    sites = drop_sites(xy)
    if not check or model.site_map is not None or np.unique(sites).size < MIN_SITES:
        return
    clean = featurize(adc, model.signal)
    keep, record = [], []
    for c in range(4):
        new = featurize(inject(adc, FaultSpec(debond=c, seed=seed + c), fs_hz, bias, adc_max), model.signal)
        base3 = three_sensor_positions(new.raw, model.signal, c)
        three = _oof_positions(three_channel_position_inputs(clean.vector, base3, c),
                               three_channel_position_inputs(new.vector, base3, c), base3, xy, sites, seed)
        four = _oof_positions(location_matrix(clean, model.location_features), location_matrix(new, model.location_features),
                              new.phys_xy_mm, xy, sites, seed)
        rows = np.isfinite(three).all(1) & np.isfinite(four).all(1)
        if np.unique(sites[rows]).size < MIN_SITES:
            keep.append(True)
            record.append({"drops": int(rows.sum())})
            continue
        err = [np.abs(three[rows] - xy[rows]).mean(1), np.abs(four[rows] - xy[rows]).mean(1)]
        chosen, mae, z = choose_by_gain(err, sites[rows], 0)
        keep.append(chosen == 0)
        record.append({"drops": int(rows.sum()), "three_sensor_mae_mm": round(mae[0], 3),
                       "four_channel_mae_mm": round(mae[1], 3), "gain_sigmas": round(float(z), 3)})
    check["three_sensor_position"] = keep
    check["three_sensor_choice"] = record


def keeps_four_channels(check: dict | None, channel: np.ndarray) -> np.ndarray:
    """[R] bool: the flagged rows (channel >= 0, the channel each flags) whose position stays the four channels'."""
    channel = np.asarray(channel, int)
    keep = (check or {}).get("three_sensor_position")
    if keep is None:
        return np.zeros(channel.shape, bool)
    four = ~np.asarray(keep, bool)
    return (channel >= 0) & four[np.clip(channel, 0, 3)]
