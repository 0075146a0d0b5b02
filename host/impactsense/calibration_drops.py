"""What the calibration drops (a few measured drops at known positions) teach a model trained on the twin's
virtual drops about the rig: the channels' timing offsets and gains, the picks' group velocity, the band
picks' constants, on an anisotropic plate the travel models themselves, and the twin's energy offsets
(docs/method.md, zero-shot; `zeroshot` puts them together)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares

from .data import Session
from .errors import DataError
from .materials import material_for_rig, travel_metric_sd
from .models import ARRIVAL_ENERGY_FEATURES, columns
from .pipeline import distances_mm, featurize
from .signal import SignalConfig
from .travel import (TravelPrior, fit_travel, fit_travel_map, picks, summed_log_energy,
                     travel_distances)


def calibration_rows(session: Session, cal: dict) -> np.ndarray:
    """Recording ids of the calibration drops (all repetitions of the calibration cases)."""
    if cal.get("exclude_recording_ids"):
        rows = np.asarray(cal["exclude_recording_ids"], int)
    elif cal.get("exclude_case_ids"):
        rows = np.flatnonzero(np.isin(session.case_id, np.asarray(cal["exclude_case_ids"], int)))
    else:
        raise DataError("CAL.json", "exclude_recording_ids", "calibration file names no calibration drops")
    if rows.size == 0 or rows.max() >= len(session):
        raise DataError("CAL.json", "exclude_recording_ids", "calibration drops do not belong to this session")
    return rows


def fit_channels_on_calibration_drops(session: Session, rows: np.ndarray, sim_adc: np.ndarray,
                                      signal: SignalConfig) -> tuple[list[float], list[float], float]:
    """The rig's channel effects the twin lacks, from the calibration drops only:
    gain = sqrt(median of measured / simulated energy), unclipped drops only, fitted first;
    then, picked with those gains, measured minus simulated ToA of drop k on channel i as
    c_k + delay_i + d_ik (1 / v_rig - 1 / v_twin) (path_misfit: d_ik the path length, c_k the drop's onset,
    removed by centring; soft-L1 as in `fit_localiser`): the delays (relative to channel 0) and the group
    velocity the rig's picks travel at, v_rig, given `signal.velocity_mm_per_us` as the twin's (fitted on
    virtual drops). Returns (delays, gains, v_rig)."""
    base = _record_time(signal)
    meas = featurize(session.adc[rows], base)
    sim = featurize(sim_adc, base)
    ok = np.isfinite(meas.toa_us).all(1) & np.isfinite(sim.toa_us).all(1)
    if ok.sum() < 2:
        raise DataError("calibration drops", None, "fewer than two calibration drops have an onset on every channel")
    gains = []
    for c in range(4):
        good = ok & ~meas.clipped[:, c] & ~sim.clipped[:, c]
        ratio = meas.energy[good, c].astype(float) / sim.energy[good, c].astype(float)
        gains.append(float(np.sqrt(np.median(ratio))) if good.any() else 1.0)
    # Delays with the gains applied, so the (amplitude-dependent) threshold picks see equal amplitudes.
    base.channel_gain = gains
    meas = featurize(session.adc[rows], base)
    diff = (meas.toa_us.astype(float) - sim.toa_us.astype(float))[ok]
    delays, slowness = path_misfit(diff, distances_mm(session.xy_mm[rows], base)[ok])
    velocity = 1.0 / (1.0 / signal.velocity_mm_per_us + slowness)
    return delays, gains, velocity


def _record_time(signal: SignalConfig) -> SignalConfig:
    """signal picking in record time, unit gains: the measured and simulated calibration drops share the capture
    (its delays cancel in their difference)."""
    base = SignalConfig.from_dict(signal.to_dict())
    base.rig_delay_us = [0.0, 0.0, 0.0, 0.0]
    base.capture_delay_us = [0.0, 0.0, 0.0, 0.0]
    base.band_delay_us = [0.0, 0.0, 0.0, 0.0]
    base.channel_gain = [1.0, 1.0, 1.0, 1.0]
    return base


def path_misfit(diff_us: np.ndarray, path_mm: np.ndarray) -> tuple[list[float], float]:
    """Measured minus simulated ToA [K, 4] of K drops as c_k + delay_i + d_ik ds (d_ik the path length [K, 4], c_k
    removed by centring; soft-L1): the delays relative to channel 0 and ds, the rig's slowness minus the twin's
    (us/mm)."""
    def residuals(p):
        r = diff_us - np.r_[0.0, p[:3]][None] - path_mm * p[3]
        return (r - r.mean(1, keepdims=True)).ravel()

    sol = least_squares(residuals, np.zeros(4), loss="soft_l1", f_scale=3.0)
    return [0.0] + [float(v) for v in sol.x[:3]], float(sol.x[3])


def fit_band_on_calibration_drops(session: Session, rows: np.ndarray, sim_adc: np.ndarray, signal: SignalConfig,
                                  gains: list[float]) -> tuple[list[float], float] | None:
    """The band picks' constants as the rig reads them, when `signal` (the localiser fitted on the virtual drops)
    has them on: measured minus simulated band ToA of the calibration drops (path_misfit, the band's travel
    metric's path lengths), on top of the virtual drops' band delays and velocity (the twin's own), as the
    threshold picks' are (fit_channels_on_calibration_drops). Without it the band localiser reads the rig with
    the twin's delays, not the rig's (docs/findings.md "Zero-shot: what limits it"). Returns (band delays,
    band velocity), or None when the band picks are off or fewer than two calibration drops have every band
    pick in both."""
    if not (signal.band_pick_hz > 0 and signal.band_velocity_mm_per_us > 0):
        return None
    base = _record_time(signal)
    sim = featurize(sim_adc, base).raw["toa_band_us"].astype(float)
    base.channel_gain = list(gains)
    meas = featurize(session.adc[rows], base).raw["toa_band_us"].astype(float)
    ok = np.isfinite(meas).all(1) & np.isfinite(sim).all(1)
    if ok.sum() < 2:
        return None
    metric = (signal.band_metric_xx, signal.band_metric_xy, signal.band_metric_yy)
    path = travel_distances(np.asarray(session.xy_mm, float)[rows][ok], signal.sensor_xy_mm, metric)
    delays, slowness = path_misfit((meas - sim)[ok], path)
    return ([float(a + b) for a, b in zip(signal.band_delay_us, delays)],
            float(1.0 / (1.0 / signal.band_velocity_mm_per_us + slowness)))


def refit_travel_metric(session: Session, rows: np.ndarray, signal: SignalConfig) -> tuple[SignalConfig, dict]:
    """On a plate whose localiser models elliptical wavefronts (travel.wants_metric: a laminate, an unknown
    material), `signal` with its travel models fitted again on the calibration drops `rows` at their known
    positions (travel.fit_travel: velocity, channel delays, the metric and the dispersion exponent of the
    threshold picks; velocity, delays and metric of the band picks when they are on, at the virtual drops'
    band frequency and fraction, the energy slowness's slope kept). The twin's anisotropy is the calibration's
    fast model's guess, and the FEM's picks do not follow it closely (docs/findings.md, the zero-shot section
    on the laminate: the FEM twin against the measured DToA). Unregularised: what many drops at known
    positions say (bench_zeroshot_diagnosis reads it on the calibration drops plus more cases); four drops
    go through map_travel_refit, which moves only as far as they determine. The onset threshold, AIC blend
    and band choice stay the virtual drops'. Returns (signal unchanged and {} when fewer than 8 drops have every pick; else the refitted
    signal and the record of the fit)."""
    toa, period = picks(session.adc[rows], signal, with_period=True)
    xy, sensors = np.asarray(session.xy_mm, float)[rows], signal.sensor_xy_mm
    try:
        fit = fit_travel(toa, xy, sensors, True, period, signal.fs_hz)
    except DataError:
        return signal, {}
    out = SignalConfig.from_dict(signal.to_dict())
    out.velocity_mm_per_us, out.rig_delay_us = fit.velocity_mm_per_us, list(fit.delays_us)
    out.travel_metric_xx, out.travel_metric_xy, out.travel_metric_yy = fit.metric
    out.dispersion_exponent, out.dispersion_ref_hz = fit.dispersion_exponent, fit.dispersion_ref_hz
    record = {"velocity_mm_per_us": fit.velocity_mm_per_us, "delays_us": list(fit.delays_us),
              "travel_metric": list(fit.metric), "dispersion_exponent": fit.dispersion_exponent}
    if signal.band_pick_hz > 0 and signal.band_velocity_mm_per_us > 0:
        raw = featurize(session.adc[rows], _band_picking(signal)).raw
        band = raw["toa_band_us"].astype(float)
        if signal.band_slowness_per_decade:     # the energy slowness's slope stays the virtual drops' (its
            # level is the refitted velocity)
            d = travel_distances(xy, sensors, (signal.band_metric_xx, signal.band_metric_xy, signal.band_metric_yy))
            loud = summed_log_energy(raw["energy"], signal.fs_hz) - signal.band_log_energy_ref
            band = band - d * signal.band_slowness_per_decade * loud[:, None]
        try:
            bfit = fit_travel(band, xy, sensors, True)
        except DataError:
            return out, record
        out.band_velocity_mm_per_us, out.band_delay_us = bfit.velocity_mm_per_us, list(bfit.delays_us)
        out.band_metric_xx, out.band_metric_xy, out.band_metric_yy = bfit.metric
        record.update(band_velocity_mm_per_us=bfit.velocity_mm_per_us, band_delay_us=list(bfit.delays_us),
                      band_metric=list(bfit.metric))
    return out, record


# The dispersion exponent's prior sd: alpha lies in [0, 1] (Kirchhoff's A0: 1/2), the range +- 2 sd.
ALPHA_SD = 0.25
# The slowness's prior sd in ln: uninformative (a factor e).
SLOWNESS_SD_LN = 1.0


def travel_priors(signal: SignalConfig, rig) -> dict[str, TravelPrior]:
    """The priors of the travel refit on the calibration drops (map_travel_refit), per pick set: centred on
    `signal`'s travel models (the virtual drops', i.e. the calibrated twin's), each constant as uncertain as
    the rig and its material leave it:
    - the channel delays: one sample interval of the logger (1 / fs_hz): a multiplexed logger's scan skew
      stays within one sample, and the electronics' and bonds' delays are a few us;
    - the slowness: not held (SLOWNESS_SD_LN): the four drops fix it to a few per cent, while the twin's own
      speed carries the calibration's modulus, which four unrepeatable cases can leave 2x off;
    - the metric's a and b: materials.travel_metric_sd (the spread of the ellipse over the material's prior
      range of E1, E2, G12; 0 on a known isotropic plate, which never refits);
    - the dispersion exponent: ALPHA_SD (the band picks have none)."""
    mat = material_for_rig(rig)
    common = {"sd_ln_slowness": SLOWNESS_SD_LN, "sd_delay_us": 1e6 / float(signal.fs_hz),
              "sd_metric": travel_metric_sd(mat)}
    out = {"threshold": TravelPrior(
        slowness_us_per_mm=1.0 / signal.velocity_mm_per_us, delays_us=tuple(float(v) for v in signal.rig_delay_us),
        a=(signal.travel_metric_xx - signal.travel_metric_yy) / 2, b=signal.travel_metric_xy,
        alpha=float(signal.dispersion_exponent), ref_hz=float(signal.dispersion_ref_hz), sd_alpha=ALPHA_SD,
        **common)}
    if signal.band_pick_hz > 0 and signal.band_velocity_mm_per_us > 0:
        out["band"] = TravelPrior(
            slowness_us_per_mm=1.0 / signal.band_velocity_mm_per_us,
            delays_us=tuple(float(v) for v in signal.band_delay_us),
            a=(signal.band_metric_xx - signal.band_metric_yy) / 2, b=signal.band_metric_xy, alpha=0.0,
            ref_hz=float(signal.dispersion_ref_hz), sd_alpha=0.0, **common)
    return out


def case_scatter(toa_us: np.ndarray, xy_mm: np.ndarray) -> float:
    """The robust sd of one pick between repetitions of a case (drop-centred picks minus their case's median,
    1.4826 MAD, with the n / (n - 1) of a median's own error); NaN when no case repeats."""
    toa = np.asarray(toa_us, float)
    ok = np.isfinite(toa).all(1)
    toa, xy = toa[ok] - toa[ok].mean(1, keepdims=True), np.asarray(xy_mm, float)[ok]
    groups = np.unique(np.round(xy, 1), axis=0, return_inverse=True)[1].ravel()
    dev = [((toa[groups == g] - np.median(toa[groups == g], 0)) * np.sqrt(n / (n - 1))).ravel()
           for g in np.unique(groups) for n in [int((groups == g).sum())] if n > 1]
    return float(1.4826 * np.median(np.abs(np.concatenate(dev)))) if dev else float("nan")


def map_travel_refit(session: Session, rows: np.ndarray, signal: SignalConfig,
                     virtual_signal: SignalConfig) -> tuple[SignalConfig, dict]:
    """On a plate whose localiser models elliptical wavefronts (travel.wants_metric), the travel models read
    from the calibration drops `rows` at their known positions as far as those drops determine them and no
    further: the maximum a posteriori fit (travel.fit_travel_map) of the threshold picks' slowness, delays,
    metric and dispersion and of the band picks' slowness, delays and metric, with priors at the virtual drops'
    constants (`virtual_signal`, the calibrated twin's) and the sds of travel_priors. The noise is the picks'
    own: their scatter between repetitions of a case (case_scatter) and, shared by a case's repetitions, the
    travel model's misfit on the virtual drops (virtual_signal.sigma_us). Four repeatable cases move the
    constants to the rig's; four whose repetitions scatter by a cycle leave them near the twin's.
    `signal` is the model's after the channel gains (the threshold picks depend on the amplitude); the onset
    threshold, AIC blend, band frequency and the energy slowness's slope stay the virtual drops'. Returns the
    signal with the refitted constants and the record (per pick set: prior, fit, posterior sd, noise)."""
    xy, sensors = np.asarray(session.xy_mm, float)[rows], signal.sensor_xy_mm
    priors = travel_priors(virtual_signal, session.rig)
    model_sd = float(virtual_signal.sigma_us)
    out = SignalConfig.from_dict(signal.to_dict())
    record = {}

    def fit(name, toa, period=None):
        pick_sd = case_scatter(toa, xy)
        pick_sd = pick_sd if np.isfinite(pick_sd) and pick_sd > 0 else model_sd
        f, post = fit_travel_map(toa, xy, sensors, priors[name], pick_sd, model_sd, period,
                                 signal.fs_hz if period is not None else None)
        p = priors[name]
        record[name] = {"velocity_mm_per_us": f.velocity_mm_per_us, "delays_us": list(f.delays_us),
                        "travel_metric": list(f.metric), "dispersion_exponent": f.dispersion_exponent,
                        "posterior_sd": post, "pick_sd_us": pick_sd, "model_sd_us": model_sd,
                        "prior": {"velocity_mm_per_us": 1.0 / p.slowness_us_per_mm, "delays_us": list(p.delays_us),
                                  "metric_a": p.a, "metric_b": p.b, "alpha": p.alpha,
                                  "sd_ln_slowness": p.sd_ln_slowness, "sd_delay_us": p.sd_delay_us,
                                  "sd_metric": p.sd_metric, "sd_alpha": p.sd_alpha}}
        return f

    toa, period = picks(session.adc[rows], signal, with_period=True)
    known = np.isfinite(period) & (period > 0)
    if priors["threshold"].alpha == 0 and known.any():   # no dispersion in the twin: its slowness is the one
        # at the rig's picked frequencies
        priors["threshold"] = replace(priors["threshold"], ref_hz=float(np.median(signal.fs_hz / period[known])))
    try:
        f = fit("threshold", toa, period)
    except DataError:
        return signal, {}
    out.velocity_mm_per_us, out.rig_delay_us = f.velocity_mm_per_us, list(f.delays_us)
    out.travel_metric_xx, out.travel_metric_xy, out.travel_metric_yy = f.metric
    out.dispersion_exponent, out.dispersion_ref_hz = f.dispersion_exponent, f.dispersion_ref_hz
    if "band" in priors:
        raw = featurize(session.adc[rows], _band_picking(signal)).raw
        band = raw["toa_band_us"].astype(float)
        if signal.band_slowness_per_decade:     # the energy slowness's slope stays the virtual drops'
            d = travel_distances(xy, sensors, (signal.band_metric_xx, signal.band_metric_xy, signal.band_metric_yy))
            loud = summed_log_energy(raw["energy"], signal.fs_hz) - signal.band_log_energy_ref
            band = band - d * signal.band_slowness_per_decade * loud[:, None]
        try:
            bf = fit("band", band)
        except DataError:
            return out, record
        out.band_velocity_mm_per_us, out.band_delay_us = bf.velocity_mm_per_us, list(bf.delays_us)
        out.band_metric_xx, out.band_metric_xy, out.band_metric_yy = bf.metric
    return out, record


def _band_picking(signal: SignalConfig) -> SignalConfig:
    """signal picking the band in record time with its channel gains and capture delays (refit_travel_metric)."""
    return SignalConfig.from_dict({**_record_time(signal).to_dict(), "channel_gain": list(signal.channel_gain),
                                   "capture_delay_us": list(signal.capture_delay_us)})


def fit_energy_offsets(session: Session, rows: np.ndarray, sim_adc: np.ndarray, measured: SignalConfig,
                       simulated: SignalConfig) -> dict[str, float]:
    """Median over the calibration drops of measured minus simulated arrival-energy features (log10)."""
    meas = featurize(session.adc[rows], measured)
    sim = featurize(sim_adc, simulated)
    ok = meas.usable & sim.usable
    if ok.sum() < 2:
        raise DataError("calibration drops", None, "fewer than two calibration drops are usable in both")
    cols = columns(ARRIVAL_ENERGY_FEATURES)
    diff = np.median(meas.vector[ok][:, cols].astype(float) - sim.vector[ok][:, cols].astype(float), axis=0)
    return {name: float(v) for name, v in zip(ARRIVAL_ENERGY_FEATURES, diff)}
