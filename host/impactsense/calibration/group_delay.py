"""Band group delays: a pair timing observable that moves smoothly with a drop's position (issue 4).

Why: the AIC DToA steps by one sample (10 us) and the band 30 % crossings (`bands`) step or jump between
envelope bumps when a drop moves by a fraction of a millimetre (docs/findings.md, `--position-scan`), so a
drop's position cannot be profiled out of them and nu stays hidden. A weighted mean over the whole packet has
no threshold and no argmax, so it moves continuously.

The observable, per band and channel: the record, baseline removed, through a zero-phase Butterworth
band-pass (the same filter on every channel: its delay cancels in the pair differences), Hilbert envelope e(t);
the packet time c = sum t W(t) e(t)^2 / sum W(t) e(t)^2, with one window W common to the event's four channels:
a cosine rise over `RISE_US` to `LEAD_US` before the anchor, flat to `FLAT_US` after it, a cosine fall over
`TAPER_US`. No threshold, no argmax, no mode picking: c is a smooth function of the record and of the anchor.
The anchor must then be smooth and quiet itself (a 10 us shift of it moves c by 1-5 us): not the mean of the
four AIC onsets (10 us steps, ~4 us of noise), but one step from it: the energy centroid of the four channels'
summed 1-15 kHz energy in the window `ANCHOR_FLAT_US` long from the mean onset, less `ANCHOR_OFFSET_US` (a
constant: the centroid sits ~0.85 ms after the onsets). It moves by ~0.2 us per us of the mean onset. The group delay of pair (i, j) is c_i - c_j (the
core's ToA_i - ToA_j order). The rig's per-channel delays are removed as the core removes them from its ToA.

Tried first and dropped (`--position-scan`, FEM drops made with 1 mm jitter):
- the lag of the envelopes' cross-correlation maximum: smooth in the lowest band, but it jumps by hundreds of
  us in others when two correlation peaks swap;
- a mean shift to the nearest mode of the kernel-smoothed energy: smooth along the scan, but between
  repetitions 1 mm apart it lands in different modes (docs/findings.md, "Numbers from the code's docstrings").
"""

from __future__ import annotations

import numpy as np
from scipy.signal import hilbert, sosfiltfilt

from .bands import band_sos

# (low Hz, high Hz, flat part of the window after the mean onset, us): chosen on `bench_calibrate.py
# --position-scan` (smooth in position) and on their nu sensitivity against noise
BANDS = ((1000.0, 3000.0, 1000.0), (2000.0, 5000.0, 500.0), (5000.0, 15000.0, 500.0))
ORDER = 2
RISE_US = 300.0
LEAD_US = 300.0
TAPER_US = 1000.0
ANCHOR_BAND_HZ = (1000.0, 15000.0)
ANCHOR_FLAT_US = 2500.0
ANCHOR_OFFSET_US = 850.0


def window(t_us, anchor_us, flat_us) -> np.ndarray:
    """[n, S] weights: cosine rise over RISE up to anchor - LEAD, 1 until anchor + flat, cosine fall over TAPER."""
    rel = t_us[None, :] - np.asarray(anchor_us, float)[:, None]
    rise = 0.5 * (1 - np.cos(np.pi * np.clip((rel + LEAD_US + RISE_US) / RISE_US, 0.0, 1.0)))
    fall = 0.5 * (1 + np.cos(np.pi * np.clip((rel - flat_us) / TAPER_US, 0.0, 1.0)))
    return rise * fall


def packet_times(env, anchor_us, flat_us, us_per_sample) -> np.ndarray:
    """Energy centroids [n, C] us of envelopes env [n, C, S] in each event's window (anchor_us [n])."""
    t = np.arange(env.shape[-1]) * us_per_sample
    w = window(t, anchor_us, flat_us)[:, None, :] * env ** 2
    tot = w.sum(-1)
    return np.where(tot > 0, (w * t).sum(-1) / np.where(tot > 0, tot, 1.0), np.nan)


def event_anchor(x, mean_onset_us, fs_hz) -> np.ndarray:
    """Each event's window anchor [n] us (record time) from baseline-removed records x [n, 4, S]."""
    e2 = (np.abs(hilbert(sosfiltfilt(band_sos(*ANCHOR_BAND_HZ, float(fs_hz), ORDER), x, axis=-1), axis=-1))
          ** 2).sum(1)
    c = packet_times(e2[:, None, :] ** 0.5, mean_onset_us, ANCHOR_FLAT_US, 1e6 / fs_hz)[:, 0]
    return np.where(np.isfinite(c), c - ANCHOR_OFFSET_US, mean_onset_us)


def group_delays(adc, toa_us, fs_hz, pair_i, pair_j, *, channel_delay_us=(0.0, 0.0, 0.0, 0.0), bands=None,
                 baseline_samples=100) -> np.ndarray:
    """Band group delays [n, B, P] us of records adc [n, 4, S] (raw counts) for the pairs (pair_i, pair_j).

    toa_us [n, 4]: the core's onsets (channel delays removed); their mean (over the finite ones) starts the
    event's anchor (`event_anchor`). NaN for an event with no onset."""
    bands = BANDS if bands is None else bands
    x = np.asarray(adc, float)
    if x.ndim != 3 or x.shape[1] != 4:
        raise ValueError(f"group_delays: adc must be [n, 4, samples], got {x.shape}")
    x = x - np.median(x[..., :baseline_samples], axis=-1, keepdims=True)
    us = 1e6 / fs_hz
    delay = np.asarray(channel_delay_us, float)
    raw = np.asarray(toa_us, float) + delay[None, :]                 # record time of each onset [n, 4]
    ok = np.isfinite(raw)
    has = ok.any(axis=1)
    anchor = event_anchor(x, np.array([r[f].mean() if f.any() else 0.0 for r, f in zip(raw, ok)]), fs_hz)
    out = np.empty((x.shape[0], len(bands), len(pair_i)))
    for b, (lo, hi, flat) in enumerate(bands):
        sos = band_sos(lo, hi, float(fs_hz), ORDER)   # the band's top held under the logger's Nyquist frequency
        if sos is None:
            out[:, b] = np.nan
            continue
        env = np.abs(hilbert(sosfiltfilt(sos, x, axis=-1), axis=-1))
        c = np.where(has[:, None], packet_times(env, anchor, flat, us), np.nan) - delay[None, :]
        out[:, b] = c[:, pair_i] - c[:, pair_j]
    return out


def names(bands=None) -> tuple:
    return tuple(f"group delay {lo / 1e3:g}-{hi / 1e3:g} kHz" for lo, hi, _ in (BANDS if bands is None else bands))
