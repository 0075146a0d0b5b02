"""A loss factor on the direct solver's records: each frequency's part of a record decays as the modal solver's.

The modal solver gives mode k the decay rate s_k = D_s / 2 + eta omega_k / 2 (`modal.Poles`, SimParams.loss_factor):
on top of the mass-proportional D_s, which damps every frequency alike, a loss factor eta damps each by its own
frequency (a laminate's or a polymer's internal friction). The explicit FEM carries D_s only. After the ~50 us
contact every record of the plate is a sum of modes released at the first touch (t = 0, the records' first
sample), so the loss factor's part is, per frequency f, the factor exp(-eta pi f t) on the record. Here that
time-varying filter is applied band by band: the record's spectrum is cut into overlapping triangular bands
(BAND_HZ apart, summing to one at every frequency), each band's signal is multiplied by its centre frequency's
factor and the bands are summed. Between two centres the gain is the straight line between theirs: for the largest
loss a plate shows (eta pi t ~ 2e-4 per Hz at the end of a 10 ms record) the line is within 0.5 % of the
exponential at 1 kHz spacing (docs/method.md, "The twin's loss factor").
"""

from __future__ import annotations

import numpy as np
from scipy.fft import irfft, next_fast_len, rfft, rfftfreq

BAND_HZ = 1000.0


def apply_loss_factor(volts: np.ndarray, fs_hz: float, loss_factor: float, band_hz: float = BAND_HZ) -> np.ndarray:
    """`volts` [..., n] (t = 0 at sample 0) with every frequency f's part damped by exp(-loss_factor pi f t);
    returned as a new float array (the input when loss_factor is 0)."""
    if loss_factor <= 0:
        return volts
    x = np.asarray(volts, float)
    n = x.shape[-1]
    nfft = next_fast_len(2 * n)                    # zero padding: no band's filter wraps the record's end round
    spec = rfft(x, nfft, axis=-1)
    f = rfftfreq(nfft, 1.0 / fs_hz)
    t = np.arange(n) / fs_hz
    out = np.zeros_like(x)
    for fc in np.arange(0.0, f[-1] + band_hz, band_hz):
        w = np.clip(1.0 - np.abs(f - fc) / band_hz, 0.0, None)
        k = np.flatnonzero(w)
        if k.size == 0:
            continue
        band = np.zeros_like(spec)
        band[..., k] = spec[..., k] * w[k]
        out += irfft(band, nfft, axis=-1)[..., :n] * np.exp(-loss_factor * np.pi * fc * t)
    return out
