"""The arrival times' part the travel model misses near the plate's edges, learnt from the training drops, and the
physics positions it gives (a host-side position member; docs/findings.md "Edge images in the travel time").

Near an edge the wave reflected there reaches a sensor on a path only a little longer than the direct one, and the
picks of the far channels come late: the core's localiser, which knows only the direct path, then places a drop
near an edge outwards. Each pick set's centred travel residual at the training drops' true positions is fitted
(Huber-weighted least squares) on a few bases of the geometry, shared by every channel and every drop:

- the direct distance d and d^2 (the residual's curve in the distance);
- for each pair of opposite edges (x = 0 / x = W, y = 0 / y = H) and scale L, the sum over the two edges of
  exp(-(d_image - d) / L), d_image the distance from the drop's mirror image in the edge (in the pick set's
  travel metric): near 1 where the reflected path is hardly longer than the direct one.

The correction at a position is those bases times the coefficients; the core's localiser (localise_batch, the
same one process_event runs) is run again on the picks minus the correction at its last position (PASSES times).
"""

from __future__ import annotations

import numpy as np

from . import _core
from .travel import slowness_scales, travel_distances

IMAGE_SCALES_MM = (10.0, 30.0, 80.0)
N_BASES = 2 + 2 * len(IMAGE_SCALES_MM)
PASSES = 2
HUBER_US = 3.0
PICK_SETS = ("threshold", "band")


def _metric(signal, pick_set: str) -> tuple[float, float, float]:
    if pick_set == "threshold":
        return (signal.travel_metric_xx, signal.travel_metric_xy, signal.travel_metric_yy)
    return (signal.band_metric_xx, signal.band_metric_xy, signal.band_metric_yy)


def travel_bases(xy_mm: np.ndarray, signal, pick_set: str) -> np.ndarray:
    """[R, 4, N_BASES] the bases of each channel's travel-time correction at positions xy_mm [R, 2]."""
    xy = np.asarray(xy_mm, float).reshape(-1, 2)
    sensors = signal.sensor_xy_mm
    metric = _metric(signal, pick_set)
    d = travel_distances(xy, sensors, metric)
    w, h = float(signal.plate_x_mm), float(signal.plate_y_mm)
    x, y = xy[:, 0], xy[:, 1]
    images = {"x": (np.c_[-x, y], np.c_[2 * w - x, y]), "y": (np.c_[x, -y], np.c_[x, 2 * h - y])}
    extra = {k: [travel_distances(m, sensors, metric) - d for m in pair] for k, pair in images.items()}
    cols = [d, d * d / 100.0]
    for scale in IMAGE_SCALES_MM:
        for k in ("x", "y"):
            cols.append(sum(np.exp(-e / scale) for e in extra[k]))
    return np.stack(cols, 2)


def pick_set_arrivals(raw: dict, signal, pick_set: str):
    """The picks the core's localiser reads for a pick set, as process_event gives them: toa [R, 4] (delays
    removed), usable [R, 4], the per-channel travel-time factors [R, 4] and the velocity."""
    flags = np.asarray(raw["flags"])
    use = (flags & (_core.FLAG_NO_ONSET | _core.FLAG_DEAD)) == 0
    if pick_set == "threshold":
        toa = np.asarray(raw["toa_us"], float)
        v = float(signal.velocity_mm_per_us)
        scale = (slowness_scales(raw["pick_period"], signal.fs_hz, signal.dispersion_exponent,
                                 signal.dispersion_ref_hz) if signal.dispersion_exponent else np.ones(toa.shape))
        return toa, use & np.isfinite(toa), scale, v
    toa = np.asarray(raw["toa_band_us"], float) - np.asarray(signal.band_delay_us, float)[None]
    v = float(signal.band_velocity_mm_per_us)
    slowness = np.full(len(toa), 1.0 / v)
    if signal.band_slowness_per_decade:   # impactcore band_velocity_for, as a factor on every channel
        log_e = _core.band_log_energy_batch(np.ascontiguousarray(raw["energy"], np.float32),
                                            np.ascontiguousarray(flags, np.uint8),
                                            [int(bool(c)) for c in signal.channel_left_out], float(signal.fs_hz))
        line = 1.0 / v + signal.band_slowness_per_decade * (log_e.astype(float) - signal.band_log_energy_ref)
        slowness = np.where(np.isfinite(line) & (line > 0), line, slowness)
    return toa, use & np.isfinite(toa), np.repeat((slowness * v)[:, None], 4, 1), v


def fit_correction(raw: dict, xy_mm: np.ndarray, signal, pick_set: str, bases=None) -> list[float] | None:
    """The coefficients of a pick set's correction from drops at known positions (their centred residuals, every
    channel picked), or None when fewer than 8 drops have four picks. bases: a function like travel_bases (the
    default), (xy_mm, signal, pick_set) -> [R, 4, n] (a diagnosis's other travel laws)."""
    toa, use, scale, v = pick_set_arrivals(raw, signal, pick_set)
    xy = np.asarray(xy_mm, float)
    resid = toa - travel_distances(xy, signal.sensor_xy_mm, _metric(signal, pick_set)) * scale / v
    rows = use.all(1) & np.isfinite(resid).all(1)
    if rows.sum() < 8:
        return None
    r = resid[rows] - resid[rows].mean(1, keepdims=True)
    b = (bases or travel_bases)(xy[rows], signal, pick_set)
    b = b - b.mean(1, keepdims=True)
    a, y = b.reshape(-1, b.shape[2]), r.ravel()
    weight = np.ones(len(y))
    for _ in range(10):
        root = np.sqrt(weight)
        coef = np.linalg.lstsq(a * root[:, None], y * root, rcond=None)[0]
        weight = np.minimum(1.0, HUBER_US / np.maximum(np.abs(y - a @ coef), 1e-9))
    return [float(c) for c in coef]


