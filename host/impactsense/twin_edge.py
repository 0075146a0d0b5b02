"""The twin's height estimate near the plate's edges: a bias the training drops' out-of-fold estimates show.

Held out, drops near an edge may get a twin height estimate biased one way (in sample, the twin fitted on the
drop, they do not); the energy class's boundary sits between two drop heights a few per cent apart, so such a
bias moves edge drops across it. Off by default (`train(..., twin_edge=True)` turns it on): the bias differs
between sessions; another day's session of the same rig showed it with the other sign, and the term learnt on the
first day cost that day's class (docs/findings.md "Session 19: classfix"). The term: with d the reported
position's distance to the nearest plate edge,

    log10 h' = log10 h - b * max(0, 1 - d / D)

fitted on the training drops' out-of-fold estimates and reported positions (twin_oof.out_of_fold_twin): per
position group (a case's repetitions share one) the mean residual r_g = mean(log10 h_est - log10 h_true) and the
mean ramp z_g; b by least squares through the origin over the groups for each D in EDGE_RAMPS_MM, the D of the
smallest residual sum of squares; kept only when |b| exceeds EDGE_MIN_T standard errors of b (over the groups),
else no term (b = 0). The board applies the same term (impactapp, from the exported twin config).
"""

from __future__ import annotations

import numpy as np

EDGE_RAMPS_MM = (30.0, 45.0, 60.0, 80.0)
EDGE_MIN_T = 2.0
MIN_GROUPS = 8


def edge_distance_mm(xy_mm: np.ndarray, plate_x_mm: float, plate_y_mm: float) -> np.ndarray:
    """Distance (mm) of each position [R, 2] to the nearest edge of the plate [0, X] x [0, Y] (NaN rows: NaN)."""
    xy = np.asarray(xy_mm, float).reshape(-1, 2)
    return np.minimum(np.minimum(xy[:, 0], plate_x_mm - xy[:, 0]), np.minimum(xy[:, 1], plate_y_mm - xy[:, 1]))


def edge_ramp(xy_mm: np.ndarray, ramp_mm: float, plate_x_mm: float, plate_y_mm: float) -> np.ndarray:
    """max(0, 1 - d / ramp_mm) per position; 0 everywhere when ramp_mm <= 0."""
    d = edge_distance_mm(xy_mm, plate_x_mm, plate_y_mm)
    if ramp_mm <= 0:
        return np.zeros_like(d)
    return np.clip(1.0 - d / ramp_mm, 0.0, None)


def edge_term(fit, xy_mm: np.ndarray, plate_x_mm: float, plate_y_mm: float) -> np.ndarray:
    """The term b * ramp (log10 height) a TwinFit's estimate at xy_mm loses; zeros without one."""
    ramp_mm = float(getattr(fit, "edge_ramp_mm", 0.0) or 0.0)
    return float(getattr(fit, "edge_log10_bias", 0.0) or 0.0) * edge_ramp(xy_mm, ramp_mm, plate_x_mm, plate_y_mm)


def fit_edge_term(residual_log10: np.ndarray, xy_mm: np.ndarray, groups: np.ndarray, plate_x_mm: float,
                  plate_y_mm: float) -> dict:
    """The edge term from out-of-fold residuals (log10 h_est - log10 h_true per drop; NaN: no estimate), the
    drops' reported positions and their position groups (module doc). Returns the model card's record:
    edge_ramp_mm and edge_log10_bias (0, 0: not kept), with the figures the rule read."""
    r = np.asarray(residual_log10, float)
    xy = np.asarray(xy_mm, float).reshape(-1, 2)
    g = np.asarray(groups)
    ok = np.isfinite(r) & np.isfinite(xy).all(1)
    out = {"edge_ramp_mm": 0.0, "edge_log10_bias": 0.0, "rule": f"out-of-fold residuals, |b| > {EDGE_MIN_T} se over "
           "position groups", "candidates": []}
    ids = np.unique(g[ok])
    if ids.size < MIN_GROUPS:
        out["reason"] = f"fewer than {MIN_GROUPS} positions with an out-of-fold estimate"
        return out
    rg = np.array([r[ok & (g == i)].mean() for i in ids])
    best = None
    for ramp_mm in EDGE_RAMPS_MM:
        z = edge_ramp(xy, ramp_mm, plate_x_mm, plate_y_mm)
        zg = np.array([z[ok & (g == i)].mean() for i in ids])
        zz = float(zg @ zg)
        if zz <= 0:
            continue
        b = float(zg @ rg) / zz
        sse = float(np.sum((rg - b * zg) ** 2))
        se = float(np.sqrt(sse / (ids.size - 1) / zz))
        out["candidates"].append({"ramp_mm": ramp_mm, "bias_log10": b, "se": se, "sse": sse})
        if best is None or sse < best[2]:
            best = (ramp_mm, b, sse, se)
    if best is not None and abs(best[1]) > EDGE_MIN_T * best[3]:
        out["edge_ramp_mm"], out["edge_log10_bias"] = float(best[0]), float(best[1])
    return out


def fit_on_out_of_fold(fit, oof: dict, height_mm: np.ndarray, xy_mm: np.ndarray, signal) -> tuple[dict, np.ndarray | None]:
    """The edge term from out_of_fold_twin's figures (log10_height_mm, twin_xy_mm) of drops at true xy_mm and
    height_mm on signal's plate, set on the TwinFit `fit` when kept. Returns the card's record and the out-of-fold
    estimates less the term (None when not kept; NaN: no estimate), what the energy class then learns on."""
    from .twin import position_groups

    est = np.asarray(oof["log10_height_mm"], float)
    plate = (float(signal.plate_x_mm), float(signal.plate_y_mm))
    record = fit_edge_term(est - np.log10(np.asarray(height_mm, float)), oof["twin_xy_mm"], position_groups(xy_mm),
                           *plate)
    if record["edge_log10_bias"] == 0.0:
        return record, None
    fit.edge_ramp_mm, fit.edge_log10_bias = record["edge_ramp_mm"], record["edge_log10_bias"]
    return record, est - edge_term(fit, oof["twin_xy_mm"], *plate)


def refit_class(fit, oof: dict, height_mm: np.ndarray, xy_mm: np.ndarray, signal, energy_j: np.ndarray,
                card: dict) -> tuple | None:
    """ImpactModel.fit's twin with `signal` (None: no term): the edge term (fit_on_out_of_fold; its record in
    card["twin_edge_height"]) and, when kept, the twin's energy classifier (models.TWIN_CLASSIFIER) on the
    out-of-fold estimates less it, as a new drop's estimate is read: (classifier, threshold); None otherwise."""
    if signal is None:
        return None
    from .models import TWIN_CLASSIFIER, fit_energy_classifier

    card["twin_edge_height"], est = fit_on_out_of_fold(fit, oof, height_mm, xy_mm, signal)
    if est is None:
        return None
    ok = np.isfinite(est)
    return fit_energy_classifier(est[ok, None], np.asarray(energy_j, float)[ok], TWIN_CLASSIFIER)
