"""recording -> signal core -> features: the host side of the one path through the data.

Every number here comes from the C++ core (`impactsense._core`, compiled from firmware/lib/impactcore);
this module fits the physics localiser's two constants (group velocity and
per-channel delays) on training drops, and arranges the core's outputs as arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _core
from .data import Session
from .signal import SignalConfig, core_samples, core_window

FEATURE_NAMES: list[str] = list(_core.FEATURE_NAMES)
PAIRS = list(zip(_core.PAIR_I, _core.PAIR_J))


@dataclass
class Features:
    """The core's view of a set of recordings (row k = recording k)."""

    vector: np.ndarray        # float32 [R, n_features] in FEATURE_NAMES order
    phys_xy_mm: np.ndarray    # float32 [R, 2] physics localiser
    phys_cov: np.ndarray      # float32 [R, 3] cov_xx, cov_xy, cov_yy (mm^2)
    accepted: np.ndarray      # bool [R] Eq. 35
    status: np.ndarray        # int32 [R] core status (0 ok)
    flags: np.ndarray         # uint8 [R, 4] per-channel flags
    toa_us: np.ndarray        # float32 [R, 4] (channel delays removed)
    energy: np.ndarray        # float32 [R, 4]
    raw: dict                 # every array extract_batch returned
    left_out: tuple = (0, 0, 0, 0)   # the config's channel_left_out: channels without an onset by design

    def __len__(self) -> int:
        return int(self.vector.shape[0])

    def take(self, rows: np.ndarray) -> "Features":
        rows = np.asarray(rows)
        return Features(self.vector[rows], self.phys_xy_mm[rows], self.phys_cov[rows], self.accepted[rows],
                        self.status[rows], self.flags[rows], self.toa_us[rows], self.energy[rows],
                        {k: v[rows] for k, v in self.raw.items()}, self.left_out)

    @property
    def clipped(self) -> np.ndarray:
        return (self.flags & _core.FLAG_CLIPPED) != 0

    @property
    def dead(self) -> np.ndarray:
        return (self.flags & _core.FLAG_DEAD) != 0

    @property
    def no_onset(self) -> np.ndarray:
        return (self.flags & _core.FLAG_NO_ONSET) != 0

    @property
    def usable(self) -> np.ndarray:
        """Rows the core processed with an onset on every channel in use (not left out) and a finite feature
        vector but for the columns that read a left-out channel's onset (NaN by design)."""
        use = ~np.asarray(self.left_out, bool)
        read = columns_reading(self.left_out, FEATURE_NAMES, keep=True)
        return ((self.status == _core.STATUS_OK) & ~self.no_onset[:, use].any(1)
                & np.isfinite(self.vector[:, read]).all(1))


def onset_columns(channel: int, names: list[str]) -> list[str]:
    """The feature names that read `channel`'s onset (the core leaves them NaN when it has none): the arrival
    time differences with it, its relative arrival time and its residual ratio."""
    own = {f"rel_toa_{channel}_us", f"residual_ratio_{channel}"}
    pairs = {f"dtoa_{i}{j}_us" for i, j in PAIRS if channel in (i, j)}
    return [n for n in names if n in own | pairs]


def columns_reading(left_out, names: list[str], keep: bool = False) -> list:
    """The names of `names` that read no left-out channel's onset (keep: their indices in `names` instead)."""
    drop = {n for c, v in enumerate(left_out) if v for n in onset_columns(c, names)}
    return [k for k, n in enumerate(names) if n not in drop] if keep else [n for n in names if n not in drop]


def as_int16(adc: np.ndarray, cfg: SignalConfig | None = None) -> np.ndarray:
    """The rig's ADC counts as the core's int16 samples for cfg (signal.core_samples: a 16-bit logger's
    re-centred); without cfg, counts of an ADC of up to 15 bits as they are."""
    if cfg is not None:
        return core_samples(adc, cfg)
    adc = np.asarray(adc)
    if adc.ndim == 2:
        adc = adc[None]
    adc = core_window(adc)
    if adc.dtype == np.uint16 and adc.size and int(adc.max()) > 32767:
        raise ValueError("ADC counts above 32767 do not fit the core's int16 samples: give the rig's SignalConfig")
    return np.ascontiguousarray(adc.astype(np.int16, copy=False))


