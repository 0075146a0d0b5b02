"""The physics localiser's travel-time model, fitted on training drops: velocity, channel delays, the travel
metric of an anisotropic plate, and the onset threshold the core picks with.

Model (docs/method.md "Travel-time model"): ToA_ik = t0_k + |p_k - s_i|_Q / v + delay_i, with
|d|_Q = sqrt(d^T Q d), Q = [[1 + a, b], [b, 1 - a]] (trace 2: v stays the mean speed; Q = I on an isotropic
plate). On an orthotropic plate flexural wavefronts are close to ellipses whose axes are the material's; Q
carries them into the core's localiser (impactcore.h travel_metric_*). t0_k is eliminated by centring each
drop's residuals; a soft-L1 loss keeps cycle-skipped picks from steering the fit.

Dispersion: on a flexural plate higher frequencies travel faster, and the cycle a threshold catches arrives
with its own frequency's group velocity. The core measures the period of that cycle (impactcore.h pick_period)
and the localiser scales each channel's slowness by (f / f_ref)^-alpha, f = fs / period. alpha is fitted
with the rest and kept only when it explains the picks clearly better (DISPERSION_GAIN); f_ref is the
training picks' median frequency (Kirchhoff's A0 has alpha = 1/2; a noisy period attenuates the fit).

The onset threshold: a dispersive plate (a stiff metal, a laminate) sends a weak, fast precursor ahead of the
main flexural arrival; a threshold near the noise catches one cycle of it or another from drop to drop. The
threshold (and the AIC blend, among the configured one and AIC_BLENDS) is chosen from a few multiples of the
rig's default by how well the fitted model explains the training drops' picks (robust residual spread in mm, i.e. times the velocity), so the core's own picker
decides and nothing is tuned to one plate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from . import _core
from .errors import DataError  # a ValueError too
from .signal import SignalConfig

THRESHOLD_FACTORS = (1.0, 2.0, 3.0, 5.0, 8.0)
# A candidate threshold replaces the default only when it explains the training picks this much better.
THRESHOLD_GAIN = 0.85
VELOCITY_SCAN_MM_PER_US = np.geomspace(0.2, 10.0, 120)
# AIC blends tried beside the configured one: with the dispersion term the threshold crossing, whose cycle's
# period the core measures, is the consistent pick, and less of the AIC onset can explain the picks better.
AIC_BLENDS = (0.2, 0.0)
# The dispersion term is kept when it brings the robust residual spread below this fraction of the fit
# without it.
DISPERSION_GAIN = 0.95
# Under a cost budget (the board's refit: pipeline.fit_localiser's `fits`) the travel metric of a plate of an
# unknown material is kept when it brings the robust residual spread out of fold (METRIC_FOLDS folds of the
# training drops' sites) below this fraction of the isotropic fit's: an isotropic plate then gets the Euclidean
# distance, the core's cheaper localiser form (board/cost.py). In sample the metric's two parameters lower the
# spread on an isotropic plate too (docs/findings.md "Session 23: boardfit").
METRIC_GAIN = 0.95
METRIC_FOLDS = 5


@dataclass
class TravelFit:
    velocity_mm_per_us: float
    delays_us: list[float]          # channel 0 first (0), relative
    metric: tuple[float, float, float]   # Q_xx, Q_xy, Q_yy
    spread_us: float                # robust sd of the residuals (1.4826 MAD)
    n: int
    dispersion_exponent: float = 0.0   # alpha of the slowness (f / f_ref)^-alpha
    dispersion_ref_hz: float = 25000.0

    @property
    def spread_mm(self) -> float:
        return self.spread_us * self.velocity_mm_per_us


def metric_of(a: float, b: float) -> tuple[float, float, float]:
    return (1.0 + a, b, 1.0 - a)


def travel_distances(xy_mm: np.ndarray, sensor_xy_mm: np.ndarray, metric=(1.0, 0.0, 1.0)) -> np.ndarray:
    """|p - s_i|_Q for every position [R, 2] and sensor [4, 2] -> [R, 4]."""
    dx = np.asarray(xy_mm, float)[:, None, 0] - sensor_xy_mm[None, :, 0]
    dy = np.asarray(xy_mm, float)[:, None, 1] - sensor_xy_mm[None, :, 1]
    qxx, qxy, qyy = metric
    return np.sqrt(np.maximum(qxx * dx * dx + 2 * qxy * dx * dy + qyy * dy * dy, 0.0))


def _centred(r: np.ndarray) -> np.ndarray:
    return r - r.mean(1, keepdims=True)


def _start_slowness(toa: np.ndarray, d: np.ndarray) -> float:
    """The slowness (us/mm) of least median |residual| over a log scan of velocities: a start that does not
    depend on the plate's material."""
    best, best_s = np.inf, 1.0
    for v in VELOCITY_SCAN_MM_PER_US:
        r = _centred(toa - d / v)
        r = _centred(r - np.median(r, 0, keepdims=True))   # channel delays, roughly
        score = float(np.median(np.abs(r)))
        if score < best:
            best, best_s = score, 1.0 / v
    return best_s


