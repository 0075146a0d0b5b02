"""The board's analog front end: an anti-alias low-pass in front of the SAADC (rig.json `board_front_end`).

Declared as a Butterworth low-pass of `anti_alias_poles` poles with its -3 dB corner at `anti_alias_hz`
(data.Rig.board_anti_alias). The emulated board (capture.board_samples) applies it to the lab's recordings
before the scan grid, as the analog filter acts on the sensor's voltage before the SAADC samples it. The
model is the analog filter's own response (scipy.signal.butter(..., analog=True)), applied to the recording's
spectrum up to its Nyquist frequency: exact for the band-limited signal the recording holds (no bilinear
warping), causal (the analog filter's impulse response), and the same on all four channels, so it delays every
arrival by the same group delay and leaves the differences of arrival times as they were.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, freqs_zpk


def anti_alias_response(f_hz, corner_hz: float, poles: int) -> np.ndarray:
    """The analog Butterworth's complex response H(j 2 pi f) at f_hz: |H| = 1 / sqrt(1 + (f / corner)^(2 poles))."""
    z, p, k = butter(int(poles), 2 * np.pi * float(corner_hz), analog=True, output="zpk")
    _, h = freqs_zpk(z, p, k, worN=2 * np.pi * np.atleast_1d(np.asarray(f_hz, float)))
    return h


def settle_samples(fs_hz: float, corner_hz: float, poles: int) -> int:
    """Samples (at fs_hz) within which the filter's impulse response has decayed below 1e-6 of its peak: the
    slowest pole's envelope exp(-sigma t), sigma = 2 pi corner sin(pi / (2 poles))."""
    sigma = 2 * np.pi * float(corner_hz) * np.sin(np.pi / (2 * int(poles)))
    return int(np.ceil(np.log(1e6) / sigma * float(fs_hz))) + 1


def anti_aliased(x: np.ndarray, fs_hz: float, corner_hz: float, poles: int) -> np.ndarray:
    """x (float, [..., n] at fs_hz) through the analog low-pass: float32 [..., n]. Each record is led in by its
    first sample and continued by its last for as long as the filter takes to settle (settle_samples, at least
    256), so the filter starts at rest on the record's level (an analog filter has been running before the
    record) and the FFT's wrap-around falls outside the record."""
    x = np.asarray(x, np.float32)
    n = x.shape[-1]
    pad = max(256, settle_samples(fs_hz, corner_hz, poles))
    xp = np.pad(x, [(0, 0)] * (x.ndim - 1) + [(pad, pad)], mode="edge").astype(np.float64)
    level = xp[..., :1]
    m = xp.shape[-1]
    h = anti_alias_response(np.fft.rfftfreq(m, 1.0 / float(fs_hz)), corner_hz, poles)
    y = np.fft.irfft(np.fft.rfft(xp - level, axis=-1) * h, n=m, axis=-1) + level
    return y[..., pad:pad + n].astype(np.float32)
