"""The mains hum of a quiet segment: a least-squares lock-in at 50 and 60 Hz (diagnose's residuals, `info`)."""

from __future__ import annotations

import numpy as np

HUM_HZ = (50.0, 60.0)


def hum_lock_in(seg: np.ndarray, fs_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares lock-in at HUM_HZ over a quiet segment [R, C, S] (counts less the bias), with offset and
    trend: (amplitude [R, C, len(HUM_HZ)], the fit's coefficients [R, C, 2 + 2 len(HUM_HZ)], what is left of the
    segment's mean square [R, C])."""
    r, c, m = seg.shape
    tt = np.arange(m) / fs_hz
    cols = [np.ones_like(tt), tt - tt.mean()]
    for hz in HUM_HZ:
        cols += [np.cos(2 * np.pi * hz * tt), np.sin(2 * np.pi * hz * tt)]
    X = np.stack(cols, axis=1)
    flat = seg.reshape(-1, m).T
    coef_flat, *_ = np.linalg.lstsq(X, flat, rcond=None)
    coef = coef_flat.T.reshape(r, c, -1)
    hum = np.stack([np.hypot(coef[..., 2 + 2 * k], coef[..., 3 + 2 * k]) for k in range(len(HUM_HZ))], axis=2)
    return hum, coef, ((flat - X @ coef_flat) ** 2).mean(axis=0).reshape(r, c)
