"""What `diagnose` reports of the residuals themselves: how each channel's residual depends on where and how
the ball hit, and the repeated drops' own scatter (the floor no timing model goes below)."""

from __future__ import annotations

import numpy as np

from . import residuals as R


def dependence(ref: R.Reference, F: R.Features) -> dict:
    """How each channel's residuals depend on distance, direction, height, drop order and amplitude:
    per channel, a joint least-squares slope (± standard error) of the drop-centred ToA residual (µs) and
    log-energy residual on standardised regressors (slope per 1 SD of the regressor)."""
    d, th, _, _ = ref.geometry(F)
    amp = F.log_energy - F.log_energy.mean(axis=1, keepdims=True)
    out = {"regressors": ["distance_mm", "cos2theta", "sin2theta", "height_mm", "drop_order", "log_energy"]}
    for label, r in (("toa_us", ref.toa_resid(F)), ("log_energy", ref.energy_resid(F))):
        rows = []
        for c in range(4):
            X = np.stack([d[:, c], np.cos(2 * th[:, c]), np.sin(2 * th[:, c]), F.height_mm, F.order,
                          amp[:, c]], axis=1)
            ok = np.all(np.isfinite(X), axis=1) & np.isfinite(r[:, c])
            if label == "log_energy":
                ok &= ~ref.clip_mask(F)[:, c]
            X = X[ok]
            X = (X - X.mean(0)) / np.maximum(X.std(0), 1e-9)
            X = np.c_[np.ones(len(X)), X]
            y = r[ok, c]
            beta, *_ = np.linalg.lstsq(X, y, rcond=None)
            res = y - X @ beta
            cov = np.linalg.pinv(X.T @ X) * res.var(ddof=X.shape[1])
            rows.append({"slope": beta[1:].tolist(), "se": np.sqrt(np.diag(cov))[1:].tolist(),
                         "mean": float(np.mean(y))})
        out[label] = rows
    return out


def repeatability(F: R.Features) -> dict:
    """Within-case scatter of DToA (µs rms, per pair): the floor no timing model can go below."""
    dt = F.toa_us[:, R.PAIR_I] - F.toa_us[:, R.PAIR_J]
    dev, dof = np.zeros(6), 0
    for c in np.unique(F.case_id):
        m = F.case_id == c
        if m.sum() > 1:
            x = dt[m]
            dev += np.nansum((x - np.nanmean(x, 0)) ** 2, axis=0)
            dof += m.sum() - 1
    return {"dtoa_within_case_rms_us": (np.sqrt(dev / max(dof, 1))).tolist(), "dof": int(dof)}