def slowness_scales(period_samples, fs_hz: float, exponent: float, ref_hz: float) -> np.ndarray:
    """(f / ref_hz)^-exponent per pick, f = fs_hz / period (1 where the period is unknown): the travel-time
    factors the core's localiser applies (impactcore dispersion_scales)."""
    period = np.asarray(period_samples, float)
    ok = np.isfinite(period) & (period > 0)
    out = np.ones(period.shape)
    out[ok] = (fs_hz / (period[ok] * ref_hz)) ** (-exponent)
    return out


def channels_in_use(left_out, n_channels: int = 4) -> np.ndarray:
    """[n_channels] bool: the channels a model reads (not in `left_out`, the core's channel_left_out flags)."""
    flags = np.zeros(n_channels, bool) if left_out is None else np.asarray(left_out, bool)
    return ~flags


def complete_drops(toa_us: np.ndarray, left_out=None) -> np.ndarray:
    """[R] bool: the drops with an onset on every channel in use (a left-out channel has none by design)."""
    toa = np.asarray(toa_us, float)
    return np.isfinite(toa[:, channels_in_use(left_out, toa.shape[1])]).all(1)


def fit_travel(toa_us: np.ndarray, xy_mm: np.ndarray, sensor_xy_mm: np.ndarray,
               anisotropic: bool | None, period_samples: np.ndarray | None = None, fs_hz: float | None = None,
               left_out=None) -> TravelFit:
    """Velocity, channel delays (relative to the first channel in use, channel 0 unless left out) and, when
    anisotropic, the metric's a, b; with the picks' periods (samples at fs_hz) also the dispersion exponent,
    kept when it explains the picks clearly better (DISPERSION_GAIN). anisotropic None (metric_choice: an unknown
    material): both fits, the metric's kept when it explains held-out drops' picks clearly better (METRIC_GAIN,
    held_out_spread_us). left_out:
    the core's channel_left_out flags; those channels are not read (their delay 0) and need no onset."""
    if anisotropic is None:
        iso = fit_travel(toa_us, xy_mm, sensor_xy_mm, False, period_samples, fs_hz, left_out)
        aniso = fit_travel(toa_us, xy_mm, sensor_xy_mm, True, period_samples, fs_hz, left_out)
        spread = {a: held_out_spread_us(toa_us, xy_mm, sensor_xy_mm, a, period_samples, fs_hz, left_out)
                  for a in (False, True)}
        return aniso if spread[True] < METRIC_GAIN * spread[False] else iso
    toa = np.asarray(toa_us, float)
    use = channels_in_use(left_out, toa.shape[1])
    if use.sum() < 3:
        raise DataError("training drops", "adc", f"only {int(use.sum())} channels in use (need 3 to place a drop)")
    ok = complete_drops(toa, left_out)
    if ok.sum() < 8:
        raise DataError("training drops", "adc", f"only {int(ok.sum())} have an onset on every channel in use "
                        "(need 8: a dead or clipped channel in every drop?)")
    toa, xy, sensors = toa[ok][:, use], np.asarray(xy_mm, float)[ok], np.asarray(sensor_xy_mm, float)[use]
    d0 = travel_distances(xy, sensors)
    s0 = _start_slowness(toa, d0)
    fit = _fit(toa, xy, d0, s0, sensors, anisotropic, None, 25000.0)
    if period_samples is not None and fs_hz is not None:
        period = np.asarray(period_samples, float)[ok][:, use]
        known = np.isfinite(period) & (period > 0)
        if known.mean() >= 0.5:
            ref_hz = float(np.median(fs_hz / period[known]))
            disp = _fit(toa, xy, d0, s0, sensors, anisotropic, (period, fs_hz), ref_hz)
            fit = disp if disp.spread_us < DISPERSION_GAIN * fit.spread_us else fit
    if not use.all():
        delays = np.zeros(len(use))
        delays[use] = fit.delays_us
        fit.delays_us = [float(v) for v in delays]
    return fit