def featurize(adc: np.ndarray, cfg: SignalConfig) -> Features:
    """Runs the core's per-event path (the firmware's) over every recording."""
    a16 = as_int16(adc, cfg)
    raw = _core.extract_batch(a16, cfg.core())
    ev = _core.process_batch(a16, cfg.core(), cfg.localiser())
    raw["band_xy_mm"] = ev["band_xy_mm"]     # the band picks' own position (NaN: off or not placed)
    return Features(vector=ev["vector"], phys_xy_mm=ev["phys_xy_mm"], phys_cov=ev["phys_cov"],
                    accepted=ev["accepted"].astype(bool), status=ev["status"], flags=raw["flags"],
                    toa_us=raw["toa_us"], energy=raw["energy"], raw=raw,
                    left_out=tuple(int(bool(v)) for v in cfg.channel_left_out))


def distances_mm(xy_mm: np.ndarray, cfg: SignalConfig) -> np.ndarray:
    s = cfg.sensor_xy_mm
    return np.hypot(xy_mm[:, None, 0] - s[None, :, 0], xy_mm[:, None, 1] - s[None, :, 1])


def fit_localiser(session: Session, rows: np.ndarray, cfg: SignalConfig, choose_threshold: bool = True,
                  fits=None, rig_drops: tuple[np.ndarray, np.ndarray] | None = None,
                  band_choice=None) -> SignalConfig:
    """Fits the physics localiser on training drops (travel.py): the onset threshold and AIC blend the core
    picks with, the group velocity, the per-channel delays (relative to channel 0), the dispersion of the
    picked cycles' speed with their frequency (when it explains the picks clearly better) and, on a plate
    whose material is not a known isotropic one, the travel metric of its elliptical wavefronts (with a target's
    budget `fits`, on a material the table does not know only when it explains held-out picks clearly better:
    travel.metric_choice).

    Model: ToA_ik = t0_k + |p_k - s_i|_Q / v + delay_i at the drops' nominal positions. Returns a copy of
    `cfg` with those set; the delays are rig_delay_us (the capture's, cfg.capture_delay_us, are removed
    from the picks first). choose_threshold False keeps cfg's onset threshold and AIC blend. fits: a test
    SignalConfig -> bool of the options (band picks, localiser starts) a target can afford (the board's event
    budget: board.cost.signal_fits); options it rejects are not tried. rig_drops (adc, xy_mm): the session is a
    calibrated twin's virtual drops and these the rig's calibration drops, which break the threshold's ties
    (travel.choose_threshold). band_choice: a SignalConfig -> SignalConfig choosing the band picks and finishing
    the fit (band_forests.forest_band_choice) in place of choose_band + band_finished."""
    from .travel import fit_travel, metric_choice, picks, wants_metric
    from .travel import choose_threshold as choose

    # a target's cost budget (fits): an unknown material's metric must explain held-out picks clearly better (its
    # localiser form costs more); the host, without one, fits it as the material asks (travel.wants_metric)
    aniso = metric_choice(session.rig) if fits is not None else wants_metric(session.rig)
    if choose_threshold:
        thr, blend, fit, _ = choose(session.adc[rows], session.xy_mm[rows], cfg, aniso, rig_drops)
    else:
        thr, blend = float(cfg.onset_threshold_counts), float(cfg.aic_blend)
        toa, period = picks(session.adc[rows], cfg, with_period=True)
        fit = fit_travel(toa, session.xy_mm[rows], cfg.sensor_xy_mm, aniso, period, cfg.fs_hz,
                         left_out=cfg.channel_left_out)
    out = SignalConfig.from_dict(cfg.to_dict())
    out.onset_threshold_counts = thr
    out.aic_blend = blend
    out.velocity_mm_per_us = fit.velocity_mm_per_us
    out.rig_delay_us = list(fit.delays_us)
    out.travel_metric_xx, out.travel_metric_xy, out.travel_metric_yy = fit.metric
    out.sigma_us = fit.spread_us if fit.n else cfg.sigma_us
    out.dispersion_exponent = fit.dispersion_exponent
    out.dispersion_ref_hz = fit.dispersion_ref_hz
    out = choose_starts(session, rows, out, fits)
    if band_choice is not None:
        return band_choice(out)
    return band_finished(session, rows, choose_band(session, rows, out, fits), fits)


