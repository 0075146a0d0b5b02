"""The effect interface and the helpers the effects share.

An effect is a parameterised addition to the reference model (`impactsense.residuals.Reference`):
- `fit(ref, F, sensor)` estimates its parameters from features only (never from any injected truth);
- `add(ref, sensor, params)` returns the reference with the effect added (the model the loop keeps);
- `apply_signal(adc, sensor, params, ctx, rng)` puts the effect into raw recordings (uint16 [R, 4, S]):
  used to inject effects in tests and by the simulator path;
- `core_overrides(values, sensor, params)` feeds the signal core's settings where the effect is a picker correction;
- `material(params)` says whether the size is worth acting on (the rig tolerance stated per effect).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from ..residuals import Features, Reference, _robust_lstsq


class Effect(ABC):
    name = ""
    per_sensor = True
    units: dict = {}
    meaning = ""
    nests: str | None = None   # a simpler effect this one contains (same sensor): must beat it, not just none

    def candidates(self):
        return [0, 1, 2, 3] if self.per_sensor else [None]

    @abstractmethod
    def fit(self, ref: Reference, F: Features, sensor):
        """Every effect implements this (see the module docstring)."""

    @abstractmethod
    def add(self, ref: Reference, sensor, params) -> Reference:
        """Every effect implements this (see the module docstring)."""

    @abstractmethod
    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        """Every effect implements this (see the module docstring)."""

    def core_overrides(self, values: dict, sensor, params) -> dict:
        """The core's settings (signal.settings) with this effect's picker correction; most have none."""
        return values

    def material(self, params) -> bool:
        return True

    def resolution(self, params) -> dict:
        """Per parameter fitted on a grid, the grid's step at params (same units): the finest difference the fit
        can tell. A delete-a-fold interval narrower than it says nothing of the data (every fold on one node
        gives a zero width); `diagnose._param_ci` keeps each half-width at least this. Most fits are continuous."""
        return {}

    def bounds(self, params) -> dict:
        """Per parameter with a physical domain its fit clamps to, (low, high) (same units; an amplitude is never
        below zero). `diagnose._param_ci` keeps each interval inside it: value +- t x se of an amplitude near
        zero reaches below zero, which no session can have. Most parameters have none."""
        return {}

    def describe(self, sensor, params) -> str:
        where = f" on S{sensor + 1} (ch{sensor})" if sensor is not None else ""
        vals = ", ".join(f"{k}={v:.4g}" for k, v in params.items() if isinstance(v, (int, float)))
        return f"{self.name}{where}: {vals}"


def channel_columns(n: int, sensor: int) -> np.ndarray:
    e = np.zeros((n, 4))
    e[:, sensor] = 1.0
    return e


def fit_timing(ref: Reference, F: Features, cols: list[np.ndarray]) -> np.ndarray:
    """Robust LS of the centred ToA residual on centred columns ([R, 4] each): returns coefficients."""
    r = ref.toa_resid(F)
    ok = np.all(np.isfinite(r), axis=1)
    X = np.stack([ref.centre_timing(c[ok]).ravel() for c in cols], axis=1)
    sol, _ = _robust_lstsq(X, r[ok].ravel())
    return sol


# ---- signal helpers -------------------------------------------------------------------------------
def to_float(adc, bias):
    return adc.astype(np.float64) - bias


def to_adc(a, bias, adc_max):
    return np.clip(np.rint(a + bias), 0, adc_max).astype(np.uint16)


def frac_shift(x: np.ndarray, shift_samples: np.ndarray) -> np.ndarray:
    """Delays each row of x by shift_samples (may be fractional, per row) with an FFT phase ramp."""
    n = x.shape[-1]
    pad = 256
    xp = np.concatenate([x, np.repeat(x[..., -1:], pad, axis=-1)], axis=-1)
    m = xp.shape[-1]
    f = np.fft.rfftfreq(m)
    X = np.fft.rfft(xp, axis=-1)
    X *= np.exp(-2j * np.pi * f * np.asarray(shift_samples)[..., None])
    return np.fft.irfft(X, m, axis=-1)[..., :n]


def shift_channels(adc, shifts_us, ctx):
    """shifts_us [R, 4]: delay of each channel of each recording (µs)."""
    a = to_float(adc, ctx["bias"])
    s = np.asarray(shifts_us) * ctx["fs_hz"] * 1e-6
    out = frac_shift(a.reshape(-1, a.shape[-1]), s.reshape(-1)).reshape(a.shape)
    return to_adc(out, ctx["bias"], ctx["adc_max"])


def geometry(ctx, sensor_xy=None):
    sxy = np.asarray(ctx["sensor_xy_mm"] if sensor_xy is None else sensor_xy, float)
    dx = ctx["x_mm"][:, None] - sxy[None, :, 0]
    dy = ctx["y_mm"][:, None] - sxy[None, :, 1]
    return np.hypot(dx, dy), np.arctan2(dy, dx)


def context(session, slowness_us_per_mm: float = 1.0 / 0.98):
    """What apply_signal needs to know about a session (declared geometry, ADC, an assumed velocity)."""
    rig = session.rig
    return {"x_mm": np.asarray(session.x_mm, float), "y_mm": np.asarray(session.y_mm, float),
            "sensor_xy_mm": rig.sensor_xy_mm.astype(float), "fs_hz": float(rig.fs_hz),
            "bias": float(rig.bias_counts), "adc_max": int(rig.adc_max),
            "slowness_us_per_mm": float(slowness_us_per_mm)}
