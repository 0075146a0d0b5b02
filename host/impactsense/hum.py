"""The mains hum of a quiet segment: a least-squares lock-in at 50 and 60 Hz (diagnose's residuals, `info`)."""

from __future__ import annotations

import numpy as np

HUM_HZ = (50.0, 60.0)
FLOOR_SIGMAS = 2.0   # white noise alone reads over this at either frequency in ~1/4 of fits: its median, never


def _design(m: int, fs_hz: float, index: np.ndarray | None = None) -> np.ndarray:
    """The lock-in's columns over m samples (or at the record's sample numbers `index`, e.g. a quiet start and a
    quiet tail together: the hum is one sinusoid across the record): offset, trend, cos and sin at each of
    HUM_HZ."""
    tt = (np.arange(m) if index is None else np.asarray(index, float)) / fs_hz
    cols = [np.ones_like(tt), tt - tt.mean()]
    for hz in HUM_HZ:
        cols += [np.cos(2 * np.pi * hz * tt), np.sin(2 * np.pi * hz * tt)]
    return np.stack(cols, axis=1)


def hum_floor(m: int, fs_hz: float, residual_ms: np.ndarray, index: np.ndarray | None = None) -> np.ndarray:
    """The hum amplitude a median over drops of a lock-in over m samples stays under for white noise alone:
    FLOOR_SIGMAS standard errors of one hum quadrature (the worse of HUM_HZ), from the fits' residual mean
    square [...]. A segment of about a mains period hardly tells 50 from 60 Hz, offset and trend apart: its
    standard error grows (20 ms at 24 counts rms: ~7 counts), and an amplitude under this floor is not hum."""
    X = _design(m, fs_hz, index)
    cov = np.linalg.inv(X.T @ X)
    q = max(float(cov[2 + 2 * k, 2 + 2 * k] + cov[3 + 2 * k, 3 + 2 * k]) / 2 for k in range(len(HUM_HZ)))
    return FLOOR_SIGMAS * np.sqrt(np.asarray(residual_ms, float) * q)


def hum_lock_in(seg: np.ndarray, fs_hz: float, index: np.ndarray | None = None,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares lock-in at HUM_HZ over a quiet segment [R, C, S] (counts less the bias), with offset and
    trend: (amplitude [R, C, len(HUM_HZ)], the fit's coefficients [R, C, 2 + 2 len(HUM_HZ)], what is left of the
    segment's mean square [R, C]). index: the segment's sample numbers in the record (default 0..S-1)."""
    r, c, m = seg.shape
    X = _design(m, fs_hz, index)
    flat = seg.reshape(-1, m).T
    coef_flat, *_ = np.linalg.lstsq(X, flat, rcond=None)
    coef = coef_flat.T.reshape(r, c, -1)
    hum = np.stack([np.hypot(coef[..., 2 + 2 * k], coef[..., 3 + 2 * k]) for k in range(len(HUM_HZ))], axis=2)
    return hum, coef, ((flat - X @ coef_flat) ** 2).mean(axis=0).reshape(r, c)


def hum_readable(hum, floor, adc_max: int) -> np.ndarray:
    """Per record or channel: whether the segment the hum was read over can tell a hum the logger could record from the
    record's offset, trend and ringing. A hum over the ADC's half range would clip every record, so a reading or
    a noise floor (hum.hum_floor) at or above it is the lock-in's ill-conditioning over a small part of a mains
    period (a short record's tail), not a hum: not reported."""
    half = adc_max / 2.0
    return (np.asarray(hum, float) < half) & (np.asarray(floor, float) < half)


def tail_lock_in(seg: np.ndarray, fs_hz: float, adc_max: int | None = None):
    """`hum_lock_in` over a record's tail [R, C, S]; with `adc_max`, a record whose tail cannot read a hum the
    logger could hold (`hum_readable`) gets hum 0, its mean alone as the fit (the offset) and its variance as
    what is left."""
    hum, coef, left = hum_lock_in(seg, fs_hz)
    if adc_max is None:
        return hum, coef, left
    readable = hum_readable(hum.max(axis=2), hum_floor(seg.shape[2], fs_hz, left), adc_max)
    tail = np.asarray(seg, np.float64)
    offset_only = np.zeros_like(coef)
    offset_only[..., 0] = tail.mean(axis=2)
    return (np.where(readable[..., None], hum, 0.0), np.where(readable[..., None], coef, offset_only),
            np.where(readable, left, tail.var(axis=2)))


TAIL_BLOCK_S = 1e-3      # the blocks in which the ring-down is followed to the noise
TAIL_QUIET_RATIO = 1.2   # a block is quiet when its first-difference rms is within this x the quiet start's


def _block_rms(a: np.ndarray, start: int, width: int) -> np.ndarray:
    """Each record's and channel's rms about its own straight line over samples start..start+width [R, C]: the
    plate's ringing (kHz) stays in it; a mains hum over a block of a few ms is nearly a line and leaves it."""
    seg = a[:, :, start:start + width]
    i = np.arange(seg.shape[2], dtype=np.float32)
    i -= i.mean()
    c = seg - seg.mean(axis=2, keepdims=True)
    slope = (c * i).sum(axis=2, keepdims=True) / float((i * i).sum())
    return np.sqrt(((c - slope * i) ** 2).mean(axis=2))


def quiet_tail_start(seg_adc: np.ndarray, fs_hz: float, quiet_start: int) -> int | None:
    """The first sample of the record's tail after which the hit's ring-down has reached the noise: the start of
    the first block (TAIL_BLOCK_S) after `quiet_start` from which on every block's rms about its own line (median
    over the drops, the loudest channel) is within TAIL_QUIET_RATIO x the quiet start's blocks' (`_block_rms`; a
    hum channel's own hum leaves it). None when the ring-down lasts to the record's end."""
    a = np.asarray(seg_adc, np.float32)
    n = a.shape[2]
    width = max(32, int(round(TAIL_BLOCK_S * fs_hz)))
    lead = min(16, quiet_start // 4)
    ref_starts = np.arange(0, quiet_start - lead - width + 1, width)
    starts = np.arange(quiet_start, n - width + 1, width)
    if ref_starts.size == 0 or starts.size == 0:
        return None
    ref = np.median(np.stack([np.median(_block_rms(a, s, width), axis=0) for s in ref_starts]), axis=0)
    rms = np.stack([np.median(_block_rms(a, s, width), axis=0) for s in starts])       # [blocks, C]
    loud = (rms > TAIL_QUIET_RATIO * np.maximum(ref, 1e-3)).any(axis=1)
    if loud[-1]:
        return None
    last_loud = np.flatnonzero(loud)
    return int(starts[last_loud[-1] + 1]) if last_loud.size else int(starts[0])


def quiet_index(seg_adc: np.ndarray, fs_hz: float, quiet_start: int) -> np.ndarray | None:
    """The record's quiet samples for the hum: the quiet start (less a margin before the first arrival) and the
    tail after the ring-down (`quiet_tail_start`), as sample numbers; None without a quiet tail."""
    t0 = quiet_tail_start(seg_adc, fs_hz, quiet_start)
    if t0 is None:
        return None
    lead = min(16, quiet_start // 4)
    return np.r_[np.arange(0, quiet_start - lead), np.arange(t0, np.asarray(seg_adc).shape[2])]