def band_finished(session: Session, rows: np.ndarray, cfg: SignalConfig, fits=None) -> SignalConfig:
    """fit_localiser's last steps once the band picks are chosen (on or off): the band picks' localiser shares
    localiser_starts (chosen again with them on), then the posterior mean (choose_posterior)."""
    out = choose_starts(session, rows, cfg, fits) if cfg.band_velocity_mm_per_us > 0 else cfg
    return choose_posterior(session, rows, out, fits)


# More localiser starts (impactcore.h localiser_starts) are kept when they lower the training drops' physics
# MAE to this fraction of one start's: out beyond the sensors' hull the best-screened start can end in the
# wrong Huber valley.
STARTS_GAIN = 0.97
STARTS_TRIED = (1, 2, 4)


def choose_starts(session: Session, rows: np.ndarray, cfg: SignalConfig, fits=None) -> SignalConfig:
    """cfg with the localiser_starts whose physics positions of the training drops are closest to the truth
    (the configured number unless another is clearly better); fits (fit_localiser): only those it accepts
    (one start always)."""
    xy = np.asarray(session.xy_mm, float)[rows]
    score = {}
    for n in STARTS_TRIED:
        trial = SignalConfig.from_dict({**cfg.to_dict(), "localiser_starts": n})
        if fits is not None and n > 1 and not fits(trial):
            continue
        phys = featurize(session.adc[rows], trial).phys_xy_mm.astype(float)
        ok = np.isfinite(phys).all(1)
        score[n] = float(np.mean(np.abs(phys[ok] - xy[ok]))) if ok.any() else np.inf
    chosen = int(cfg.localiser_starts) if int(cfg.localiser_starts) in score else min(score)
    best = min(score, key=score.get)
    if score[best] < STARTS_GAIN * score[chosen]:
        chosen = best
    out = SignalConfig.from_dict(cfg.to_dict())
    out.localiser_starts = chosen
    return out


# The localiser's position as the posterior mean over a grid around its fit (impactcore.h posterior_grid) is
# kept when it lowers the training drops' physics MAE to this fraction of the fit's (the rule of
# localiser_starts): out beyond the sensors' hull the fit lands anywhere along a long, flat valley, the mean
# over the part of it on the plate much less so (docs/findings.md "The posterior mean").
POSTERIOR_GAIN = 0.97
POSTERIOR_GRID = 15


def physics_mae(session: Session, rows: np.ndarray, cfg: SignalConfig) -> float:
    """The training drops' physics MAE per axis (mm) under cfg; inf when no drop is placed."""
    xy = np.asarray(session.xy_mm, float)[rows]
    phys = featurize(session.adc[rows], cfg).phys_xy_mm.astype(float)
    ok = np.isfinite(phys).all(1)
    return float(np.mean(np.abs(phys[ok] - xy[ok]))) if ok.any() else np.inf


def choose_posterior(session: Session, rows: np.ndarray, cfg: SignalConfig, fits=None) -> SignalConfig:
    """cfg with posterior_grid POSTERIOR_GRID when its physics positions of the training drops are clearly
    closer to the truth (POSTERIOR_GAIN) and fits (fit_localiser) accepts it, else with the fit's (0)."""
    off = SignalConfig.from_dict({**cfg.to_dict(), "posterior_grid": 0})
    trial = SignalConfig.from_dict({**cfg.to_dict(), "posterior_grid": POSTERIOR_GRID})
    if fits is not None and not fits(trial):
        return off
    return trial if physics_mae(session, rows, trial) < POSTERIOR_GAIN * physics_mae(session, rows, off) else off


