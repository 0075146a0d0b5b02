"""Eq. 36 metrics: R2, RMSE and MAE for x and for y, then averaged; the inner region of method.md."""

from __future__ import annotations

import numpy as np

INNER_MM = (60.0, 260.0)


def inner_mask(xy_mm: np.ndarray, lo: float = INNER_MM[0], hi: float = INNER_MM[1]) -> np.ndarray:
    xy_mm = np.asarray(xy_mm)
    return np.all((xy_mm >= lo) & (xy_mm <= hi), axis=1)


def localisation_metrics(true_xy: np.ndarray, pred_xy: np.ndarray) -> dict:
    """R2, RMSE and MAE of x and of y, averaged (Eq. 36); plus the mean Euclidean error."""
    t = np.asarray(true_xy, float)
    p = np.asarray(pred_xy, float)
    if t.shape[0] == 0:
        return {"n": 0, "r2": float("nan"), "rmse_mm": float("nan"), "mae_mm": float("nan"),
                "euclid_mm": float("nan")}
    r2, rmse, mae = [], [], []
    for k in range(2):
        e = p[:, k] - t[:, k]
        ss_tot = float(np.sum((t[:, k] - t[:, k].mean()) ** 2))
        r2.append(1.0 - float(np.sum(e ** 2)) / ss_tot if ss_tot > 0 else float("nan"))
        rmse.append(float(np.sqrt(np.mean(e ** 2))))
        mae.append(float(np.mean(np.abs(e))))
    return {"n": int(t.shape[0]), "r2": float(np.mean(r2)), "rmse_mm": float(np.mean(rmse)),
            "mae_mm": float(np.mean(mae)), "euclid_mm": float(np.mean(np.hypot(*(p - t).T)))}


def region_metrics(true_xy: np.ndarray, pred_xy: np.ndarray) -> dict:
    m = inner_mask(true_xy)
    return {"all": localisation_metrics(true_xy, pred_xy),
            "inner": localisation_metrics(np.asarray(true_xy)[m], np.asarray(pred_xy)[m])}
