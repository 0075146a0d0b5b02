import numpy as np
import pytest

from impactsense.data import load_session


@pytest.fixture(scope="session")
def session1():
    return load_session("bundled:session-1")


@pytest.fixture(scope="session")
def synth():
    """The synthetic_capture function below."""
    return synthetic_capture


def synthetic_capture(onsets, n=2000, amp=600.0, freq_hz=20000.0, fs_hz=100000.0, bias=2048, noise=0.0,
                      decay_per_s=800.0, seed=0):
    """4-channel uint16 capture: a decaying sine burst starting exactly at each channel's onset (samples)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs_hz
    out = np.empty((4, n))
    for c, t0 in enumerate(onsets):
        tau = t - t0 / fs_hz
        burst = np.where(tau >= 0, amp * np.sin(2 * np.pi * freq_hz * tau) * np.exp(-decay_per_s * tau), 0.0)
        out[c] = bias + burst + (rng.normal(0, noise, n) if noise else 0.0)
    return np.clip(np.round(out), 0, 4095).astype(np.uint16)