# The band picks (impactcore band_onset) are kept when the mean of their position and the threshold picks'
# brings the training drops' physics MAE to this fraction of the threshold picks' alone (the same rule as
# localiser_starts'). Their peak is sought over this many times the longest sensor-to-sensor travel time.
BAND_GAIN = 0.97
BAND_WINDOW_TRAVELS = 2.0
# The band's frequency (times the training picks' median frequency) and the fraction of its envelope's peak
# the pick takes, tried on the training drops: the pair whose band travel model explains the training band
# picks best (robust residual spread in mm, as choose_threshold scores thresholds) is the one tried against
# the threshold picks. Below the picks' median frequency and low on the envelope's rise the pick sits ahead
# of the edge reflections that reshape the envelope near its peak (docs/findings.md "Band picks: the
# fraction and the frequency").
BAND_FREQUENCY_FACTORS = (1.0, 0.7)
BAND_FRACTIONS = (0.1, 0.05, 0.03)


def band_config(session: Session, rows: np.ndarray, cfg: SignalConfig, fits=None,
                floor: float = 0.0) -> SignalConfig | None:
    """cfg with the band picks on: their frequency a multiple of the training picks' median (fs / pick_period)
    and their envelope fraction (BAND_FREQUENCY_FACTORS x BAND_FRACTIONS, the pair whose physics positions are
    closest on the training drops (physics_mae; the travel fit's own spread chose a pair whose positions were
    further off: docs/findings.md "The band pair chosen by the positions"); with fits (fit_localiser) only pairs it accepts with cfg's starts or one), their
    noise floor from the training drops' median noise rms (band_noise_counts: a noisier lab then does not move
    the picks), their travel model (velocity, delays, metric on a plate that wants one) fitted on the training
    drops; None when the picks give no frequency or too few band picks. floor > 0: band_noise_counts is this
    instead of the training drops' noise (band_floor_preset)."""
    from .travel import complete_drops, fit_travel, metric_choice, travel_distances, wants_metric

    a16 = as_int16(session.adc[rows], cfg)
    raw = _core.extract_batch(a16, cfg.core())
    period = raw["pick_period"].astype(float)
    floor = floor if floor > 0 else noise_floor(raw, cfg)
    known = np.isfinite(period) & (period > 0)
    if known.mean() < 0.5:
        return None
    median_hz = float(np.median(cfg.fs_hz / period[known]))
    sensors = cfg.sensor_xy_mm
    metric = (cfg.travel_metric_xx, cfg.travel_metric_xy, cfg.travel_metric_yy)
    longest = max(float(travel_distances(sensors[i:i + 1], sensors, metric).max()) for i in range(len(sensors)))
    xy = np.asarray(session.xy_mm, float)[rows]
    best, best_spread = None, np.inf
    for factor in BAND_FREQUENCY_FACTORS:
        for fraction in BAND_FRACTIONS:
            trial = SignalConfig.from_dict(cfg.to_dict())
            trial.band_pick_hz = factor * median_hz
            trial.band_pick_fraction = fraction
            trial.band_noise_counts = floor
            trial.band_window_us = BAND_WINDOW_TRAVELS * longest / cfg.velocity_mm_per_us
            toa = _core.extract_batch(a16, trial.core())["toa_band_us"].astype(float)
            if complete_drops(toa, cfg.channel_left_out).sum() < 8:
                continue
            fit = fit_travel(toa, xy, sensors, metric_choice(session.rig) if fits is not None else
                             wants_metric(session.rig), left_out=cfg.channel_left_out)
            trial.band_velocity_mm_per_us = fit.velocity_mm_per_us
            trial.band_delay_us = list(fit.delays_us)
            trial.band_metric_xx, trial.band_metric_xy, trial.band_metric_yy = fit.metric
            if fits is not None and not (fits(trial) or fits(SignalConfig.from_dict(
                    {**trial.to_dict(), "localiser_starts": 1}))):
                continue
            spread = physics_mae(session, rows, trial)
            if spread < best_spread:
                best, best_spread = trial, spread
    return best


