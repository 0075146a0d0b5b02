"""Band group delays: a pair timing observable that moves smoothly with a drop's position (issue 4).

Why: the AIC DToA steps by one sample (10 us) and the band 30 % crossings (`bands`) step or jump between
envelope bumps when a drop moves by a fraction of a millimetre (docs/findings.md, `--position-scan`), so a
drop's position cannot be profiled out of them and nu stays hidden. A weighted mean over the whole packet has
no threshold and no argmax, so it moves continuously.

The observable, per band and channel: the record, baseline removed, through a zero-phase Butterworth
band-pass (the same filter on every channel: its delay cancels in the pair differences), Hilbert envelope e(t);
the packet time c is the fixed point of c = sum t K(t - c) e(t)^2 / sum K(t - c) e(t)^2 with K a biweight
kernel of half-width `HALF_US` (a mean shift to the nearest mode of the smoothed energy, started at the
channel's own AIC onset: the start only picks the basin, not the value, so the onset's 10 us steps do not
reach it). The group delay of pair (i, j) is c_i - c_j (the core's ToA_i - ToA_j order). The rig's
per-channel delays are removed as the core removes them from its ToA.

Tried first and dropped: the lag of the envelopes' cross-correlation maximum (parabolic vertex) in a window
common to the event: smooth in 1-4 kHz (0.6 us rms off a straight line over +-1.5 mm) but it jumps by up to
300 us in 2-5 kHz when two correlation peaks swap.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.signal import butter, hilbert, sosfiltfilt

# (low Hz, high Hz, kernel half-width us): chosen on `bench_calibrate.py --position-scan` (smooth in position)
BANDS = ((1000.0, 3000.0, 600.0), (2000.0, 5000.0, 1000.0), (3000.0, 8000.0, 300.0))
ORDER = 2
ITERATIONS = 40
TOL_US = 1e-3


@lru_cache(maxsize=8)
def _sos(lo, hi, fs):
    return butter(ORDER, [lo, hi], btype="band", fs=fs, output="sos")


def packet_times(env, start_us, half_us, us_per_sample) -> np.ndarray:
    """Mean-shift packet times [...] us of envelopes env [..., S] started at start_us [...] (finite)."""
    t = np.arange(env.shape[-1]) * us_per_sample
    e2 = env ** 2
    c = np.asarray(start_us, float).copy()
    for _ in range(ITERATIONS):
        k = np.clip(1.0 - ((t - c[..., None]) / half_us) ** 2, 0.0, None) ** 2
        w = k * e2
        tot = w.sum(-1)
        new = np.where(tot > 0, (w * t).sum(-1) / np.where(tot > 0, tot, 1.0), np.nan)
        done = np.nanmax(np.abs(new - c)) < TOL_US if np.isfinite(new).any() else True
        c = new
        if done:
            break
    return c


def group_delays(adc, toa_us, fs_hz, pair_i, pair_j, *, channel_delay_us=(0.0, 0.0, 0.0, 0.0), bands=None,
                 baseline_samples=100) -> np.ndarray:
    """Band group delays [n, B, P] us of records adc [n, 4, S] (raw counts) for the pairs (pair_i, pair_j).

    toa_us [n, 4]: the core's onsets (channel delays removed), each channel's mean-shift start. NaN where a
    channel has no onset."""
    bands = BANDS if bands is None else bands
    x = np.asarray(adc, float)
    if x.ndim != 3 or x.shape[1] != 4:
        raise ValueError(f"group_delays: adc must be [n, 4, samples], got {x.shape}")
    x = x - np.median(x[..., :baseline_samples], axis=-1, keepdims=True)
    us = 1e6 / fs_hz
    delay = np.asarray(channel_delay_us, float)
    raw = np.asarray(toa_us, float) + delay[None, :]                 # record time of each onset [n, 4]
    ok = np.isfinite(raw)
    out = np.empty((x.shape[0], len(bands), len(pair_i)))
    for b, (lo, hi, half) in enumerate(bands):
        env = np.abs(hilbert(sosfiltfilt(_sos(lo, hi, float(fs_hz)), x, axis=-1), axis=-1))
        c = np.where(ok, packet_times(env, np.where(ok, raw, 0.0), half, us), np.nan) - delay[None, :]
        out[:, b] = c[:, pair_i] - c[:, pair_j]
    return out


def names(bands=None) -> tuple:
    return tuple(f"group delay {lo / 1e3:g}-{hi / 1e3:g} kHz" for lo, hi, _ in (BANDS if bands is None else bands))
