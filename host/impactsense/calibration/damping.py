"""D_s from the envelope decay: the direct estimate of the plate's mass-proportional damping.

With M u'' + D_s M u' + K u = f, u = exp(-D_s t / 2) v turns the equation into M v'' + (K - D_s^2 / 4 M) v =
f exp(D_s t / 2): once the ~50 us contact is over, every record of the damped plate is the undamped one times
exp(-D_s t / 2) (the D_s^2 / 4 shift of K is < 0.1 % of any mode above 1 kHz). The log-envelope slope of every
channel is therefore lambda = lambda_0 + D_s / 2, lambda_0 the geometric trend of the undamped field (direct
wave spreading, reflections), the same for the twin and the rig when the twin's geometry is right.

The observable is the log-envelope slope in 1 ms blocks from 1 ms after the AIC onset, like the diagnose
tool's decay (`impactsense.residuals`), up to 8 ms after it or the record's end (`record_blocks`: a record that
keeps under MIN_BLOCKS whole blocks after the start is cut into MIN_BLOCKS shorter blocks; a block past a
record's end is left out, never padded), but with the noise power subtracted from each block and the window cut
where the *measured* case's envelope falls to `SNR` x the noise (the same blocks are then used for the FEM
records of that case, scaled to the measured peak): a twin that decays faster or slower must not see a
different window, and blocks at the noise floor must not flatten the slope. Then

    D_s = D_ref + (lambda_meas - lambda_sim(D_ref)) / s,   s = d lambda_sim / d D_s  (theory 1/2)

with s measured by a secant between two FEM runs; the median over the 16 (drop, sensor) differences makes it
robust to a channel whose envelope the twin gets wrong.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _core
from ..signal import core_samples

BLOCK_MS = 1.0
START_MS = 1.0          # after the AIC onset: the direct wave has passed
MAX_MS = 8.0            # window end at the latest (the FEM runs cover it, see DECAY_DURATION_MS)
SNR = 5.0               # keep blocks whose noise-corrected RMS is at least SNR x the noise RMS
MIN_BLOCKS = 3
MIN_BLOCK_MS = 0.2      # blocks are never cut shorter (a few cycles of a plate's lowest ringing modes)
# the span the blocks are sized to: this quantile over the records' channels of the time each keeps after the
# window's start (a few late picks do not shrink every block; a channel that keeps less loses its last block)
SPAN_QUANTILE = 0.1
# FEM duration for the decay runs: the window ends MAX_MS after the onset, the onset is < 0.5 ms after the
# touch, and the simulator fades its last taper_ms (1 ms) out
DECAY_DURATION_MS = 10.0
# The estimate's lower bound (1/s). The design's D_s range (fem.FACTORS, 200..1200) is where its Sobol runs
# screen the PZT block, not what a plate can be: glass or a thick metal plate on soft pads rings for 50-100 ms
# (D_s 20-40). An estimate under the design's low end is kept down to this floor (a decay time of 0.4 s).
FLOOR_PER_S = 5.0


@dataclass(frozen=True)
class Blocks:
    """The decay window's layout: `count` blocks of `width_ms` from START_MS after the onset."""
    width_ms: float = BLOCK_MS
    count: int = int(round((MAX_MS - START_MS) / BLOCK_MS))

    @property
    def end_ms(self) -> float:
        return START_MS + self.width_ms * self.count


def _onsets(a: np.ndarray, cfg):
    feats = _core.extract_batch(core_samples(a, cfg), cfg)
    onset = np.nan_to_num(np.asarray(feats["toa_aic"], float), nan=0.0).astype(int)
    return onset, np.asarray(feats["noise_rms"], float) ** 2


def record_blocks(adc, cfg) -> Blocks:
    """The blocks the records hold: 1 ms blocks up to MAX_MS after the onset or the span the records keep after
    START_MS (its SPAN_QUANTILE over the records' channels), whichever ends first; a span under MIN_BLOCKS whole
    blocks is cut into MIN_BLOCKS blocks of span / MIN_BLOCKS (not under MIN_BLOCK_MS)."""
    a = np.asarray(adc)
    onset, _ = _onsets(a, cfg)
    fs = float(cfg.fs_hz)
    kept = int(np.floor(np.quantile(a.shape[-1] - onset, SPAN_QUANTILE)))     # samples from the onset
    span_ms = (kept - int(round(START_MS * 1e-3 * fs))) / fs * 1e3
    full = Blocks()
    whole = int(np.floor(span_ms / BLOCK_MS + 1e-9))
    if whole >= full.count:
        return full
    if whole >= MIN_BLOCKS:
        return Blocks(BLOCK_MS, whole)
    width = np.floor(span_ms * 1e-3 * fs / MIN_BLOCKS) / fs * 1e3       # whole samples: none past the span
    return Blocks(float(max(width, MIN_BLOCK_MS)), MIN_BLOCKS)


