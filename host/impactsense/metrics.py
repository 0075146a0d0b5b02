"""Eq. 36 metrics: R2, RMSE and MAE for x and for y, then averaged; and the same in the rig's inner region
(`Rig.inner_region_mm`: rig.json `inner_region_mm`, else the sensors' bounding box inset by 30 mm)."""

from __future__ import annotations

import numpy as np



def inner_mask(xy_mm: np.ndarray, region: tuple[float, float, float, float]) -> np.ndarray:
    """Rows of xy_mm inside region (x0, x1, y0, y1), edges included."""
    xy_mm = np.asarray(xy_mm, float).reshape(-1, 2)
    x0, x1, y0, y1 = region
    return (xy_mm[:, 0] >= x0) & (xy_mm[:, 0] <= x1) & (xy_mm[:, 1] >= y0) & (xy_mm[:, 1] <= y1)


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


def region_metrics(true_xy: np.ndarray, pred_xy: np.ndarray, region: tuple[float, float, float, float]) -> dict:
    """Eq. 36 over every drop ("all") and over the drops whose true position lies in region ("inner")."""
    m = inner_mask(true_xy, region)
    return {"all": localisation_metrics(true_xy, pred_xy),
            "inner": localisation_metrics(np.asarray(true_xy)[m], np.asarray(pred_xy)[m])}