def travel_residuals(fit: TravelFit, toa_us: np.ndarray, xy_mm: np.ndarray, sensor_xy_mm: np.ndarray,
                     period_samples: np.ndarray | None = None, fs_hz: float | None = None, left_out=None) -> np.ndarray:
    """Each drop's residuals (us) under `fit` (its metric, velocity, delays and dispersion), centred over the
    channels in use: [R', channels in use], the drops with every pick of those."""
    toa = np.asarray(toa_us, float)
    use, ok = channels_in_use(left_out, toa.shape[1]), complete_drops(toa, left_out)
    d = travel_distances(np.asarray(xy_mm, float)[ok], np.asarray(sensor_xy_mm, float), fit.metric)
    if period_samples is not None and fs_hz is not None:
        d = d * slowness_scales(np.asarray(period_samples, float)[ok], fs_hz, fit.dispersion_exponent,
                                fit.dispersion_ref_hz)
    r = toa[ok] - d / fit.velocity_mm_per_us - np.asarray(fit.delays_us, float)[None]
    return _centred(r[:, use])


def held_out_spread_us(toa_us: np.ndarray, xy_mm: np.ndarray, sensor_xy_mm: np.ndarray, anisotropic: bool,
                       period_samples: np.ndarray | None = None, fs_hz: float | None = None, left_out=None,
                       folds: int = METRIC_FOLDS) -> float:
    """The robust spread (1.4826 MAD, us) of the residuals of drops under a fit_travel made without their site:
    the drops' sites (their positions) in `folds` folds; inf when a fold's fit fails or there are fewer sites
    than 2 x folds."""
    xy = np.asarray(xy_mm, float)
    site = np.unique(np.round(xy, 1), axis=0, return_inverse=True)[1].ravel()
    if site.max(initial=-1) + 1 < 2 * folds:
        return float("inf")
    fold = np.random.default_rng(0).permutation(site.max() + 1)[site] % folds
    period = None if period_samples is None else np.asarray(period_samples, float)
    toa = np.asarray(toa_us, float)
    out = []
    for f in range(folds):
        held = fold == f
        try:
            fit = fit_travel(toa[~held], xy[~held], sensor_xy_mm, anisotropic,
                             None if period is None else period[~held], fs_hz, left_out)
        except ValueError:
            return float("inf")
        out.append(travel_residuals(fit, toa[held], xy[held], sensor_xy_mm,
                                    None if period is None else period[held], fs_hz, left_out).ravel())
    r = np.concatenate(out)
    return float(1.4826 * np.median(np.abs(r))) if r.size else float("inf")


