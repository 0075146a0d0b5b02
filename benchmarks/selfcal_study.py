"""Self-calibration: a model's per-channel ToA constants refitted from a session's own picks, without labels.

A channel whose wave shows d us later than the model was trained with (a longer cable, a re-glued disc along
its look direction, the part of any move that is constant over the impacts) biases every position the model
gives. Without labels the drops' positions are unknown, but their number is not: each drop's four picks
carry three time differences and fix two coordinates, so one difference per drop is left over, and its
dependence on where the drop landed makes the channels' constants identifiable over many drops. The joint
fit (`fit_channel_offsets`): for drops k and channels i,

    toa_ki = t0_k + s_ki |p_k - s_i|_Q + delta_i,

the model's own travel law (slowness s = 1 / velocity, the dispersion factor of each pick's period, the travel
metric Q, the model's sensor positions); unknowns p_k, t0_k (eliminated by centring each drop) and delta
(channel 0's fixed at 0: a constant on every channel is an origin time). Huber-like loss (soft_l1 at the
localiser's huber_us).

The law is not the plate (site terms: the reference's picks scatter several us about it in a way smooth in
position), so the same fit on the model's own training drops does not give 0: `self_calibrate` subtracts it
(the fit on the reference session, unlabelled as well) and reports the difference, with delete-a-block
jackknife standard errors of both fits. Only combinations of the constants that the drops determine well are
kept (MODE_SE_US): a constant on one channel is nearly a shift of every position (on a four-corner layout at a
few us of pick noise only one of the three combinations is fitted well: docs/findings.md). Positions in the data
are not used.

This absorbs the part of a change that is constant over the impacts; it is a refit of the model's constants,
not a named effect: `diagnose` names effects (with labels), this only recentres a model on new data. Measured on
the loop's sessions it did not give accuracy back, so `retrain` and the loop do not call it (docs/findings.md,
issue 16 loopmove4; `benchmarks/bench_self_calibration.py`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares

JACKKNIFE_BLOCKS = 10     # delete-a-block jackknife over the new session's drops (in recording order)
MIN_DROPS = 20            # fewer usable drops: no refit
MODE_SE_US = 1.0          # combinations of the constants fitted to better than this (us, one sigma) are kept
APPLY_Z = 3.0             # a channel's offset is applied when |offset| > this x its jackknife standard error
                          # (on some channel; then all channels' offsets go in, as one recentring)


@dataclass
class ChannelOffsets:
    offset_us: list[float]                 # per channel, centred (sum 0): the ToA constant to add to rig_delay_us
    se_us: list[float]                     # jackknife standard errors (centred)
    n: int                                 # drops used
    reference_us: list[float] = field(default_factory=list)   # the same fit on the reference (subtracted)
    applied: bool = False
    n_modes: int = 0                        # combinations of the constants kept (of 3)

    @property
    def z(self) -> np.ndarray:
        se = np.maximum(np.asarray(self.se_us), 1e-9)
        return np.abs(np.asarray(self.offset_us)) / se

    def to_dict(self) -> dict:
        return {"offset_us": [round(v, 3) for v in self.offset_us], "se_us": [round(v, 3) for v in self.se_us],
                "reference_us": [round(v, 3) for v in self.reference_us], "n": self.n, "applied": self.applied,
                "modes_kept": self.n_modes,
                "rule": f"applied when some channel's |offset| > {APPLY_Z} x its jackknife standard error"}


def _travel(xy: np.ndarray, cfg, scale: np.ndarray) -> np.ndarray:
    from impactsense.travel import travel_distances
    metric = (cfg.travel_metric_xx, cfg.travel_metric_xy, cfg.travel_metric_yy)
    return travel_distances(xy, cfg.sensor_xy_mm, metric) * scale / float(cfg.velocity_mm_per_us)


def usable_picks(features, cfg):
    """(ToA [R, 4] us with the model's delays removed, slowness factors per pick, start positions [R, 2], rows)
    of the drops with a pick on every channel and a physics position."""
    from impactsense.travel import slowness_scales
    toa = np.asarray(features.toa_us, float)
    start = np.asarray(features.phys_xy_mm, float)
    rows = np.flatnonzero(np.isfinite(toa).all(1) & np.isfinite(start).all(1))
    period = np.asarray(features.raw["pick_period"], float)[rows]
    scale = slowness_scales(period, float(cfg.fs_hz), float(cfg.dispersion_exponent), float(cfg.dispersion_ref_hz))
    return toa[rows], scale, start[rows], rows


def fit_channel_offsets(toa: np.ndarray, scale: np.ndarray, start_xy: np.ndarray, cfg) -> np.ndarray:
    """The joint fit of the module doc: delta_1..3 (us, channel 0's fixed at 0) with every drop's position free."""
    n = len(toa)
    plate = np.array([float(cfg.plate_x_mm), float(cfg.plate_y_mm)])
    f_scale = max(float(cfg.huber_us), 1.0)

    def unpack(p):
        return np.r_[0.0, p[:3]], p[3:].reshape(n, 2)

    def residuals(p):
        delta, xy = unpack(p)
        r = toa - _travel(xy, cfg, scale) - delta[None]
        return (r - r.mean(1, keepdims=True)).ravel()

    # each drop's 4 residuals depend on its own 2 coordinates and on the 3 constants
    rows = np.arange(4 * n)
    jac = sparse.lil_matrix((4 * n, 3 + 2 * n), dtype=int)
    jac[:, :3] = 1
    k = rows // 4
    jac[rows, 3 + 2 * k] = 1
    jac[rows, 4 + 2 * k] = 1
    p0 = np.r_[np.zeros(3), np.clip(start_xy, 0.0, plate).ravel()]
    margin = 0.25 * plate
    lo = np.r_[np.full(3, -np.inf), np.tile(-margin, n)]
    hi = np.r_[np.full(3, np.inf), np.tile(plate + margin, n)]
    sol = least_squares(residuals, p0, jac_sparsity=jac, bounds=(lo, hi), loss="soft_l1", f_scale=f_scale,
                        x_scale="jac", max_nfev=200)
    return sol.x[:3]


def self_calibrate(model, reference_adc: np.ndarray, data_adc: np.ndarray) -> ChannelOffsets:
    """The channels' ToA constants of `data_adc` (unlabelled recordings) relative to the model's training
    recordings `reference_adc` (also unlabelled here), by the model's core and travel law (`offsets_from_picks`)."""
    from impactsense.pipeline import featurize
    cfg = model.signal
    return offsets_from_picks(usable_picks(featurize(reference_adc, cfg), cfg)[:3],
                              usable_picks(featurize(data_adc, cfg), cfg)[:3], cfg)


def _fit_with_jackknife(picks, cfg) -> tuple[np.ndarray, np.ndarray]:
    """delta_1..3 of the joint fit and its delete-a-block jackknife covariance [3, 3] (blocks in recording order)."""
    toa, scale, start = picks
    delta = fit_channel_offsets(toa, scale, start, cfg)
    blocks = np.array_split(np.arange(len(toa)), JACKKNIFE_BLOCKS)
    loo = np.array([fit_channel_offsets(np.delete(toa, b, 0), np.delete(scale, b, 0), np.delete(start, b, 0), cfg)
                    for b in blocks])
    g = len(blocks)
    dev = loo - loo.mean(0)
    return delta, (g - 1) / g * dev.T @ dev


def offsets_from_picks(reference, data, cfg) -> ChannelOffsets:
    """reference, data: (ToA [R, 4] us, slowness factors [R, 4], start positions [R, 2]) of usable drops. The
    joint fit on each; their difference kept only along the combinations of the constants that the data
    determine to better than MODE_SE_US (eigenvectors of the sum of both fits' delete-a-block jackknife
    covariances: a constant on a channel is partly a shift of every position, and some combinations are not
    identifiable at a few us of pick noise), with its jackknife standard errors; `applied` by APPLY_Z."""
    toa, scale, start = data
    n = len(toa)
    if n < MIN_DROPS or len(reference[0]) < MIN_DROPS:
        return ChannelOffsets([0.0] * 4, [float("inf")] * 4, n, [0.0] * 4, False)
    delta, cov = _fit_with_jackknife(data, cfg)
    ref_delta, ref_cov = _fit_with_jackknife(reference, cfg)
    w, V = np.linalg.eigh(cov + ref_cov)
    keep = V[:, np.sqrt(np.maximum(w, 0.0)) < MODE_SE_US]
    proj = keep @ keep.T
    C = np.vstack([np.zeros(3), np.eye(3)])
    C -= C.mean(0)                                   # delta_1..3 -> centred 4 channels
    diff = C @ proj @ (delta - ref_delta)
    se = np.sqrt(np.maximum(np.diag(C @ proj @ (cov + ref_cov) @ proj @ C.T), 0.0))   # both fits' noise
    out = ChannelOffsets([float(v) for v in diff], [float(v) for v in se], n,
                         [float(v) for v in C @ ref_delta], n_modes=int(keep.shape[1]))
    out.applied = bool(np.any(np.abs(diff) > APPLY_Z * np.maximum(se, 1e-9)))
    return out


def recentred(model, offsets: ChannelOffsets):
    """A copy of `model` whose core removes the offsets too (rig_delay_us, and the band picks' band_delay_us:
    a channel's constant delays both picks alike). The forests and the localiser see the drops as the model's
    training drops showed them."""
    import copy
    out = copy.copy(model)
    sig = type(model.signal).from_dict(model.signal.to_dict())
    sig.rig_delay_us = [float(a) + float(b) for a, b in zip(sig.rig_delay_us, offsets.offset_us)]
    if float(getattr(sig, "band_velocity_mm_per_us", 0.0)) > 0:
        sig.band_delay_us = [float(a) + float(b) for a, b in zip(sig.band_delay_us, offsets.offset_us)]
    out.signal = sig
    return out