def energy_slowness_config(session: Session, rows: np.ndarray, band: SignalConfig) -> SignalConfig | None:
    """band (band_config's) with the band localiser's slowness linear in the drops' summed log energy
    (travel.fit_energy_slowness on the training drops' band picks; impactcore band_slowness_per_decade), or
    None when it cannot be fitted."""
    from .travel import complete_drops, fit_energy_slowness, fit_travel, summed_log_energy, wants_metric

    raw = _core.extract_batch(as_int16(session.adc[rows], band), band.core())
    toa = raw["toa_band_us"].astype(float)
    xy = np.asarray(session.xy_mm, float)[rows]
    if complete_drops(toa, band.channel_left_out).sum() < 8:
        return None
    fit = fit_travel(toa, xy, band.sensor_xy_mm, wants_metric(session.rig), left_out=band.channel_left_out)
    line = fit_energy_slowness(toa, xy, band.sensor_xy_mm, fit, summed_log_energy(raw["energy"], band.fs_hz),
                               left_out=band.channel_left_out)
    if line is None:
        return None
    out = SignalConfig.from_dict(band.to_dict())
    out.band_velocity_mm_per_us, out.band_slowness_per_decade, out.band_log_energy_ref = line
    return out


def noise_floor(raw: dict, cfg: SignalConfig) -> float:
    """The median noise rms (counts) of extract_batch's channels in use (0 when none reads one)."""
    noise = raw["noise_rms"].astype(float)[:, np.asarray(cfg.channel_left_out) == 0]
    noise = noise[np.isfinite(noise) & (noise > 0)]
    return float(np.median(noise)) if noise.size else 0.0


def training_noise_floor(session: Session, rows: np.ndarray, cfg: SignalConfig) -> float:
    """The band picks' noise floor band_config takes from these drops (their median noise rms, counts)."""
    return noise_floor(_core.extract_batch(as_int16(session.adc[rows], cfg), cfg.core()), cfg)


def band_floor_preset(cfg: SignalConfig) -> float:
    """The band picks' noise floor (band_noise_counts) a configuration with the band picks off carries for them
    when they are chosen (loop.pick_settings sets it under a diagnosed raised white-noise floor: the reference
    drops' noise, without the change); 0: the training drops' median noise rms (band_config)."""
    return float(cfg.band_noise_counts) if float(cfg.band_pick_hz) <= 0 else 0.0


def band_off(cfg: SignalConfig) -> SignalConfig:
    """cfg with the band picks off."""
    return SignalConfig.from_dict({**cfg.to_dict(), "band_pick_hz": 0.0, "band_velocity_mm_per_us": 0.0,
                                   "band_slowness_per_decade": 0.0, "band_log_energy_ref": 0.0,
                                   "band_noise_counts": 0.0})


def choose_band(session: Session, rows: np.ndarray, cfg: SignalConfig, fits=None,
                gain: float = BAND_GAIN) -> SignalConfig:
    """cfg with the band picks when they bring the training drops' physics positions clearly closer to the
    truth (gain, BAND_GAIN; np.inf: on whenever band_config gives a pair), else cfg with them off; with the band
    picks on, their localiser's slowness follows the drops' summed log energy (energy_slowness_config) when that
    is clearly closer again (BAND_GAIN). fits (fit_localiser): the band picks only where it accepts them (with
    one localiser start if cfg's starts do not fit)."""
    off = band_off(cfg)
    trial = band_config(session, rows, off, fits, band_floor_preset(cfg))
    if trial is not None and fits is not None and not fits(trial):
        trial = SignalConfig.from_dict({**trial.to_dict(), "localiser_starts": 1})
        if not fits(trial):
            return off
    if trial is None:
        return off
    band_mae = physics_mae(session, rows, trial)
    if not (gain == np.inf or band_mae < gain * physics_mae(session, rows, off)):
        return off
    # Kept band picks only: their localiser's slowness linear in the drop's summed log energy, kept by the same
    # rule against one velocity. Tried where the band picks were off too, it turned them on where their slopes were
    # steep and the held-out physics positions worse (docs/findings.md "the speed follows the drop").
    loud = energy_slowness_config(session, rows, trial)
    if loud is not None and (fits is None or fits(loud)) and physics_mae(session, rows, loud) < BAND_GAIN * band_mae:
        return loud
    return trial