def _fit(toa, xy, d0, s0, sensor_xy_mm, anisotropic: bool, periods, ref_hz: float) -> TravelFit:
    n_metric = 2 if anisotropic else 0
    k = toa.shape[1]         # the channels fitted: slowness, k - 1 delays, the metric, alpha

    def unpack(p):
        a, b = (p[k], p[k + 1]) if anisotropic else (0.0, 0.0)
        alpha = p[k + n_metric] if periods is not None else 0.0
        return p[0], np.r_[0.0, p[1:k]], metric_of(a, b), alpha

    def residuals(p):
        s, delay, q, alpha = unpack(p)
        d = d0 if not anisotropic else travel_distances(xy, sensor_xy_mm, q)
        if periods is not None:
            d = d * slowness_scales(periods[0], periods[1], alpha, ref_hz)
        return _centred(toa - d * s - delay[None]).ravel()

    p0 = [s0] + [0.0] * (k - 1) + [0.0] * n_metric + ([0.0] if periods is not None else [])
    lo = [1e-3] + [-np.inf] * (k - 1) + [-0.9] * n_metric + ([0.0] if periods is not None else [])
    hi = [np.inf] * k + [0.9] * n_metric + ([1.0] if periods is not None else [])
    sol = least_squares(residuals, p0, bounds=(lo, hi), loss="soft_l1", f_scale=3.0)
    s, delay, q, alpha = unpack(sol.x)
    r = residuals(sol.x)
    return TravelFit(velocity_mm_per_us=float(1.0 / s), delays_us=[float(v) for v in delay],
                     metric=tuple(float(v) for v in q), spread_us=float(1.4826 * np.median(np.abs(r))),
                     n=len(toa), dispersion_exponent=float(alpha), dispersion_ref_hz=float(ref_hz))


def summed_log_energy(energy: np.ndarray, fs_hz: float) -> np.ndarray:
    """log10(sum_c E_c / fs) per drop, E the core's channel energies [R, 4] (counts^2 samples): the core's own
    number (impactcore summed_log_energy, which its band localiser reads); NaN where the sum is not positive."""
    return _core.summed_log_energy_batch(np.ascontiguousarray(energy, np.float32), float(fs_hz)).astype(float)


def fit_energy_slowness(toa_us: np.ndarray, xy_mm: np.ndarray, sensor_xy_mm: np.ndarray, fit: TravelFit,
                        log_energy: np.ndarray, left_out=None) -> tuple[float, float, float] | None:
    """The band picks' slowness as a line in the drops' summed log energy: each training drop's own slowness
    (its centred residuals under `fit` regressed on its centred travel distances) fitted against log_energy
    (least squares). Returns (velocity at the reference, slope in us/mm per decade, reference log energy: the
    training drops' median), i.e. slowness = 1 / velocity + slope (log_energy - reference); None when fewer than
    8 drops have every pick (of the channels in use: not in left_out) and an energy."""
    use = channels_in_use(left_out, np.asarray(toa_us).shape[1])
    toa = (np.asarray(toa_us, float) - np.asarray(fit.delays_us, float)[None])[:, use]
    d = travel_distances(xy_mm, np.asarray(sensor_xy_mm, float)[use], fit.metric)
    r = _centred(toa - d / fit.velocity_mm_per_us)
    dc = _centred(d)
    with np.errstate(invalid="ignore", divide="ignore"):
        own = (r * dc).sum(1) / (dc * dc).sum(1)
    le = np.asarray(log_energy, float)
    ok = np.isfinite(own) & np.isfinite(le)
    if ok.sum() < 8:
        return None
    c0, c1 = np.linalg.lstsq(np.c_[np.ones(ok.sum()), le[ok]], own[ok], rcond=None)[0]
    ref = float(np.median(le[ok]))
    slowness = 1.0 / fit.velocity_mm_per_us + c0 + c1 * ref
    if not slowness > 0:
        return None
    return float(1.0 / slowness), float(c1), ref


def wants_metric(rig) -> bool:
    """Fit the travel metric unless the rig's material is a known isotropic one (materials.py)."""
    from .materials import material_for_rig

    mat = material_for_rig(rig)
    return mat.orthotropic or not mat.known


