"""bench_delay_picks' shift: a band-limited signal delayed by a fractional number of samples is the signal at the
shifted times (what a pure channel delay is); a whole-sample delay moves the samples."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_delay_picks  # noqa: E402


def test_fft_delay_is_a_pure_time_shift_of_a_band_limited_signal():
    n = 2000
    t = np.arange(n)
    env = np.exp(-0.5 * ((t - 900) / 120.0) ** 2)          # a burst well inside the record
    f = 0.27                                                  # cycles per sample (27 kHz at 100 kHz)
    sig = env * np.sin(2 * np.pi * f * t)
    d = 0.783
    want = np.exp(-0.5 * ((t - d - 900) / 120.0) ** 2) * np.sin(2 * np.pi * f * (t - d))
    got = bench_delay_picks.fft_delay(sig[None], d)[0]
    assert np.max(np.abs(got - want)) < 1e-3 * np.max(np.abs(sig))
    whole = bench_delay_picks.fft_delay(sig[None], 3.0)[0]
    assert np.allclose(whole[3:], sig[:-3], atol=1e-9)