def block_power(adc, cfg, bias: float, blocks: Blocks = Blocks()) -> np.ndarray:
    """Noise-corrected mean square per block after the onset, [R, 4, blocks] (counts^2); NaN for a block that
    runs past its record's end."""
    a = np.asarray(adc)
    onset, noise2 = _onsets(a, cfg)
    fs = float(cfg.fs_hz)
    bw = int(round(blocks.width_ms * 1e-3 * fs))
    b0 = int(round(START_MS * 1e-3 * fs))
    nb = blocks.count
    idx = onset[..., None] + b0 + np.arange(nb * bw)[None, None, :]
    past = (onset[..., None] + b0 + (np.arange(nb)[None, None, :] + 1) * bw) > a.shape[-1]
    idx = np.clip(idx, 0, a.shape[-1] - 1)
    seg = np.take_along_axis(a.astype(float) - bias, idx, axis=-1).reshape(*a.shape[:2], nb, bw)
    power = seg.var(axis=-1) - noise2[..., None]          # var: the block mean (baseline drift) removed
    return np.where(past, np.nan, power)


def window_mask(power_meas: np.ndarray, noise_rms: np.ndarray) -> np.ndarray:
    """[cases, 4, blocks] True for the leading blocks whose measured RMS stays >= SNR x noise (NaN: not)."""
    ok = power_meas >= (SNR * np.asarray(noise_rms, float)[..., None]) ** 2
    return np.cumprod(ok, axis=-1).astype(bool)


def decay_rates(power: np.ndarray, mask: np.ndarray, width_ms: float = BLOCK_MS) -> np.ndarray:
    """Amplitude decay rate [1/s] (positive = decaying) per (case, channel): LS slope of log power / -2."""
    t = (np.arange(power.shape[-1]) + 0.5) * width_ms * 1e-3
    out = np.full(power.shape[:-1], np.nan)
    for ij in np.ndindex(*power.shape[:-1]):
        m = mask[ij] & (power[ij] > 0)
        if m.sum() >= MIN_BLOCKS:
            out[ij] = -0.5 * np.polyfit(t[m], np.log(power[ij][m]), 1)[0]
    return out


def case_power(power: np.ndarray, recording_ids: list) -> np.ndarray:
    """[cases, 4, blocks]: geometric mean of the block power over each case's repetitions (NaN where one
    repetition's record ends before the block does)."""
    return np.stack([np.exp(np.mean(np.log(np.maximum(power[np.asarray(r)], 1e-6)), axis=0))
                     for r in recording_ids])


def scaled_noisy(adc, peak, bias: float, noise_counts: float, rng, adc_max: int) -> np.ndarray:
    """Simulated records scaled to `peak` [cases, 4] about the bias, the rig's noise added, quantised."""
    a = np.asarray(adc, float) - bias
    pk = np.abs(a).max(axis=-1, keepdims=True)
    a = a * np.asarray(peak, float)[..., None] / np.where(pk > 0, pk, 1.0)
    a = a + rng.normal(0.0, noise_counts, a.shape)
    return np.clip(np.rint(a + bias), 0, adc_max).astype(np.uint16)


def sim_power(adc, cfg, bias, peak, noise_counts: float, n_noise: int, seed: int,
              blocks: Blocks = Blocks()) -> np.ndarray:
    """`block_power` of simulated records scaled to the measured peaks, noise added (mean of realisations)."""
    rng = np.random.default_rng(seed)
    rail = int(cfg.adc_max) + int(cfg.sample_offset)   # the ADC's top in its own counts
    return np.mean([block_power(scaled_noisy(adc, peak, bias, noise_counts, rng, rail), cfg, bias, blocks)
                    for _ in range(max(1, n_noise))], axis=0)


def robust_se(values: np.ndarray) -> float:
    """Standard error of the median of `values` from their MAD (normal efficiency factor 1.2533)."""
    v = np.asarray(values, float).ravel()
    v = v[np.isfinite(v)]
    mad = 1.4826 * np.median(np.abs(v - np.median(v)))
    return float(1.2533 * mad / np.sqrt(max(v.size, 1)))


def damping_step(meas: np.ndarray, sim: np.ndarray, d_ref: float, slope: float = 0.5) -> float:
    """D_s that moves the twin's decay onto the measured one: d_ref + median(meas - sim) / slope."""
    diff = np.asarray(meas, float) - np.asarray(sim, float)
    return float(d_ref + np.nanmedian(diff) / slope)
