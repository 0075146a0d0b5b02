"""recording -> signal core -> features: the host side of the one path through the data.

Every number here comes from the C++ core (`impactsense._core`, compiled from firmware/lib/impactcore);
this module fits the physics localiser's two constants (group velocity and
per-channel delays) on training drops, and arranges the core's outputs as arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from . import _core
from .data import Session
from .signal import SignalConfig

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

    def __len__(self) -> int:
        return int(self.vector.shape[0])

    def take(self, rows: np.ndarray) -> "Features":
        rows = np.asarray(rows)
        return Features(self.vector[rows], self.phys_xy_mm[rows], self.phys_cov[rows], self.accepted[rows],
                        self.status[rows], self.flags[rows], self.toa_us[rows], self.energy[rows],
                        {k: v[rows] for k, v in self.raw.items()})

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
        """Rows the core processed with an onset on every channel and a finite feature vector."""
        return (self.status == _core.STATUS_OK) & ~self.no_onset.any(1) & np.isfinite(self.vector).all(1)


def as_int16(adc: np.ndarray) -> np.ndarray:
    """uint16 ADC counts (<= 4095 for 12 bits) as the core's int16, C-contiguous."""
    adc = np.asarray(adc)
    if adc.ndim == 2:
        adc = adc[None]
    if adc.dtype == np.uint16 and adc.size and int(adc.max()) > 32767:
        raise ValueError("ADC counts above 32767 do not fit the core's int16 samples")
    return np.ascontiguousarray(adc.astype(np.int16, copy=False))


def featurize(adc: np.ndarray, cfg: SignalConfig) -> Features:
    """Runs the core's per-event path (the firmware's) over every recording."""
    a16 = as_int16(adc)
    raw = _core.extract_batch(a16, cfg.core())
    ev = _core.process_batch(a16, cfg.core(), cfg.localiser())
    return Features(vector=ev["vector"], phys_xy_mm=ev["phys_xy_mm"], phys_cov=ev["phys_cov"],
                    accepted=ev["accepted"].astype(bool), status=ev["status"], flags=raw["flags"],
                    toa_us=raw["toa_us"], energy=raw["energy"], raw=raw)


def distances_mm(xy_mm: np.ndarray, cfg: SignalConfig) -> np.ndarray:
    s = cfg.sensor_xy_mm
    return np.hypot(xy_mm[:, None, 0] - s[None, :, 0], xy_mm[:, None, 1] - s[None, :, 1])


def fit_localiser(session: Session, rows: np.ndarray, cfg: SignalConfig) -> SignalConfig:
    """Fits the group velocity and per-channel delays (relative to channel 0) on training drops.

    Model: ToA_ik = t0_k + d_ik / v + delay_i at the drops' nominal positions; t0_k is eliminated by
    centring each drop's residuals; a soft-L1 loss keeps cycle-skipped picks from steering the fit.
    Returns a copy of `cfg` with velocity and rig_delay_us set (the capture's delays, cfg.capture_delay_us,
    are removed from the picks first).
    """
    base = SignalConfig.from_dict(cfg.to_dict())
    base.rig_delay_us = [0.0, 0.0, 0.0, 0.0]
    raw = _core.extract_batch(as_int16(session.adc[rows]), base.core())
    toa = raw["toa_us"].astype(float)
    ok = np.isfinite(toa).all(1)
    if ok.sum() < 8:
        raise ValueError(f"only {int(ok.sum())} training drops have an onset on every channel")
    d = distances_mm(session.xy_mm[rows], cfg)[ok]
    toa = toa[ok]

    def residuals(p):
        r = toa - d / p[0] - np.r_[0.0, p[1:]][None]
        return (r - r.mean(1, keepdims=True)).ravel()

    sol = least_squares(residuals, [cfg.velocity_mm_per_us, 0.0, 0.0, 0.0], loss="soft_l1", f_scale=3.0)
    out = SignalConfig.from_dict(cfg.to_dict())
    out.velocity_mm_per_us = float(sol.x[0])
    out.rig_delay_us = [0.0] + [float(v) for v in sol.x[1:]]
    r = residuals(sol.x)
    out.sigma_us = float(np.sqrt(np.median(r ** 2)) * 1.4826) if r.size else cfg.sigma_us
    return out
