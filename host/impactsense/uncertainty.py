"""The reported position's uncertainty on the host: the twin's calibrated 1-sigma with a leave-one-channel-out
jackknife of the twin's match added in quadrature.

twin.calibrated_uncertainty reports u = (a + b s) sqrt(max(1, m / m_ref)): s the match's spread, m its misfit
(the energies' reduced chi^2). That follows errors the match's noise makes, not one channel whose energies no
longer fit the twin. Session-2 is such a day (channel 3 reads 7.4 us early and its energies scatter 3-4x more
about the twin than on session-1): the misfit averages that channel's excess over all 16 features (median
m / m_ref 1.9, so u grows x1.3) while the match, which reads position from the channels' energy ratios, moves
in full (errors x1.9); 0.47 of the session-1 model's errors lie within u there. Dropping one channel at a time
shows it directly: the match moves by 0.8-1.1 mm on session-1 whichever channel is dropped, on session-2 by
2.7 mm when channel 3 is.

The jackknife over the n channels with a usable feature (p_(-c): the match without channel c's four features,
from the same start; p_bar their mean) estimates the variance of the match that the channels' disagreement
makes, with no constant of its own:

    J^2 = (n - 1) / n * sum_c |p_(-c) - p_bar|^2,      u^2 = ((a' + b' s) sqrt(max(1, m / m_ref)))^2 + J^2

a', b' are fitted as twin.fit_uncertainty fits a, b (maximum likelihood on the training drops' out-of-fold
errors, cases grouped), with J in place; m_ref is the twin's. Nothing is fitted on another session. This is
host-only: four more matches an event would cost the board ~4 x 8k of its 64k instructions, so the board keeps
a, b (and the card keeps them for export) and `uncertainty_jackknife_offset_mm` / `_scale` sit beside them.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from .errors import DataError
from .twin import TwinFit, calibrated_uncertainty, estimate

N_CHANNELS = 4
CHANNEL_BITS = 0xF          # a channel's four features in the usable mask (channel-major: bits 4c..4c+3)


def channel_jackknife_mm(site, fit: TwinFit, feats, usable, start_xy_mm) -> np.ndarray:
    """J (mm) per event: the jackknife spread of the twin's match over the channels with a usable feature,
    each left out in turn (the same start, fit and site map as the reported match). NaN where fewer than two
    channel-deleted matches exist."""
    feats = np.asarray(feats)
    usable = np.asarray(usable, np.int64)
    n = len(feats)
    moved = np.full((n, N_CHANNELS, 2), np.nan)
    for c in range(N_CHANNELS):
        bits = CHANNEL_BITS << (4 * c)
        rows = np.flatnonzero(usable & bits)
        if rows.size == 0:
            continue
        e = estimate(site, fit, feats[rows], (usable[rows] & ~bits).astype(np.uint16), np.asarray(start_xy_mm)[rows])
        ok = np.asarray(e["status"]) == 0
        moved[rows[ok], c] = np.asarray(e["xy_mm"], float)[ok]
    have = np.isfinite(moved[..., 0])
    k = have.sum(1)
    mean = np.nansum(moved, 1) / np.maximum(k, 1)[:, None]
    ss = np.nansum((moved - mean[:, None]) ** 2, axis=(1, 2))
    return np.where(k >= 2, np.sqrt((k - 1) / np.maximum(k, 1) * ss), np.nan)


def _inflation(fit_or_ref, misfit) -> np.ndarray:
    ref = fit_or_ref.uncertainty_misfit_ref if isinstance(fit_or_ref, TwinFit) else float(fit_or_ref)
    m = np.asarray(misfit, float)
    return np.sqrt(np.maximum(1.0, m / ref)) if ref > 0 else np.ones_like(m)


def fit_jackknife_uncertainty(spread_mm, misfit, jackknife_mm, error_mm, misfit_ref: float) -> dict:
    """a', b' >= 0 of u^2 = ((a' + b' s) sqrt(max(1, m / misfit_ref)))^2 + J^2 by maximum likelihood of the
    radial errors (Rayleigh, E r^2 = u^2), from out-of-fold estimates. Returns TwinFit's
    uncertainty_jackknife_* fields."""
    s, m, j, r = (np.asarray(v, float) for v in (spread_mm, misfit, jackknife_mm, error_mm))
    ok = np.isfinite(s) & np.isfinite(m) & np.isfinite(j) & np.isfinite(r)
    if ok.sum() < 20:
        raise DataError("training data", None, f"only {int(ok.sum())} out-of-fold twin estimates with a channel "
                        "jackknife to calibrate the uncertainty (need >= 20)")
    s, j, r = s[ok], j[ok], r[ok]
    inflate = _inflation(misfit_ref, m[ok])

    def nll(p):   # -log Rayleigh(r; sigma^2 = u^2 / 2) up to constants
        u2 = np.maximum(((p[0] + p[1] * s) * inflate) ** 2 + j ** 2, 1e-6)
        return float(np.sum(np.log(u2) + r ** 2 / u2))

    b0 = float(np.sqrt(max(np.mean(r ** 2 - j ** 2), 1e-6) / np.mean((s * inflate) ** 2)))
    res = minimize(nll, [0.0, b0], method="L-BFGS-B", bounds=[(0.0, None), (0.0, None)])
    if not res.success:
        raise DataError("training data", None, f"the jackknife uncertainty's fit did not converge ({res.message})")
    return {"uncertainty_jackknife_offset_mm": float(res.x[0]), "uncertainty_jackknife_scale": float(res.x[1])}


def jackknife_calibrated(fit: TwinFit) -> bool:
    return (getattr(fit, "uncertainty_jackknife_offset_mm", 0.0) > 0
            or getattr(fit, "uncertainty_jackknife_scale", 0.0) > 0)


def host_uncertainty(fit: TwinFit, spread_mm, misfit, jackknife_mm) -> np.ndarray:
    """The reported 1-sigma radial uncertainty (mm) on the host (module doc); a fit without the jackknife's
    constants (older cards) reports twin.calibrated_uncertainty."""
    if not jackknife_calibrated(fit):
        return calibrated_uncertainty(fit, spread_mm, misfit)
    base = (fit.uncertainty_jackknife_offset_mm + fit.uncertainty_jackknife_scale * np.asarray(spread_mm, float))
    return np.hypot(base * _inflation(fit, misfit), np.asarray(jackknife_mm, float))


def out_of_fold_twin(X_loc, phys_xy_mm, xy_mm, height_mm, feats, usable, site_map, settings,
                     n_folds: int = 5) -> dict:
    """models.out_of_fold_twin with the channel jackknife: the twin's reported position of every training drop
    as a new drop would get it (forests and twin fit on the other folds, folds grouped by position, then the
    match around the forests' position), and the jackknife of that match. Returns error_mm, spread_mm,
    misfit, jackknife_mm per drop (NaN where the twin gives no estimate)."""
    from sklearn.model_selection import GroupKFold

    from .twin import fit_twin

    xy = np.asarray(xy_mm, float)
    groups = np.unique(np.round(xy, 1), axis=0, return_inverse=True)[1].ravel()
    k = min(n_folds, int(groups.max()) + 1)
    if k < 2:
        raise DataError("training data", "x_mm, y_mm", "the uncertainty's calibration needs drops at >= 2 positions")
    out = {key: np.full(len(xy), np.nan) for key in ("error_mm", "spread_mm", "misfit", "jackknife_mm")}
    resid = xy - phys_xy_mm
    for tr, va in GroupKFold(k).split(xy, groups=groups):
        start = phys_xy_mm[va] + np.stack([settings.regressor().fit(X_loc[tr], resid[tr, c]).predict(X_loc[va])
                                           for c in (0, 1)], axis=1)
        fit = fit_twin(feats[tr], usable[tr], site_map, xy[tr], height_mm[tr])
        est = estimate(site_map, fit, feats[va], usable[va], start)
        ok = np.asarray(est["status"]) == 0
        rows = va[ok]
        out["error_mm"][rows] = np.linalg.norm(np.asarray(est["xy_mm"], float)[ok] - xy[rows], axis=1)
        out["spread_mm"][rows] = np.asarray(est["spread_mm"], float)[ok]
        out["misfit"][rows] = np.asarray(est["misfit"], float)[ok]
        out["jackknife_mm"][rows] = channel_jackknife_mm(site_map, fit, feats[va][ok], usable[va][ok], start[ok])
    return out


def calibrate(model, features, xy_mm, height_mm, settings=None) -> dict:
    """Fits the jackknife's a', b' of a trained model with a site map (models.ImpactModel) on its training
    drops (the Features it was fitted on, their positions and heights) and sets them on model.twin_fit.
    Returns the fields set."""
    from .models import LOCATION_FEATURES, ForestSettings, columns
    from .sitemap import twin_features

    if model.site_map is None or model.twin_fit is None:
        raise DataError("model", "twin", "the jackknife uncertainty needs a model with the twin's site map")
    use = features.usable
    rows = np.flatnonzero(use)
    feats, usable = twin_features(features.take(rows))
    oof = out_of_fold_twin(features.vector[use][:, columns(LOCATION_FEATURES)], features.phys_xy_mm[use],
                           np.asarray(xy_mm, float)[use], np.asarray(height_mm, float)[use], feats, usable,
                           model.site_map, settings or ForestSettings(**{
                               k: v for k, v in (model.card.get("forest") or {}).items()
                               if k in ForestSettings.__dataclass_fields__}))
    got = fit_jackknife_uncertainty(oof["spread_mm"], oof["misfit"], oof["jackknife_mm"], oof["error_mm"],
                                    model.twin_fit.uncertainty_misfit_ref)
    for key, value in got.items():
        setattr(model.twin_fit, key, value)
    return got


def predict_uncertainty(model, features, prediction: dict) -> np.ndarray:
    """uncertainty_mm of model.predict(features)'s events (prediction: its output) with the channel
    jackknife (host_uncertainty); NaN where the twin gave no position."""
    from .sitemap import twin_features

    u = np.full(len(features), np.nan)
    rows = np.flatnonzero(np.isfinite(prediction["xy_mm"]).all(1))
    if rows.size == 0:
        return u
    feats, usable = twin_features(features.take(rows))
    jack = channel_jackknife_mm(model.site_map, model.twin_fit, feats, usable, prediction["forest_xy_mm"][rows])
    u[rows] = host_uncertainty(model.twin_fit, prediction["twin_spread_mm"][rows], prediction["twin_misfit"][rows],
                               jack)
    return u
