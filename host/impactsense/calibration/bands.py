"""Band arrival times: a second timing observable for sub-problem 1.

Why: the signal core's AIC onset is the fastest part of the A0 front, the high-frequency end where Mindlin's
shear stiffness kappa G = kappa E / 2(1 + nu) slows the flexural wave; its DToA fix one combination of the
bending stiffness D ~ E / (1 - nu^2) and kappa G. The arrival of a LOW band (1-5 kHz, the Kirchhoff end of the
branch) depends on D almost alone, so the two together could separate E and nu. On this rig they do not by
enough: one 0.01 of nu at fixed D moves them by ~0.5-1 us against 2-4 us of target error (docs/findings.md);
calibration records how far they move (`plate_fem.nu_identifiability`).

The observable: the record, baseline removed, through a causal Butterworth band-pass (nothing of the band
precedes the onset), Hilbert envelope; in each channel's window from just before its own AIC onset, the first
crossing of `FRACTION` of the window's envelope maximum (linear between samples). A crossing on the rising
edge moves continuously with the plate; a peak pick jumps between packets. Times are in us with the rig's
per-channel delays removed (the core's convention), so pair differences compare with the simulator's.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.signal import butter, hilbert, sosfilt

BANDS_HZ = ((1000.0, 4000.0), (2000.0, 5000.0))
ORDER = 2               # causal Butterworth band-pass: nothing of the band precedes the onset
LEAD_US = 20.0          # each channel's window starts this long before its own AIC onset ...
WINDOW_US = 800.0       # ... and lasts this long (the low band's packet rises within it at every sensor)
FRACTION = 0.3          # the arrival: first crossing of this fraction of the window's envelope maximum


# A band's top is held to this share of the logger's Nyquist frequency: a low-rate logger (20 kHz: Nyquist 10 kHz)
# cannot hold a 5-15 kHz band, and a Butterworth edge at the Nyquist frequency is not a filter.
NYQUIST_SHARE = 0.9


@lru_cache(maxsize=16)
def band_sos(lo, hi, fs, order=ORDER):
    """A Butterworth band-pass's second-order sections over [lo, min(hi, NYQUIST_SHARE x fs / 2)] Hz, or None when
    nothing of the band lies under that top (the band's values are then NaN)."""
    top = min(float(hi), NYQUIST_SHARE * 0.5 * float(fs))
    if float(lo) >= top:
        return None
    return butter(order, [float(lo), top], btype="band", fs=float(fs), output="sos")


def band_arrivals(adc, toa_us, fs_hz, *, channel_delay_us=(0.0, 0.0, 0.0, 0.0), bands=None,
                  baseline_samples=100) -> np.ndarray:
    """Band arrival times [n, 4, len(bands)] us of records adc [n, 4, S] (raw counts).

    toa_us [n, 4]: the core's onsets (channel delays removed) of the same records, which anchor each channel's
    window; channel_delay_us: the rig's per-channel delays (a channel reading d us early has d < 0), removed
    from the result as the core removes them from its ToA. NaN where a channel has no onset."""
    bands = BANDS_HZ if bands is None else bands
    x = np.asarray(adc, float)
    x = x - np.median(x[..., :baseline_samples], axis=-1, keepdims=True)
    s = x.shape[-1]
    us = 1e6 / fs_hz
    raw = np.asarray(toa_us, float) + np.asarray(channel_delay_us, float)[None, :]      # record time [n, 4]
    t = np.arange(s) * us
    inside = (t >= (raw - LEAD_US)[..., None]) & (t <= (raw + WINDOW_US)[..., None])    # [n, 4, S]
    out = np.full(raw.shape + (len(bands),), np.nan)
    for b, (lo, hi) in enumerate(bands):
        sos = band_sos(lo, hi, float(fs_hz))
        if sos is None:   # the band lies above what the logger holds
            continue
        env = np.abs(hilbert(sosfilt(sos, x, axis=-1), axis=-1))
        env_w = np.where(inside, env, 0.0)
        thr = FRACTION * env_w.max(axis=-1)
        i = np.maximum(np.argmax(env_w >= thr[..., None], axis=-1), 1)                   # first sample >= thr
        a = np.take_along_axis(env_w, (i - 1)[..., None], -1)[..., 0]
        c = np.take_along_axis(env_w, i[..., None], -1)[..., 0]
        frac = np.clip((thr - a) / np.where(c > a, c - a, 1.0), 0.0, 1.0)
        out[..., b] = np.where(np.isfinite(raw) & (thr > 0), (i - 1 + frac) * us, np.nan) - (raw - np.asarray(toa_us, float))
    return out


def pair_differences(times, pair_i, pair_j) -> np.ndarray:
    """[n, 4, B] times -> [n, B, 6] pair differences (ToA_i - ToA_j, the core's pair order)."""
    t = np.moveaxis(np.asarray(times, float), -1, 1)
    return t[..., pair_i] - t[..., pair_j]
