"""The onset phase test (benchmarks/bench_onset_phase.py) tells a picker whose time does not depend on where the
50 kHz samples fall from one whose time does: on a band-limited burst (all of it below the board's 25 kHz Nyquist
frequency) sampled at eight sub-sample phases, the crossing of the windowed-sinc interpolant agrees across the
phases, and the core's threshold crossing (linear between samples, |x| caught near a cycle's peak) does not."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_onset_phase as bench  # noqa: E402

from impactsense.signal import SignalConfig  # noqa: E402

FS = bench.FS
T0_US = 3000.0          # the burst's centre
SIGMA_US = 150.0        # Gaussian envelope: its spectrum is F +- 1 / (2 pi sigma) ~ +-1 kHz wide
F_HZ = 12000.0          # carrier, 0.24 fs: the burst is band-limited well below fs / 2
AMP = 2000.0
THRESHOLD = 50.0


def burst(phase: float, n: int = 800) -> np.ndarray:
    """The burst sampled at 50 kHz, the first sample at phase x 20 us: int16 [4, n] (every channel alike)."""
    t = (np.arange(n) + phase) / FS * 1e6 - T0_US
    x = 2048.0 + AMP * np.exp(-0.5 * (t / SIGMA_US) ** 2) * np.sin(2 * np.pi * F_HZ * t * 1e-6)
    return np.repeat(np.rint(x).astype(np.int16)[None], 4, axis=0)


def picks(phases):
    cfg = SignalConfig.from_dict({**SignalConfig().to_dict(), "fs_hz": FS, "onset_threshold_counts": THRESHOLD})
    x = np.stack([burst(p) for p in phases])
    got, raw = bench.core_picks(x, cfg)
    base = np.asarray(raw["baseline"], float)
    thr = np.maximum(THRESHOLD, cfg.onset_noise_factor * np.asarray(raw["noise_rms"], float))
    shift = np.asarray(phases)[:, None] * bench.US   # the samples' own clock: back to the burst's
    core = got["core threshold crossing"] + shift
    interp = bench.sinc(x, base, thr, got["core threshold crossing"]) + shift
    return core[:, 0], interp[:, 0]


def test_the_phase_test_tells_a_phase_independent_crossing_from_the_threshold_pick():
    phases = np.arange(8) / 8.0
    core, interp = picks(phases)
    assert np.isfinite(core).all() and np.isfinite(interp).all()
    # The interpolant's crossing: the sinc's error on a 0.24 fs carrier (Kaiser, 4 taps a side: ~1 % of the
    # amplitude there, ~1 count at the 50-count crossing) and int16 rounding (0.5 count) over the |x| slope at the
    # crossing (2 pi F x 50 counts ~ 3.8 counts / us): < 1 us; 2 us allows the linear step between the x4 points.
    assert np.ptp(interp) < 2.0, interp
    # The threshold crossing catches the first sample over 50 counts: up to half a 83 us carrier cycle apart.
    assert np.ptp(core) > 4.0 * np.ptp(interp), (core, interp)