def metric_choice(rig) -> bool | None:
    """fit_travel's `anisotropic` for a model trained on the rig's drops under a cost budget (the board's refit):
    True on an orthotropic material (the metric fitted), False on a known isotropic one, None on an unknown
    material (the metric fitted and kept only when it explains held-out drops' picks clearly better:
    METRIC_GAIN). Without a budget the host fits the metric wherever wants_metric says."""
    from .materials import material_for_rig

    mat = material_for_rig(rig)
    return True if mat.orthotropic else (False if mat.known else None)


def picks(adc: np.ndarray, cfg: SignalConfig, with_period: bool = False, **overrides):
    """The core's ToA (us) with the rig's delays off (the capture's still removed) and `overrides`: [R, 4];
    with_period: also the picks' periods (samples, impactcore pick_period)."""
    from .pipeline import as_int16

    trial = SignalConfig.from_dict({**cfg.to_dict(), "rig_delay_us": [0.0] * 4, **overrides})
    raw = _core.extract_batch(as_int16(adc, trial), trial.core())
    toa = raw["toa_us"].astype(float)
    return (toa, raw["pick_period"].astype(float)) if with_period else toa


def choose_threshold(adc: np.ndarray, xy_mm: np.ndarray, cfg: SignalConfig, anisotropic: bool,
                     rig_drops: tuple[np.ndarray, np.ndarray] | None = None,
                     ) -> tuple[float, float, TravelFit, list[dict]]:
    """The onset threshold (counts) among THRESHOLD_FACTORS x the configured one, and the AIC blend among the
    configured one and AIC_BLENDS, whose travel fit explains the training picks best (robust spread in mm);
    the configured pair unless another is clearly better (`chosen_trial`). rig_drops (adc, xy_mm): the training
    drops are a calibrated twin's virtual drops and these the rig's calibration drops; among the pairs the
    virtual drops cannot tell apart, the one whose twin travel law explains the rig's picks best
    (`transfer_spread_mm`). Returns threshold, blend, fit, the trials."""
    base, base_blend = float(cfg.onset_threshold_counts), float(cfg.aic_blend)
    blends = [base_blend] + [b for b in AIC_BLENDS if b != base_blend]
    trials = []
    for f in THRESHOLD_FACTORS:
        thr = base * f
        for blend in blends:
            try:
                toa, period = picks(adc, cfg, with_period=True, onset_threshold_counts=thr, aic_blend=blend)
                fit = fit_travel(toa, xy_mm, cfg.sensor_xy_mm, anisotropic, period, cfg.fs_hz,
                                 left_out=cfg.channel_left_out)
            except ValueError:
                continue
            trials.append({"onset_threshold_counts": thr, "aic_blend": blend, "spread_mm": fit.spread_mm, "fit": fit})
    if not trials:
        raise DataError("training drops", "adc", "no onset threshold gives an onset on every channel in use of 8 "
                        "of them (a dead or clipped channel in every drop?)")
    if rig_drops is not None:
        best = min(t["spread_mm"] for t in trials)
        for t in trials:
            if THRESHOLD_GAIN * t["spread_mm"] <= best:
                toa, period = picks(rig_drops[0], cfg, with_period=True, onset_threshold_counts=t["onset_threshold_counts"],
                                    aic_blend=t["aic_blend"])
                t["rig_spread_mm"] = transfer_spread_mm(t["fit"], toa, rig_drops[1], cfg.sensor_xy_mm, period,
                                                        cfg.fs_hz, cfg.channel_left_out)
    chosen = chosen_trial(trials, base, base_blend)
    table = [{k: v for k, v in t.items() if k != "fit"} for t in trials]
    return chosen["onset_threshold_counts"], chosen["aic_blend"], chosen["fit"], table


