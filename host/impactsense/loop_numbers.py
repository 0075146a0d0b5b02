"""The loop's before / after numbers of a reference model on a session: the physics localiser's MAE, the DToA
residual and the log-energy residual (`residuals.metrics`), over the channels whose timing counts."""

from __future__ import annotations

import numpy as np

from . import _core
PAIR_I = np.array([0, 0, 0, 1, 1, 2])   # the six channel pairs of the DToA
PAIR_J = np.array([1, 2, 3, 2, 3, 3])


def localise(ref, F) -> np.ndarray:
    """Physics TDOA localiser of the core: the model's velocity, delays, sensor positions; timing_out left out."""
    toa = (F.toa_us - ref.delay_us).astype(np.float32)
    keep = np.broadcast_to(~np.isin(np.arange(4), ref.timing_out), toa.shape)
    use = (np.all(np.isfinite(toa) | ~keep, axis=1, keepdims=True) & keep).astype(np.uint8)
    toa = np.ascontiguousarray(np.nan_to_num(toa))
    out = _core.localise_batch(toa, np.ascontiguousarray(use), [float(v) for v in ref.sensor_xy_mm[:, 0]],
                               [float(v) for v in ref.sensor_xy_mm[:, 1]],
                               float(1.0 / ref.slowness_us_per_mm), 7.0,
                               float(F.plate_mm[0]), float(F.plate_mm[1]))
    return np.stack([np.asarray(out["x_mm"]), np.asarray(out["y_mm"])], axis=1)


def metrics(ref, F) -> dict:
    """The loop's before/after numbers: DToA residual RMS (µs) at the declared positions, physics
    localiser MAE (mm, mean of the x and y MAE, Eq. 36), RMS of the log-energy residual (nepers)."""
    pred = ref.toa_pred(F)
    pi, pj = (p[~np.isin(PAIR_I, ref.timing_out) & ~np.isin(PAIR_J, ref.timing_out)] for p in (PAIR_I, PAIR_J))
    dt_meas = F.toa_us[:, pi] - F.toa_us[:, pj]
    dt_pred = pred[:, pi] - pred[:, pj]
    r = dt_meas - dt_pred
    xy = localise(ref, F)
    err = np.abs(xy - np.stack([F.x_mm, F.y_mm], 1))
    er = ref.energy_resid(F)[~ref.clip_mask(F)]
    return {"dtoa_rms_us": float(np.sqrt(np.nanmean(r ** 2))),
            "mae_mm": float(np.nanmean(err)),
            "energy_rms": float(np.sqrt(np.mean(er ** 2)))}
