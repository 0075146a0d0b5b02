"""bench_bond_inverse.spectral_one_pole: a bonded channel's one-pole read from its spectrum against the reference's
(different drops; the other channels' ratio taken out). Synthetic records only: nothing simulated."""

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_bond_inverse import spectral_one_pole  # noqa: E402

FS, N, START = 100_000.0, 2048, 128


def drops(seed: int, level: float, channel: int = -1, fc: float = 0.0, g: float = 1.0, noise: float = 2.0):
    """120 records of 4 channels: quiet until START, then a decaying broadband arrival of `level` (each drop
    its own), the amplifier's white noise (`noise` counts) after the channel's bond (g / (1 + j f / fc))."""
    rng = np.random.default_rng(seed)
    t = np.arange(N - START)
    burst = rng.normal(size=(120, 4, N - START)) * np.exp(-t / 300.0) * level * rng.uniform(0.8, 1.2, (120, 1, 1))
    if channel >= 0:
        f = np.fft.rfftfreq(2 * burst.shape[-1], 1.0 / FS)
        h = g / (1.0 + 1j * f / fc) if fc > 0 else g
        burst[:, channel] = np.fft.irfft(np.fft.rfft(burst[:, channel], 2 * burst.shape[-1]) * h)[..., :N - START]
    x = np.zeros((120, 4, N))
    x[..., START:] = burst
    return SimpleNamespace(adc=2048.0 + x + noise * rng.normal(size=x.shape), rig=SimpleNamespace(fs_hz=FS))


def test_a_bonds_one_pole_is_read_from_the_spectra_of_other_drops():
    ref = drops(0, 200.0)
    fc, g = spectral_one_pole(ref, drops(1, 300.0, channel=2, fc=3000.0, g=0.7), 2)   # stronger drops: taken out
    # above the corner |H| = g fc / f: the product is what the spectra fix best (few bins lie below fc)
    assert abs(fc * g / (3000.0 * 0.7) - 1.0) < 0.05
    assert abs(fc / 3000.0 - 1.0) < 0.15 and abs(g / 0.7 - 1.0) < 0.10


def test_a_plain_gain_or_no_change_is_no_low_pass():
    ref = drops(0, 200.0)
    fc, g = spectral_one_pole(ref, drops(2, 200.0, channel=1, g=0.6), 1)
    assert abs(g / 0.6 - 1.0) < 0.07 and fc > 100_000.0
    fc, g = spectral_one_pole(ref, drops(3, 200.0), 0)
    assert abs(g - 1.0) < 0.07 and fc > 100_000.0
