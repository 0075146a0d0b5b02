"""Residual analysis: features of a session, a reference physics model, residuals and the loop's metrics.

The reference model (`Reference`) predicts, at a drop's declared position p_k and for channel i:
- timing:   ToA_ik = t0_k + s * |p_k - S_i| * (1 + a_c cos 2θ_ik + a_s sin 2θ_ik) + delay_i   [µs]
            (t0_k is eliminated by centring each drop's four residuals, so only DToA information is used)
- energy:   log E_ik = e_k + α d_ik + β log d_ik + g_i          (e_k eliminated the same way; g_i = 2 log gain)
- spectrum: log centroid_ik = c0 + c1 d_ik + c_i                (2 ms after the onset)
- decay:    decay_ik = λ + λ_i                                   [1/s, log-envelope slope 1..8 ms after onset,
            of the signal above the noise: hum and noise power taken out; nan when under 3 blocks are above it]
- noise:    log rms_ik = n_i ; hum amplitude (50/60 Hz lock-in over the tail) = h_i
- rails:    per-channel clipping rails lo_i, hi_i               [counts]
Each group has a residual scale σ estimated on the reference data; the effect library (`impactsense.effects`)
adds parameters to these groups, and `impactsense.diagnose` decides which additions the data supports.

Timing uses the core's picks with the rig's delays off. By default the AIC onset (CoreConfig.aic_blend = 1),
which does not slide with amplitude; `site_reference.choose_picker` picks, on the reference session, the
onset threshold and AIC blend whose reference explains held-out drops best (a threshold crossing is steadier
on a dispersive plate), with the picked cycle's dispersion taken out where the travel fit keeps it
(`dispersion_corrected`, the core localiser's model); the amplitude dependence of such picks is then the
measured timing part of a gain change (`effects.sensor_gain`, `pick_toa_us`). A picker may carry several
onset thresholds (`onset_threshold_levels`): the core picks at each and the pick is their mean, steadier
than any one level (each crossing's noise is partly its own).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.special import xlogy

from . import _core
from .data import Session
from .hum import HUM_HZ, hum_lock_in, tail_lock_in  # noqa: F401  (HUM_HZ is read from here too: effects/noise.py)
from .signal import core_config, core_samples
# the DToA pairs and the loop's before / after numbers (`loop_numbers`), importable from here as before
from .loop_numbers import PAIR_I as PAIR_I, PAIR_J as PAIR_J, localise as localise, metrics as metrics

CENTROID_S = 2e-3           # spectral-centroid window after the onset
CENTROID_LEAD_S = 5e-5      # ... starting this long before the onset
DECAY_BLOCKS_S = (1e-3, 8e-3, 1e-3)  # envelope blocks after the onset: start, stop, width
DECAY_MIN_SNR = 1.0         # a decay block counts when its power above the noise is at least this x the noise
TAIL_START_S = 25e-3        # tail used for the hum lock-in (signal decayed by e^-10) ...


def tail_start(samples: int, fs_hz: float) -> int:
    """First sample of the hum lock-in's tail: TAIL_START_S, or the record's second half when it is shorter
    than 2 x TAIL_START_S (a short capture or a fast logger: never an empty tail)."""
    return min(int(round(TAIL_START_S * fs_hz)), int(samples) // 2)
PLATEAU_SAMPLES = 4         # equal consecutive samples at the extreme that mark clipping


# The core's picker for timing residuals (overrides for signal.core_config): the AIC onset, no delay removed.
TIMING_PICKER = {"aic_blend": 1.0, "rig_delay_us": [0.0, 0.0, 0.0, 0.0]}


PICK_KEYS = ("onset_threshold_counts", "aic_blend")   # a picker's core settings; its other keys are the
# dispersion of its picks (`dispersion_corrected`) and the thresholds whose picks are averaged (LEVELS_KEY)
LEVELS_KEY = "onset_threshold_levels"


def timing_picker(picker: dict | None = None) -> dict:
    """The core overrides the timing residuals are picked with: TIMING_PICKER updated by `picker`'s core
    settings (the rig's delays stay off)."""
    own = {k: v for k, v in (picker or {}).items() if k in PICK_KEYS}
    return {**TIMING_PICKER, **own, "rig_delay_us": [0.0, 0.0, 0.0, 0.0]}


@dataclass
class Features:
    """Per-drop, per-channel observables of one session (arrays [R] or [R, 4])."""

    x_mm: np.ndarray
    y_mm: np.ndarray
    height_mm: np.ndarray
    case_id: np.ndarray
    order: np.ndarray          # drop order 0..1
    toa_us: np.ndarray         # AIC onset, no delay removed
    log_energy: np.ndarray
    clipped: np.ndarray        # bool
    log_centroid: np.ndarray
    decay_per_s: np.ndarray
    log_noise: np.ndarray
    hum_counts: np.ndarray     # [R, 4, 2] amplitude at 50 and 60 Hz
    plateau_hi: np.ndarray     # level of a clipped top plateau, or -1
    plateau_lo: np.ndarray
    sensor_xy_mm: np.ndarray   # declared [4, 2]
    plate_mm: tuple
    fs_hz: float
    adc_max: int
    # the reference's smooth site terms at these drops (`impactsense.site_reference`), None when not learned
    site_toa_us: np.ndarray | None = None
    site_log_energy: np.ndarray | None = None
    picker: dict | None = None   # the picker toa_us was picked with (`timing_picker`; None: TIMING_PICKER)
    pick_period: np.ndarray | None = None   # the picked cycle's period (samples, impactcore pick_period)
    toa_band_us: np.ndarray | None = None   # the core's band picks (`band_timing`), None when not picked

    def __len__(self):
        return len(self.x_mm)

    def subset(self, rows) -> "Features":
        rows = np.asarray(rows)
        kw = {}
        for k, v in self.__dict__.items():
            kw[k] = v[rows] if isinstance(v, np.ndarray) and v.ndim >= 1 and k != "sensor_xy_mm" else v
        return Features(**kw)


def _plateaus(a: np.ndarray, adc_max: int):
    """Level of a run of >= PLATEAU_SAMPLES equal samples at the max (min) of each channel, else -1."""
    a = np.asarray(a, dtype=np.int32)
    hi = a.max(axis=2)
    lo = a.min(axis=2)
    cnt_hi = (a == hi[..., None]).sum(axis=2)
    cnt_lo = (a == lo[..., None]).sum(axis=2)
    # consecutive: clipped runs are contiguous; a count of equal extremes is a cheap and adequate proxy
    ph = np.where(cnt_hi >= PLATEAU_SAMPLES, hi, -1)
    pl = np.where(cnt_lo >= PLATEAU_SAMPLES, lo, -1)
    return ph.astype(float), pl.astype(float)


def signal_features(adc: np.ndarray, onset_samples: np.ndarray, fs_hz: float, bias: float,
                    adc_max: int | None = None):
    """Spectral centroid, decay rate and hum amplitude: diagnostics computed on the host (not pickers).
    A record's tail that cannot read a hum the logger could hold (`hum.hum_readable`, with `adc_max`: a short
    record's tail, a small part of a mains period) gives hum 0 and only its offset is taken out of the decay's
    blocks; a decay block that runs past the record's end is left out (it would read the last sample repeated)."""
    a = adc.astype(np.float32) - bias
    r, c, n = a.shape
    on = np.clip(np.nan_to_num(onset_samples, nan=0).astype(int), 0, n - 1)
    samples = lambda s: int(round(s * fs_hz))  # noqa: E731
    # centroid of the first CENTROID_S after the onset
    m = samples(CENTROID_S)
    idx = np.clip(on[..., None] - samples(CENTROID_LEAD_S) + np.arange(m), 0, n - 1)
    seg = np.take_along_axis(a, idx, axis=2)
    seg = seg - seg.mean(axis=2, keepdims=True)
    p = np.abs(np.fft.rfft(seg * np.hanning(m), axis=2)) ** 2
    f = np.fft.rfftfreq(m, 1.0 / fs_hz)
    centroid = (p * f).sum(axis=2) / np.maximum(p.sum(axis=2), 1e-12)
    # hum: least-squares lock-in at 50 and 60 Hz over the tail (with offset and trend)
    t0 = tail_start(n, fs_hz)
    hum, coef, noise_ms = tail_lock_in(a[:, :, t0:], fs_hz, adc_max)
    # decay: slope of the log RMS envelope in blocks, of the signal alone: the tail's offset and hum (extended
    # over the record) are taken out and the tail's noise power is subtracted from each block's mean square;
    # a block that is not above the noise (power SNR < DECAY_MIN_SNR) is left out of the slope
    ta = (np.arange(n) - t0) / fs_hz
    base = coef[..., :1]   # the offset (the tail's trend is not extended back)
    for k, hz in enumerate(HUM_HZ):
        base = base + coef[..., 2 + 2 * k, None] * np.cos(2 * np.pi * hz * ta) \
            + coef[..., 3 + 2 * k, None] * np.sin(2 * np.pi * hz * ta)
    b0, b1, bw = (samples(v) for v in DECAY_BLOCKS_S)
    starts = np.arange(b0, b1, bw)
    offsets = (starts[:, None] + np.arange(bw)[None, :]).reshape(-1)
    idx = np.clip(on[..., None] + offsets, 0, n - 1)
    sig = a - base.astype(np.float32)
    blk = np.take_along_axis(sig, idx.reshape(r, c, -1), axis=2).reshape(r, c, len(starts), bw)
    power = (blk.astype(np.float64) ** 2).mean(axis=3) - noise_ms[..., None]
    use = (power > DECAY_MIN_SNR * noise_ms[..., None]) & (on[..., None] + starts + bw <= n)
    env = 0.5 * np.log(np.maximum(power, 1e-6))
    t = np.broadcast_to((starts + bw / 2) / fs_hz, env.shape)
    w = use.astype(float)
    nw = w.sum(axis=2)
    tm = (w * t).sum(axis=2) / np.maximum(nw, 1)
    tc = (t - tm[..., None]) * w
    den = (tc * (t - tm[..., None])).sum(axis=2)
    decay = np.where((nw >= 3) & (den > 0), -(tc * env).sum(axis=2) / np.maximum(den, 1e-12), np.nan)
    return np.log(np.maximum(centroid, 1.0)), decay, hum


def hum_white_gain(fs_hz: float, samples: int) -> np.ndarray:
    """E[lock-in amplitude^2] at 50 and 60 Hz per unit white-noise power (counts^2): the tail's lock-in
    (offset, trend, 50 and 60 Hz; a few cycles, so the regressors are far from orthogonal) reads white noise
    of variance v as v x this gain."""
    t0 = tail_start(samples, fs_hz)
    tt = np.arange(max(samples - t0, 8)) / fs_hz
    cols = [np.ones_like(tt), tt - tt.mean()]
    for hz in HUM_HZ:
        cols += [np.cos(2 * np.pi * hz * tt), np.sin(2 * np.pi * hz * tt)]
    X = np.stack(cols, axis=1)
    cov = np.diag(np.linalg.pinv(X.T @ X))
    return np.array([cov[2] + cov[3], cov[4] + cov[5]])


def core_picks(session: Session, picker: dict | None) -> tuple[dict, np.ndarray]:
    """The core's features by `timing_picker(picker)` and the picks (µs, [R, 4]): the core's ToA, or where the
    picker lists onset_threshold_levels the mean of the core's ToA at each level (the other features are the
    first level's; a channel without a crossing at some level keeps the mean of the levels it crossed)."""
    levels = list((picker or {}).get(LEVELS_KEY) or [])
    cfg = core_config(session.rig, **timing_picker(picker))
    samples = core_samples(session.adc, cfg)
    f = _core.extract_batch(samples, cfg)
    if len(levels) < 2:
        return f, np.asarray(f["toa_us"], float)
    toa = [np.asarray(f["toa_us"], float)]
    for level in levels[1:]:
        cfg.onset_threshold_counts = float(level)
        toa.append(np.asarray(_core.extract_batch(samples, cfg)["toa_us"], float))
    with np.errstate(invalid="ignore"):
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # no level crossed: NaN, as the core's own
            return f, np.nanmean(np.stack(toa), axis=0)


def extract(session: Session, picker: dict | None = None) -> Features:
    """Features of every drop of a session: core features (ToA by `timing_picker(picker)`, the AIC onset by
    default; `core_picks`) plus host diagnostics (their windows start at the AIC onset whatever the picker)."""
    rig = session.rig
    f, picks = core_picks(session, picker)
    toa = dispersion_corrected(picks, f["pick_period"], session.x_mm, session.y_mm, rig.sensor_xy_mm,
                               float(rig.fs_hz), picker)
    onset = np.asarray(f["toa_aic"], float)
    logc, decay, hum = signal_features(session.adc, onset, rig.fs_hz, float(rig.bias_counts), int(rig.adc_max))
    ph, pl = _plateaus(session.adc, rig.adc_max)
    n = len(session)
    return Features(
        x_mm=np.asarray(session.x_mm, float), y_mm=np.asarray(session.y_mm, float),
        height_mm=np.asarray(session.height_mm, float), case_id=np.asarray(session.case_id),
        order=np.arange(n) / max(n - 1, 1), toa_us=toa,
        log_energy=np.log(np.maximum(np.asarray(f["energy"], float), 1.0)),
        clipped=(np.asarray(f["flags"]) & _core.FLAG_CLIPPED) > 0,
        log_centroid=logc, decay_per_s=decay,
        log_noise=np.log(np.maximum(np.asarray(f["noise_rms"], float), 1e-3)),
        hum_counts=hum, plateau_hi=ph, plateau_lo=pl,
        sensor_xy_mm=rig.sensor_xy_mm.astype(float), plate_mm=(rig.plate_x_mm, rig.plate_y_mm),
        fs_hz=float(rig.fs_hz), adc_max=int(rig.adc_max), picker=dict(picker) if picker else None,
        pick_period=np.asarray(f["pick_period"], float))


def dispersion_corrected(toa_us, period_samples, x_mm, y_mm, sensor_xy_mm, fs_hz: float, picker: dict | None):
    """The picks with their cycle's dispersion taken out: on a dispersive plate the cycle a pick catches travels
    at its own frequency's speed, so its travel time over the declared distance d is s d (f / f_ref)^-alpha
    (f = fs / the cycle's period: `travel.slowness_scales`, the core localiser's model); the pick less
    s d ((f / f_ref)^-alpha - 1) is the one-speed pick the reference models. Unchanged when the picker carries
    no dispersion (dispersion_exponent, dispersion_ref_hz, dispersion_slowness_us_per_mm)."""
    toa = np.asarray(toa_us, float)
    alpha = float((picker or {}).get("dispersion_exponent", 0.0))
    if alpha == 0.0:
        return toa
    from .travel import slowness_scales
    sxy = np.asarray(sensor_xy_mm, float)
    d = np.hypot(np.asarray(x_mm, float)[:, None] - sxy[None, :, 0], np.asarray(y_mm, float)[:, None] - sxy[None, :, 1])
    scale = slowness_scales(period_samples, fs_hz, alpha, float(picker["dispersion_ref_hz"]))
    return toa - float(picker["dispersion_slowness_us_per_mm"]) * d * (scale - 1.0)


def repick(session: Session, F: Features, picker: dict | None) -> Features:
    """F (features of `session`) with its ToA picked again by `timing_picker(picker)` (`core_picks`)."""
    f, picks = core_picks(session, picker)
    period = np.asarray(f["pick_period"], float)
    toa = dispersion_corrected(picks, period, F.x_mm, F.y_mm, F.sensor_xy_mm, F.fs_hz, picker)
    return replace(F, toa_us=toa, picker=dict(picker) if picker else None, pick_period=period)


# ----------------------------------------------------------------------------------------------------
def centre(r: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Subtracts each drop's mean over its (masked-in) channels: eliminates t0_k or e_k."""
    if mask is None:
        return r - r.mean(axis=1, keepdims=True)
    m = mask.astype(float)
    mean = (np.nan_to_num(r) * m).sum(axis=1, keepdims=True) / np.maximum(m.sum(axis=1, keepdims=True), 1)
    return np.where(mask, r - mean, 0.0)


def huber_ll(z: np.ndarray, k: float = 2.5) -> np.ndarray:
    """Log-likelihood (up to a constant) of standardised residuals under a Huber density."""
    a = np.abs(z)
    return -np.where(a <= k, 0.5 * a ** 2, k * a - 0.5 * k ** 2)


@dataclass
class Reference:
    """The reference model of the rig; every field has its unit in the name or the module docstring."""

    sensor_xy_mm: np.ndarray
    slowness_us_per_mm: float
    delay_us: np.ndarray = field(default_factory=lambda: np.zeros(4))
    aniso: np.ndarray = field(default_factory=lambda: np.zeros(2))
    alpha: float = 0.0
    beta: float = 0.0
    # what a raised noise floor does to the core's picks and energies, per channel: ToA later by
    # noise_toa_us + noise_toa_us_per_mm x distance, log-energy by noise_log_energy_per_mm x distance
    # (measured on the reference's own recordings with the noise put in: `effects.noise`)
    noise_toa_us: np.ndarray = field(default_factory=lambda: np.zeros(4))
    noise_toa_us_per_mm: np.ndarray = field(default_factory=lambda: np.zeros(4))
    noise_log_energy_per_mm: np.ndarray = field(default_factory=lambda: np.zeros(4))
    # what a changed signal does to the picks (a threshold crossing comes later on a weaker or low-passed
    # channel), per channel: ToA later by pick_toa_us + pick_toa_us_per_mm x distance (measured:
    # `effects.sensor_gain`, `effects.channel_lowpass`)
    pick_toa_us: np.ndarray = field(default_factory=lambda: np.zeros(4))
    pick_toa_us_per_mm: np.ndarray = field(default_factory=lambda: np.zeros(4))
    gain_log: np.ndarray = field(default_factory=lambda: np.zeros(4))   # log energy offsets
    c0: float = 8.0
    c1: float = 0.0
    cent_off: np.ndarray = field(default_factory=lambda: np.zeros(4))
    decay0_per_s: float = 400.0
    decay_off: np.ndarray = field(default_factory=lambda: np.zeros(4))
    log_noise: np.ndarray = field(default_factory=lambda: np.zeros(4))
    hum2: np.ndarray = field(default_factory=lambda: np.zeros((4, 2)))  # mean squared lock-in amplitude
    rail_lo: np.ndarray = field(default_factory=lambda: np.zeros(4))
    rail_hi: np.ndarray = field(default_factory=lambda: np.full(4, 4095.0))
    plateau_rate: float = 0.0   # rate of non-rail plateaus per drop-channel on the reference
    # where the energy model puts the discs when it differs from the timing's (`effects.sensor_position`
    # moves a disc for the timing only); None: sensor_xy_mm
    energy_sensor_xy_mm: np.ndarray | None = None
    sigma: dict = field(default_factory=dict)
    mode: str = "calibrated"
    probe: object = field(default=None, repr=False)   # a few reference recordings (forward models)
    # the site terms learned on the reference (`site_reference.SiteTerms`), None when not learned: their
    # posterior covariance is the reference's own uncertainty (`effects.sensor_position.direction_test`)
    site: object = field(default=None, repr=False)
    band: dict | None = None   # the band picks' travel law learned on the reference (`band_timing.fit_band`)
    # per position group, the intra-case correlation of the reference's cross-fitted residuals
    # (`case_correlation.reference_icc`); None: drops independent (the evidence rule's plain Markov half)
    case_icc: dict | None = None
    timing_out: tuple = ()   # channels whose timing is left out (diagnose's flagged one): ToA residual 0

    def copy(self) -> "Reference":
        return replace(self, **{k: (v.copy() if isinstance(v, (np.ndarray, dict)) else v)
                                for k, v in self.__dict__.items()})

    @property
    def velocity_m_s(self) -> float:
        return 1000.0 / self.slowness_us_per_mm

    # --- predictions ---
    def geometry(self, F: Features, sensor_xy=None):
        sxy = self.sensor_xy_mm if sensor_xy is None else sensor_xy
        dx = F.x_mm[:, None] - sxy[None, :, 0]
        dy = F.y_mm[:, None] - sxy[None, :, 1]
        d = np.hypot(dx, dy)
        th = np.arctan2(dy, dx)
        return d, th, dx / np.maximum(d, 1e-6), dy / np.maximum(d, 1e-6)

    def toa_pred(self, F: Features) -> np.ndarray:
        d, th, _, _ = self.geometry(F)
        site = 0.0 if F.site_toa_us is None else F.site_toa_us
        return self.slowness_us_per_mm * d * (1 + self.aniso[0] * np.cos(2 * th)
                                              + self.aniso[1] * np.sin(2 * th)) + self.delay_us + site \
            + self.noise_toa_us + self.noise_toa_us_per_mm * d + self.pick_toa_us + self.pick_toa_us_per_mm * d

    def timing_kept(self, n: int) -> np.ndarray | None:
        """[n, 4] True on the channels whose timing counts; None when every channel's does."""
        return np.broadcast_to(~np.isin(np.arange(4), self.timing_out), (n, 4)) if self.timing_out else None

    def centre_timing(self, x: np.ndarray) -> np.ndarray:   # `centre` over the channels whose timing counts
        return centre(x, self.timing_kept(len(x)))

    def toa_resid(self, F: Features) -> np.ndarray:
        return self.centre_timing(F.toa_us - self.toa_pred(F))

    def clip_mask(self, F: Features) -> np.ndarray:
        """Channels clipped at the ADC rails (core flag) or at this model's own rails."""
        at_hi = (F.plateau_hi >= 0) & (np.abs(F.plateau_hi - self.rail_hi) <= 1)
        at_lo = (F.plateau_lo >= 0) & (np.abs(F.plateau_lo - self.rail_lo) <= 1)
        return F.clipped | at_hi | at_lo

    def nonrail_plateaus(self, F: Features) -> np.ndarray:
        hi = (F.plateau_hi >= 0) & (np.abs(F.plateau_hi - self.rail_hi) > 1)
        lo = (F.plateau_lo >= 0) & (np.abs(F.plateau_lo - self.rail_lo) > 1)
        return hi | lo

    def energy_resid(self, F: Features) -> np.ndarray:
        d, *_ = self.geometry(F, self.energy_sensor_xy_mm)
        pred = self.alpha * d + self.beta * np.log(d) + self.gain_log + self.noise_log_energy_per_mm * d
        if F.site_log_energy is not None:
            pred = pred + F.site_log_energy
        return centre(F.log_energy - pred, ~self.clip_mask(F))

    def cent_resid(self, F: Features) -> np.ndarray:
        d, *_ = self.geometry(F)
        return F.log_centroid - (self.c0 + self.c1 * d + self.cent_off)

    def decay_resid(self, F: Features) -> np.ndarray:
        return F.decay_per_s - (self.decay0_per_s + self.decay_off)

    # --- log-likelihood per drop and group (constants dropped; same σ for every candidate) ---
    def ll_groups(self, F: Features) -> dict[str, np.ndarray]:
        s = self.sigma
        out = {
            "timing": huber_ll(self.toa_resid(F) / s["timing"]).sum(axis=1),
            "energy": (huber_ll(self.energy_resid(F) / s["energy"]) * ~self.clip_mask(F)).sum(axis=1),
            "spectrum": huber_ll(self.cent_resid(F) / s["spectrum"]).sum(axis=1),
            "decay": np.nan_to_num(huber_ll(self.decay_resid(F) / s["decay"])).sum(axis=1),   # nan: no decay
            "noise": huber_ll((F.log_noise - self.log_noise) / s["noise"]).sum(axis=1),
        }
        hum_pred = np.sqrt(self.hum2)[None]
        out["hum"] = huber_ll((F.hum_counts - hum_pred) / s["hum"]).sum(axis=(1, 2))
        ev = self.nonrail_plateaus(F)
        p0 = self.plateau_rate
        out["clipping"] = (xlogy(ev, p0) + xlogy(~ev, 1.0 - p0)).sum(axis=1)   # 0 log 0 = 0 (a rate of 0 or 1)
        return out

    def ll(self, F: Features) -> np.ndarray:
        return sum(self.ll_groups(F).values())


def _robust_lstsq(X, b, iters=5):
    w = np.ones(len(b))
    sol = np.zeros(X.shape[1])
    for _ in range(iters):
        sol = np.linalg.lstsq(X * w[:, None], b * w, rcond=None)[0]
        r = b - X @ sol
        mad = 1.4826 * np.median(np.abs(r)) + 1e-9
        w = np.sqrt(1.0 / np.maximum(1.0, np.abs(r) / (2.5 * mad)))
    return sol, b - X @ sol


def robust_sigma(r: np.ndarray) -> float:
    r = np.asarray(r)[np.isfinite(r)]
    return float(1.4826 * np.median(np.abs(r - np.median(r))) + 1e-6)


def fit_reference(F: Features, mode: str = "calibrated") -> Reference:
    """Fits the reference model on a session.

    mode "nominal": the first physics model — declared sensor positions, one group velocity, no channel
    delays, equal gains, one spectrum/decay/noise law for every channel (what the rig declares).
    mode "calibrated": the same plus per-channel delays, gains, spectral and decay offsets, noise floors.
    """
    ref = Reference(sensor_xy_mm=F.sensor_xy_mm.copy(), slowness_us_per_mm=1.0, mode=mode)
    d, *_ = ref.geometry(F)
    n = len(F)
    per_ch = mode == "calibrated"
    ok = np.all(np.isfinite(F.toa_us), axis=1)
    # timing: centred ToA = s * centred d + delays (relative to the mean of channels)
    cols = [centre(d[ok]).ravel()]
    if per_ch:
        for i in range(1, 4):
            e = np.zeros((ok.sum(), 4))
            e[:, i] = 1
            cols.append(centre(e).ravel())
    sol, res = _robust_lstsq(np.stack(cols, 1), centre(F.toa_us[ok]).ravel())
    ref.slowness_us_per_mm = float(sol[0])
    if per_ch:
        ref.delay_us = np.r_[0.0, sol[1:4]]
    ref.sigma["timing"] = robust_sigma(res)
    # energy (unclipped channels)
    m = ~F.clipped
    cols = [centre(d, m)[m], centre(np.log(d), m)[m]]
    if per_ch:
        for i in range(1, 4):
            e = np.zeros((n, 4))
            e[:, i] = 1
            cols.append(centre(e, m)[m])
    sol, res = _robust_lstsq(np.stack(cols, 1), centre(F.log_energy, m)[m])
    ref.alpha, ref.beta = float(sol[0]), float(sol[1])
    if per_ch:
        ref.gain_log = np.r_[0.0, sol[2:5]]
    ref.sigma["energy"] = robust_sigma(res)
    # spectrum
    cols = [np.ones(n * 4), d.ravel()]
    if per_ch:
        for i in range(1, 4):
            e = np.zeros((n, 4))
            e[:, i] = 1
            cols.append(e.ravel())
    sol, res = _robust_lstsq(np.stack(cols, 1), F.log_centroid.ravel())
    ref.c0, ref.c1 = float(sol[0]), float(sol[1])
    if per_ch:
        ref.cent_off = np.r_[0.0, sol[2:5]]
    ref.sigma["spectrum"] = robust_sigma(res)
    # decay, noise, hum
    with warnings.catch_warnings():   # a record too short for the decay's blocks: NaN, no decay term
        warnings.simplefilter("ignore", RuntimeWarning)
        if per_ch:
            ref.decay_off = np.nanmedian(F.decay_per_s, axis=0) - np.nanmedian(F.decay_per_s)
        ref.decay0_per_s = float(np.nanmedian(F.decay_per_s))
        ref.sigma["decay"] = robust_sigma(F.decay_per_s - ref.decay0_per_s - ref.decay_off)
    ref.log_noise = (np.median(F.log_noise, axis=0) if per_ch
                     else np.full(4, np.median(F.log_noise)))
    ref.sigma["noise"] = robust_sigma(F.log_noise - ref.log_noise)
    ref.hum2 = (F.hum_counts ** 2).mean(axis=0) if per_ch else \
        np.broadcast_to((F.hum_counts ** 2).mean(axis=(0, 1)), (4, 2)).copy()
    ref.sigma["hum"] = max(float(F.hum_counts.std()), 0.05)
    ref.rail_lo = np.zeros(4)
    ref.rail_hi = np.full(4, float(F.adc_max))
    nonrail = ref.nonrail_plateaus(F)
    ref.plateau_rate = float((nonrail.sum() + 1) / (nonrail.size + 2))
    return ref


