"""A disc's time skew in the simulator (`sim.simulate.delayed_fields`): the analogue signal delayed before the
recorder samples it. Whole samples move the record; a fraction of a sample equals the exact band-limited shift
where the response is band-limited (a coarse mesh's low-frequency plate), and the other discs are untouched."""

from __future__ import annotations

import numpy as np
import pytest

from impactsense.errors import ConfigError
from impactsense.sim.simulate import simulate_voltages

from conftest import COARSE_DROPS  # noqa: E402

X, Y, H = COARSE_DROPS


def band_limited_shift(a: np.ndarray, delay_samples: float) -> np.ndarray:
    """Rows of a shifted by delay_samples through the FFT (zero-padded: the records start and end at rest)."""
    n = a.shape[-1]
    spec = np.fft.rfft(a, 4 * n, axis=-1)
    f = np.fft.rfftfreq(4 * n)
    return np.fft.irfft(spec * np.exp(-2j * np.pi * f * delay_samples), 4 * n, axis=-1)[..., :n]


@pytest.fixture(scope="module")
def setup(coarse_plate_run):
    return coarse_plate_run


def test_a_whole_sample_delay_moves_the_record_and_leaves_the_other_discs(setup):
    rig, params, base = setup
    got = simulate_voltages(params, rig, X, Y, H, workers=1, disc_delays_s=[0.0, 2.0 / rig.fs_hz, 0.0, 0.0])["volts"]
    np.testing.assert_array_equal(got[:, [0, 2, 3]], base[:, [0, 2, 3]])
    np.testing.assert_allclose(got[:, 1, 2:], base[:, 1, :-2], rtol=0, atol=1e-12 * np.abs(base).max())
    assert np.all(got[:, 1, :2] == 0.0)


@pytest.mark.parametrize("fraction", [0.37, -0.583])
def test_a_fraction_of_a_sample_is_the_band_limited_shift_of_a_band_limited_response(setup, fraction):
    rig, params, base = setup
    got = simulate_voltages(params, rig, X, Y, H, workers=1,
                            disc_delays_s=[fraction / rig.fs_hz, 0.0, 0.0, 0.0])["volts"][:, 0]
    want = band_limited_shift(base[:, 0], fraction)
    keep = slice(0, base.shape[-1] - 20)   # a negative delay's record ends one sample early
    err = np.abs(got - want)[:, keep].max()
    assert err < 0.005 * np.abs(base[:, 0]).max()
    # and it is not the unshifted record: the shift is resolved
    assert np.abs(base[:, 0] - want)[:, keep].max() > 50 * err


def test_disc_delays_need_the_fast_path(setup):
    rig, params, _ = setup
    with pytest.raises(ConfigError, match="fast"):
        simulate_voltages(params, rig, X[:1], Y[:1], H[:1], method="direct", disc_delays_s=[1e-6, 0, 0, 0])