def chosen_trial(trials: list[dict], base: float, base_blend: float) -> dict:
    """The threshold trial `choose_threshold` keeps: the configured pair (base, base_blend, trials[0]) unless
    another explains the training picks clearly better (THRESHOLD_GAIN). When the trials carry the rig's
    `rig_spread_mm` (a twin's virtual drops, scored on the rig's calibration drops): among the trials whose
    spread is within THRESHOLD_GAIN of the best, the one with the least rig spread, when it is clearly less
    (the same THRESHOLD_GAIN) than the rig spread of the trial the virtual drops chose. The twin is cleaner than the
    rig ahead of the flexural arrival (lab noise, glitches, offsets and what the plate model leaves out reach a
    low threshold on the rig, not on the twin), so which of the thresholds the twin cannot tell apart transfers
    is for the rig's own drops to say (docs/findings.md "The zero-shot localiser's onset threshold")."""
    best = min(trials, key=lambda t: t["spread_mm"])
    chosen = trials[0]
    configured = chosen["onset_threshold_counts"] == base and chosen["aic_blend"] == base_blend
    if not configured or best["spread_mm"] < THRESHOLD_GAIN * chosen["spread_mm"]:
        chosen = best
    scored = [t for t in trials if np.isfinite(t.get("rig_spread_mm", np.nan))
              and THRESHOLD_GAIN * t["spread_mm"] <= best["spread_mm"]]
    if not scored:
        return chosen
    rig_best = min(scored, key=lambda t: t["rig_spread_mm"])
    ref = chosen.get("rig_spread_mm", np.nan)
    return rig_best if rig_best["rig_spread_mm"] < THRESHOLD_GAIN * (ref if np.isfinite(ref) else np.inf) else chosen


def transfer_spread_mm(fit: TravelFit, toa_us: np.ndarray, xy_mm: np.ndarray, sensor_xy_mm: np.ndarray,
                       period_samples: np.ndarray, fs_hz: float, left_out=None) -> float:
    """How well a travel law fitted on other drops (a twin's: its metric and dispersion) explains these drops'
    picks (a rig's calibration drops) when what a rig may change is fitted: the channel delays and the
    slowness. The robust spread of the residuals (1.4826 MAD) in mm at the fitted speed; NaN with fewer than 2
    drops with every pick."""
    toa = np.asarray(toa_us, float)
    use, ok = channels_in_use(left_out, toa.shape[1]), complete_drops(toa, left_out)
    if ok.sum() < 2:
        return float("nan")
    toa = toa[ok][:, use]
    d = (travel_distances(np.asarray(xy_mm, float)[ok], np.asarray(sensor_xy_mm, float), fit.metric)[:, use]
         * slowness_scales(np.asarray(period_samples, float)[ok][:, use], fs_hz, fit.dispersion_exponent,
                           fit.dispersion_ref_hz))

    def residuals(p):
        return _centred(toa - d * p[0] - np.r_[0.0, p[1:]][None]).ravel()

    sol = least_squares(residuals, [1.0 / fit.velocity_mm_per_us] + [0.0] * (toa.shape[1] - 1), loss="soft_l1",
                        f_scale=3.0)
    return float(1.4826 * np.median(np.abs(residuals(sol.x))) / sol.x[0])


@dataclass(frozen=True)
class TravelPrior:
    """What a travel model's constants are expected to be before a few drops at known positions are read, and
    how far off that may be (1 sd): the slowness [us/mm] (sd in ln), the channel delays [us, channel 0 first],
    the metric's a, b (Q = [[1 + a, b], [b, 1 - a]]) and the dispersion exponent (with its reference frequency)."""

    slowness_us_per_mm: float
    delays_us: tuple[float, float, float, float]
    a: float
    b: float
    alpha: float
    ref_hz: float
    sd_ln_slowness: float
    sd_delay_us: float
    sd_metric: float
    sd_alpha: float


def _soft_l1_root(r: np.ndarray, scale: float) -> np.ndarray:
    """The signed root of the soft-L1 loss 2 c^2 (sqrt(1 + (r / c)^2) - 1): r near 0, ~sqrt(2 c |r|) far out."""
    return np.sign(r) * scale * np.sqrt(2.0 * (np.sqrt(1.0 + (r / scale) ** 2) - 1.0))