def _localise(raw: dict, signal, pick_set: str, correction_us: np.ndarray, without: int = -1,
              max_evaluations: int = 0) -> np.ndarray:
    toa, use, scale, v = pick_set_arrivals(raw, signal, pick_set)
    if without >= 0:   # the three-sensor position: that channel's pick not read
        use = use.copy()
        use[:, without] = False
    toa = np.where(use, toa - correction_us, 0.0).astype(np.float32)
    scaled = pick_set == "band" or bool(signal.dispersion_exponent)
    out = _core.localise_batch(np.ascontiguousarray(toa), np.ascontiguousarray(use.astype(np.uint8)),
                               list(signal.sensor_x_mm), list(signal.sensor_y_mm), v, signal.sigma_us,
                               signal.plate_x_mm, signal.plate_y_mm, signal.huber_us,
                               list(_metric(signal, pick_set)),
                               scale.astype(np.float32).ravel().tolist() if scaled else [],
                               int(signal.localiser_starts), int(signal.posterior_grid),
                               int(max_evaluations) or int(signal.localiser_evaluation_cap))
    xy = np.stack([out["x_mm"], out["y_mm"]], 1).astype(float)
    xy[(np.asarray(out["status"]) != 0) | (use.sum(1) < 3)] = np.nan
    return xy


def three_sensor_positions(raw: dict, signal, channel: int, coefs: dict | None = None,
                           max_evaluations: int = 0) -> np.ndarray:
    """The core's physics position [R, 2] from the picks of every channel but `channel` (NaN where the other three
    do not place the drop): as process_event gives it with that channel left out, the threshold picks' position
    averaged with the band picks' where those place the drop too. coefs (a model's edge_travel, per pick set):
    each pick set's position with its correction (`corrected`, that channel's pick not read). max_evaluations
    (0: the localiser's own cap): each run's normal-equation evaluations, _core.FLAGGED_EVALUATIONS for the core's
    three_sensor_position (a channel the channel check flags)."""
    coefs = coefs or {}
    xy = _localise(raw, signal, "threshold", 0.0, without=channel, max_evaluations=max_evaluations)
    if coefs.get("threshold") is not None:
        xy = corrected(raw, signal, "threshold", xy, coefs["threshold"], without=channel)
    if float(signal.band_pick_hz) > 0 and float(signal.band_velocity_mm_per_us) > 0:
        band = _localise(raw, signal, "band", 0.0, without=channel, max_evaluations=max_evaluations)
        if coefs.get("band") is not None:
            band = corrected(raw, signal, "band", band, coefs["band"], without=channel)
        both = np.isfinite(xy).all(1) & np.isfinite(band).all(1)
        xy[both] = 0.5 * (xy[both] + band[both])
    return xy


def corrected(raw: dict, signal, pick_set: str, start_xy_mm: np.ndarray, coef, without: int = -1,
              bases=None) -> np.ndarray:
    """A pick set's positions [R, 2] with its correction: the localiser re-run on the picks minus the correction
    at the last position, from start_xy_mm (the core's position of that pick set); NaN where it had none.
    without >= 0: that channel's pick not read (the three-sensor position). bases: fit_correction's."""
    xy = np.array(start_xy_mm, float, copy=True)
    start_ok = np.isfinite(xy).all(1)
    coef = np.asarray(coef, float)
    for _ in range(PASSES):
        ok = np.isfinite(xy).all(1)
        correction = np.zeros((len(xy), 4))
        correction[ok] = (bases or travel_bases)(xy[ok], signal, pick_set) @ coef
        new = _localise(raw, signal, pick_set, correction, without=without)
        xy = np.where(np.isfinite(new), new, xy)
    xy[~start_ok] = np.nan
    return xy


def positions(raw: dict, signal, coefs: dict, threshold_xy: np.ndarray, band_xy: np.ndarray | None) -> dict:
    """The corrected positions: "threshold", "band" (NaN where the band picks did not place the drop) and
    "physics" (their mean where both are finite, else the threshold picks' own)."""
    thr = corrected(raw, signal, "threshold", threshold_xy, coefs["threshold"])
    band = np.full_like(thr, np.nan)
    if band_xy is not None and coefs.get("band") is not None:
        band = corrected(raw, signal, "band", band_xy, coefs["band"])
    placed = np.isfinite(band).all(1)
    return {"threshold": np.where(placed[:, None], thr, np.nan), "band": band,
            "physics": np.where(placed[:, None], 0.5 * (thr + band), thr)}
