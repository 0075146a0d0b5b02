"""How hard the plate was hit, by matching an event's energies against the twin's site map.

Fitting (here, in Python: it is training) finds how the rig's events relate to the map: per feature an
offset (the rig's gains and the twin's spectral tilt), a slope d feature / d log10 height, and a weight
(1 / variance of the rig-minus-map residual, pooled over the four channels per kind of energy). The
estimate itself is the core's twin_estimate (C++, the board's code) through the binding.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from scipy.optimize import minimize

from . import _core
from .errors import DataError
from .sitemap import N_FEATURES, SiteMap
from .twin_edge import edge_term

if TYPE_CHECKING:
    from .pipeline import Features
    from .signal import SignalConfig

KINDS = 4   # arrival, Delta^1, Delta^2, Delta^3 per channel (channel-major features)


@dataclass
class TwinFit:
    offset: list[float]
    slope: list[float]
    weight: list[float]
    ref_log10_height_mm: float
    prior_mm: float = 7.0
    cutoff_mm: float = 15.0
    temperature: float = 0.5
    coarse_cutoff_mm: float = 0.0   # > 0: coarse-to-fine match (twin.h TwinConfig)
    weak_channel: int = -1          # >= 0: a partly debonded channel the models were retrained for (twin.h)
    # The reported uncertainty (module doc): u = (a + b spread) * sqrt(max(1, misfit / ref)); ref 0 = no
    # inflation. The defaults (a model card from before the calibration) report the raw spread.
    uncertainty_offset_mm: float = 0.0
    uncertainty_scale: float = 1.0
    uncertainty_misfit_ref: float = 0.0
    # The height estimate's edge term (twin_edge.py): log10 h -= edge_log10_bias * max(0, 1 - d / edge_ramp_mm),
    # d the reported position's distance to the nearest plate edge; edge_ramp_mm 0: none (older cards).
    edge_ramp_mm: float = 0.0
    edge_log10_bias: float = 0.0

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TwinFit":
        try:
            fit = cls(**d)
        except TypeError as exc:
            raise DataError("model card", "twin", str(exc)) from None
        for name in ("offset", "slope", "weight"):
            if len(getattr(fit, name)) != N_FEATURES:
                raise DataError("model card", f"twin.{name}", f"needs {N_FEATURES} values")
        return fit


def _residual_rows(feats, usable, site: SiteMap, xy_mm):
    mask = ((usable[:, None].astype(np.int64) >> np.arange(N_FEATURES)) & 1).astype(bool)
    mask &= np.isfinite(feats)
    return feats.astype(float) - site.nearest(xy_mm).astype(float), mask


def fit_slopes(feats: np.ndarray, usable: np.ndarray, site: SiteMap, xy_mm: np.ndarray,
               height_mm: np.ndarray) -> np.ndarray:
    """d feature / d log10 height of the event-minus-map residual, by least squares over the drops."""
    r, mask = _residual_rows(feats, usable, site, xy_mm)
    lh = np.log10(np.asarray(height_mm, float))
    if np.ptp(lh) < 0.05:
        raise DataError("training data", "height_mm", "the twin's slopes need drops from several heights")
    slope = np.empty(N_FEATURES)
    for k in range(N_FEATURES):
        m = mask[:, k]
        if m.sum() < 5:
            raise DataError("training data", None, f"fewer than 5 drops with a usable twin feature {k}")
        slope[k] = np.polyfit(lh[m], r[m, k], 1)[0]
    return slope


def position_groups(xy_mm: np.ndarray) -> np.ndarray:
    """Drops grouped by position (a case's repetitions share one, to 0.1 mm)."""
    return np.unique(np.round(np.asarray(xy_mm, float), 1), axis=0, return_inverse=True)[1].ravel()


def _offsets(r: np.ndarray, mask: np.ndarray, additive: bool) -> np.ndarray:
    """Per feature the median residual; additive: the least-squares channel + kind table through those
    medians (a channel's gain shifts its four log-energies alike, the twin's spectral tilt a kind's four
    channels alike)."""
    offset = np.zeros(N_FEATURES)
    for k in range(N_FEATURES):
        if not mask[:, k].any():
            raise DataError("training data", None, f"no drop has a usable twin feature {k} (all clipped?)")
        offset[k] = np.median(r[mask[:, k], k])
    if additive:
        t = offset.reshape(-1, KINDS)                 # [channel, kind]: the features are channel-major
        offset = (t.mean(1, keepdims=True) + t.mean(0, keepdims=True) - t.mean()).ravel()
    return offset


def _kind_weights(dev: np.ndarray, mask: np.ndarray) -> np.ndarray:
    weight = np.zeros(N_FEATURES)
    for kind in range(KINDS):
        cols = np.arange(kind, N_FEATURES, KINDS)
        pooled = dev[:, cols][mask[:, cols]]
        if pooled.size < 4:
            raise DataError("training data", None, "too few usable drops to weight the twin's features")
        weight[cols] = 1.0 / max(float(np.var(pooled)), 1e-6)
    return weight


def fit_twin(feats: np.ndarray, usable: np.ndarray, site: SiteMap, xy_mm: np.ndarray, height_mm: np.ndarray,
             slope: np.ndarray | None = None, weight_shape: np.ndarray | None = None,
             additive_offsets: bool = False) -> TwinFit:
    """Offsets and weights from drops of known position and height (slopes too unless given).

    The default (many drops, e.g. the measured training set): per feature the median residual, per kind
    1 / the pooled residual variance. From a few positions (zero-shot: four calibration cases) both are
    noisy -- four positions' site terms give each kind's variance to ~+-40 % -- so weight_shape (e.g. the
    virtual drops' weights: the twin's own features say how much each kind varies from site to site) fixes
    the weights' shape and only one scale is fitted (mean of shape * residual^2 over the usable features:
    the maximum-likelihood variance scale); and additive_offsets (_offsets) fits 7 numbers instead of 16."""
    if slope is None:
        slope = fit_slopes(feats, usable, site, xy_mm, height_mm)
    slope = np.asarray(slope, float)
    ref = float(np.log10(site.ref_height_mm))
    r, mask = _residual_rows(feats, usable, site, xy_mm)
    r = r - slope[None, :] * (np.log10(np.asarray(height_mm, float)) - ref)[:, None]
    offset = _offsets(r, mask, additive_offsets)
    if weight_shape is None:
        weight = _kind_weights(r - offset[None, :], mask)
    else:
        shape = np.asarray(weight_shape, float)
        if shape.shape != (N_FEATURES,) or not (np.isfinite(shape).all() and (shape > 0).all()):
            raise DataError("twin fit", "weight_shape", f"needs {N_FEATURES} positive values")
        dev = r - offset[None, :]
        if mask.sum() < 4:
            raise DataError("training data", None, "too few usable drops to scale the twin's weights")
        weight = shape / max(float(np.mean((shape[None, :] * dev ** 2)[mask])), 1e-12)
    return TwinFit(offset=offset.tolist(), slope=slope.tolist(), weight=weight.tolist(), ref_log10_height_mm=ref)


def estimate(site: SiteMap, fit: TwinFit, feats: np.ndarray, usable: np.ndarray, xy_mm: np.ndarray) -> dict:
    """The core's twin_estimate for every row: log10_height_mm, xy_mm, spread_mm (the match's raw
    spread; the reported uncertainty is calibrated_uncertainty's), misfit, n_points, status."""
    f32 = lambda a: np.ascontiguousarray(np.asarray(a, np.float32))  # noqa: E731
    xy = f32(np.asarray(xy_mm, float).reshape(-1, 2))   # NaN rows: status kErrBadConfig, estimate NaN
    return _core.twin_estimate_batch(f32(feats), np.ascontiguousarray(usable, np.uint16), xy, site.q,
                                     site.nx, site.ny, site.x0_mm, site.y0_mm, site.step_mm, f32(site.base),
                                     f32(site.scale), f32(fit.offset), f32(fit.slope), f32(fit.weight),
                                     fit.ref_log10_height_mm, fit.prior_mm, fit.cutoff_mm, fit.temperature,
                                     fit.coarse_cutoff_mm)


def calibrated_uncertainty(fit: TwinFit, spread_mm, misfit) -> np.ndarray:
    """The reported 1-sigma radial uncertainty (mm) from the match's spread and misfit (module doc)."""
    u = fit.uncertainty_offset_mm + fit.uncertainty_scale * np.asarray(spread_mm, float)
    if fit.uncertainty_misfit_ref > 0:
        u = u * np.sqrt(np.maximum(1.0, np.asarray(misfit, float) / fit.uncertainty_misfit_ref))
    return u


def fit_uncertainty(spread_mm, misfit, error_mm) -> dict:
    """a, b and m_ref of calibrated_uncertainty from events the model did not learn (out-of-fold): m_ref the
    mean misfit, a, b >= 0 maximising the Rayleigh likelihood of the radial errors r with E r^2 = u^2
    (so mean (r / u)^2 = 1 at the optimum when a, b are free). Returns TwinFit's uncertainty_* fields."""
    s, m, r = (np.asarray(v, float) for v in (spread_mm, misfit, error_mm))
    ok = np.isfinite(s) & np.isfinite(m) & np.isfinite(r)
    if ok.sum() < 20:
        raise DataError("training data", None, f"only {int(ok.sum())} out-of-fold twin estimates to calibrate "
                        "the uncertainty (need >= 20)")
    s, m, r = s[ok], m[ok], r[ok]
    ref = max(float(np.mean(m)), 1e-6)
    inflate = np.sqrt(np.maximum(1.0, m / ref))

    def nll(p):   # -log Rayleigh(r; sigma^2 = u^2 / 2) up to constants
        u = np.maximum((p[0] + p[1] * s) * inflate, 1e-3)
        return float(np.sum(2 * np.log(u) + (r / u) ** 2))

    b0 = float(np.sqrt(np.mean((r / (s * inflate)) ** 2)))
    res = minimize(nll, [0.0, b0], method="L-BFGS-B", bounds=[(0.0, None), (0.0, None)])
    a, b = (float(v) for v in res.x)
    if not (res.success and a + b * s.min() > 0):
        a, b = 0.0, b0     # the plain scale (its own maximum-likelihood value)
    return {"uncertainty_offset_mm": a, "uncertainty_scale": b, "uncertainty_misfit_ref": ref}


def twin_match(site: SiteMap, fit: TwinFit, features: Features, start_xy_mm: np.ndarray, signal: SignalConfig,
               full_search: bool = False) -> dict:
    """The core's twin_match (twin.h; the board's TableModels runs the same) of every row: the twin's match
    around start_xy_mm (the forests' position; NaN rows: the forests did not run, and with one channel
    without an onset the physics three-sensor position starts it), leaving out a channel whose energies
    the twin cannot explain with the others'. Returns log10_height_mm (less the fit's edge term, twin_edge.py),
    xy_mm, spread_mm, misfit, status, left_out (-1 none) and reason (0, _core.TWIN_DEAD_CHANNEL,
    _core.TWIN_INCONSISTENT) per row. full_search: every channel tried in channel order (twin.h kTwinSearchFull)
    instead of the board's cued search."""
    f32 = lambda a: np.ascontiguousarray(np.asarray(a, np.float32))  # noqa: E731
    raw = features.raw
    misfit_ref = float(getattr(fit, "uncertainty_misfit_ref", 0.0) or 0.0)
    out = _core.twin_match_batch(
        np.ascontiguousarray(features.status, np.int32), np.ascontiguousarray(features.flags, np.uint8),
        f32(features.toa_us), f32(raw["window_energy"]), f32(raw["diff_energy"]), f32(features.phys_xy_mm),
        f32(np.asarray(start_xy_mm, float).reshape(-1, 2)), signal.localiser(), site.q, site.nx, site.ny,
        site.x0_mm, site.y0_mm, site.step_mm, f32(site.base), f32(site.scale), f32(fit.offset), f32(fit.slope),
        f32(fit.weight), fit.ref_log10_height_mm, fit.prior_mm, fit.cutoff_mm, fit.temperature, misfit_ref,
        _slowness_scales(features, signal), fit.coarse_cutoff_mm, int(getattr(fit, "weak_channel", -1)),
        full_search)
    # the height estimate's edge term at the matched position (twin_edge.py; the board's App subtracts it too)
    out["log10_height_mm"] = np.asarray(out["log10_height_mm"], float) - edge_term(
        fit, np.asarray(out["xy_mm"], float), signal.plate_x_mm, signal.plate_y_mm)
    return out


def _slowness_scales(features: Features, signal: SignalConfig) -> list[float]:
    """The localiser's per-channel travel-time factors of every row (impactcore dispersion_scales), flat; empty
    without dispersion (all 1)."""
    if not getattr(signal, "dispersion_exponent", 0.0):
        return []
    from .travel import slowness_scales

    return slowness_scales(features.raw["pick_period"], signal.fs_hz, signal.dispersion_exponent,
                           signal.dispersion_ref_hz).astype(np.float32).ravel().tolist()