def fit_travel_map(toa_us: np.ndarray, xy_mm: np.ndarray, sensor_xy_mm: np.ndarray, prior: TravelPrior,
                   pick_sd_us: float, model_sd_us: float, period_samples: np.ndarray | None = None,
                   fs_hz: float | None = None) -> tuple[TravelFit, dict]:
    """The travel model ToA_ik = t0_k + |p_k - s_i|_Q s (f_ik / f_ref)^-alpha + delay_i (fit_travel's) from a few
    drops at known positions, as the maximum a posteriori estimate under `prior`: the drops' centred residuals
    weighted by their noise, each constant pulled toward the prior by its sd. Drops at one position share that
    position's model error (model_sd_us, the travel law's own misfit), so a case of n repetitions counts as
    one observation of variance pick_sd^2 / n + model_sd^2, not n; the residuals pass a soft-L1 at pick_sd_us
    (a cycle slip of one drop does not steer the fit). What the drops determine moves; what they do not stays
    at the prior. Dispersion is fitted when the picks' periods are given and the prior's alpha sd is > 0.
    Returns the fit (its spread the robust sd of the residuals) and the posterior sd of each constant (the
    Gauss-Newton covariance at the optimum)."""
    toa = np.asarray(toa_us, float)
    ok = np.isfinite(toa).all(1)
    if ok.sum() < 2:
        raise DataError("calibration drops", "adc", f"only {int(ok.sum())} have an onset on every channel (need 2)")
    toa, xy = toa[ok], np.asarray(xy_mm, float)[ok]
    groups = np.unique(np.round(xy, 1), axis=0, return_inverse=True)[1].ravel()
    n_case = np.bincount(groups)[groups].astype(float)
    weight = 1.0 / np.sqrt(pick_sd_us ** 2 + n_case * model_sd_us ** 2)          # [K]
    outlier_us = math.hypot(pick_sd_us, model_sd_us)     # a drop's residual beyond its expected size
    periods = None
    if period_samples is not None and fs_hz is not None and prior.sd_alpha > 0:
        periods = np.asarray(period_samples, float)[ok]
    p0 = np.r_[np.log(prior.slowness_us_per_mm), prior.delays_us[1:], prior.a, prior.b, prior.alpha]
    sd = np.maximum(np.r_[prior.sd_ln_slowness, [prior.sd_delay_us] * 3, prior.sd_metric, prior.sd_metric,
                          prior.sd_alpha], 1e-9)      # a zero sd pins the constant at the prior

    def unpack(p):
        return math.exp(p[0]), np.r_[0.0, p[1:4]], metric_of(p[4], p[5]), (p[6] if periods is not None else 0.0)

    def centred_residuals(p):
        s, delay, q, alpha = unpack(p)
        d = travel_distances(xy, sensor_xy_mm, q)
        if periods is not None:
            d = d * slowness_scales(periods, fs_hz, alpha, prior.ref_hz)
        return _centred(toa - d * s - delay[None])

    def residuals(p):
        r = _soft_l1_root(centred_residuals(p), outlier_us) * weight[:, None]
        return np.r_[r.ravel(), (p - p0) / sd]

    lo = np.r_[-np.inf, [-np.inf] * 3, -0.9, -0.9, 0.0]
    hi = np.r_[np.inf, [np.inf] * 3, 0.9, 0.9, 1.0]
    sol = least_squares(residuals, np.clip(p0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi), x_scale=sd)
    s, delay, q, alpha = unpack(sol.x)
    r = centred_residuals(sol.x)
    fit = TravelFit(velocity_mm_per_us=float(1.0 / s), delays_us=[float(v) for v in delay],
                    metric=tuple(float(v) for v in q), spread_us=float(1.4826 * np.median(np.abs(r))),
                    n=int(ok.sum()), dispersion_exponent=float(alpha), dispersion_ref_hz=float(prior.ref_hz))
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac)
        post = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        post = sd
    names = ("ln_slowness", "delay_1_us", "delay_2_us", "delay_3_us", "metric_a", "metric_b", "alpha")
    posterior = {n: float(v) for n, v in zip(names, post) if n != "alpha" or periods is not None}
    return fit, posterior
