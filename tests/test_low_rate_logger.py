"""A low-rate logger (20 kHz: Nyquist 10 kHz) through calibrate's band observables: every band is held under the
logger's Nyquist frequency (calibration.bands.band_sos) and still times a packet; before, scipy refused the
5-15 kHz group-delay band and the 1-15 kHz anchor band ("critical frequencies must be 0 < Wn < fs/2") and
`impactsense calibrate` stopped with an internal error on such a session."""

import numpy as np
import pytest
from scipy.signal import butter

from impactsense.calibration import bands, group_delay, plate

DELAYS_US = np.array([0.0, 150.0, 300.0, 450.0])   # whole samples at 20 kHz


def _records(fs_hz, n=1024, onset_us=8000.0, seed=0):
    """[2, 4, n] counts: one broadband packet (a few cycles, 1-8 kHz) reaching channel c DELAYS_US[c] later."""
    t = np.arange(n) / fs_hz * 1e6
    rng = np.random.default_rng(seed)
    out = np.empty((2, 4, n))
    for r in range(2):
        for c in range(4):
            u = (t - onset_us - DELAYS_US[c]) * 1e-6
            packet = np.where(u > 0, np.exp(-u / 1.5e-4) * (np.sin(2 * np.pi * 3e3 * u) + 0.5 * np.sin(2 * np.pi * 6e3 * u)),
                              0.0)
            out[r, c] = 512 + 100 * packet + rng.normal(0, 0.3, n)
    return out


def _slopes(fs_hz):
    """Each band's group delays against the true pair delays: the least-squares slope [B] over both records."""
    adc = _records(fs_hz, n=int(1024 * fs_hz / 20000))
    toa = np.tile(8000.0 + DELAYS_US, (2, 1))
    gd = group_delay.group_delays(adc, toa, fs_hz, plate.PAIR_I, plate.PAIR_J, baseline_samples=64)
    assert gd.shape == (2, len(group_delay.BANDS), len(plate.PAIR_I))
    assert np.all(np.isfinite(gd))
    truth = np.tile(DELAYS_US[plate.PAIR_I] - DELAYS_US[plate.PAIR_J], 2)
    return np.array([np.polyfit(truth, gd[:, b].ravel(), 1)[0] for b in range(gd.shape[1])])


def test_group_delays_time_a_packet_on_a_20_khz_logger():
    """Every band times the shifted packet on a 20 kHz logger as on a 100 kHz one (the windowed centroid reads a
    shift a little short, ~0.9-0.97 of it, at any rate: the common window's taper)."""
    low, fast = _slopes(20000.0), _slopes(100000.0)
    assert np.all((low > 0.8) & (low < 1.05))
    np.testing.assert_allclose(low, fast, atol=0.05)


def test_band_arrivals_on_a_20_khz_logger():
    fs = 20000.0
    adc = _records(fs)
    toa = np.tile(8000.0 + DELAYS_US, (2, 1))
    t = bands.band_arrivals(adc, toa, fs, baseline_samples=64)
    assert np.all(np.isfinite(t))
    d = bands.pair_differences(t, plate.PAIR_I, plate.PAIR_J)
    truth = DELAYS_US[plate.PAIR_I] - DELAYS_US[plate.PAIR_J]
    assert np.abs(d - truth[None, None, :]).max() < 25.0   # half a sample at 20 kHz


def test_a_band_above_the_logger_is_nan_and_the_others_are_kept():
    fs = 8000.0   # Nyquist 4 kHz: nothing of 5-15 kHz
    adc = _records(fs, n=512)
    toa = np.tile(8000.0 + DELAYS_US, (2, 1))
    gd = group_delay.group_delays(adc, toa, fs, plate.PAIR_I, plate.PAIR_J, baseline_samples=32)
    top = [b for b, (lo, _, _) in enumerate(group_delay.BANDS) if lo >= bands.NYQUIST_SHARE * fs / 2]
    assert top and np.all(np.isnan(gd[:, top]))
    assert np.all(np.isfinite(np.delete(gd, top, axis=1)))


@pytest.mark.parametrize("fs", [50000.0, 100000.0])
def test_faster_loggers_keep_the_bands_as_they_were(fs):
    for lo, hi, _ in group_delay.BANDS:
        np.testing.assert_array_equal(bands.band_sos(lo, hi, fs, group_delay.ORDER),
                                      butter(group_delay.ORDER, [lo, hi], btype="band", fs=fs, output="sos"))
