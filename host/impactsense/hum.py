"""The mains hum of a quiet segment: a least-squares lock-in at 50 and 60 Hz (diagnose's residuals, `info`)."""

from __future__ import annotations

import numpy as np

HUM_HZ = (50.0, 60.0)
FLOOR_SIGMAS = 2.0   # white noise alone reads over this at either frequency in ~1/4 of fits: its median, never


def _design(m: int, fs_hz: float) -> np.ndarray:
    """The lock-in's columns over m samples: offset, trend, cos and sin at each of HUM_HZ."""
    tt = np.arange(m) / fs_hz
    cols = [np.ones_like(tt), tt - tt.mean()]
    for hz in HUM_HZ:
        cols += [np.cos(2 * np.pi * hz * tt), np.sin(2 * np.pi * hz * tt)]
    return np.stack(cols, axis=1)


def hum_floor(m: int, fs_hz: float, residual_ms: np.ndarray) -> np.ndarray:
    """The hum amplitude a median over drops of a lock-in over m samples stays under for white noise alone:
    FLOOR_SIGMAS standard errors of one hum quadrature (the worse of HUM_HZ), from the fits' residual mean
    square [...]. A segment of about a mains period hardly tells 50 from 60 Hz, offset and trend apart: its
    standard error grows (20 ms at 24 counts rms: ~7 counts), and an amplitude under this floor is not hum."""
    cov = np.linalg.inv(_design(m, fs_hz).T @ _design(m, fs_hz))
    q = max(float(cov[2 + 2 * k, 2 + 2 * k] + cov[3 + 2 * k, 3 + 2 * k]) / 2 for k in range(len(HUM_HZ)))
    return FLOOR_SIGMAS * np.sqrt(np.asarray(residual_ms, float) * q)


def hum_lock_in(seg: np.ndarray, fs_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares lock-in at HUM_HZ over a quiet segment [R, C, S] (counts less the bias), with offset and
    trend: (amplitude [R, C, len(HUM_HZ)], the fit's coefficients [R, C, 2 + 2 len(HUM_HZ)], what is left of the
    segment's mean square [R, C])."""
    r, c, m = seg.shape
    X = _design(m, fs_hz)
    flat = seg.reshape(-1, m).T
    coef_flat, *_ = np.linalg.lstsq(X, flat, rcond=None)
    coef = coef_flat.T.reshape(r, c, -1)
    hum = np.stack([np.hypot(coef[..., 2 + 2 * k], coef[..., 3 + 2 * k]) for k in range(len(HUM_HZ))], axis=2)
    return hum, coef, ((flat - X @ coef_flat) ** 2).mean(axis=0).reshape(r, c)
