"""A disc's bond in the simulator (`sim.bond.DiscBond`, `sim.simulate.analogue_fields`): the plate's strain reaches
the disc through a first-order low-pass with a gain loss, applied in continuous time before the recorder samples
it. On a band-limited response (a coarse mesh's plate) the bonded record must be the unbonded one through the
analytic transfer function g / (1 + j f / fc), and that gain and corner must be read back from the two records."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from impactsense.errors import ConfigError
from impactsense.sim.bond import DiscBond
from impactsense.sim.simulate import simulate_voltages

from conftest import COARSE_DROPS  # noqa: E402

X, Y, H = COARSE_DROPS


def through(a: np.ndarray, fs_hz: float, gain: float, corner_hz: float) -> np.ndarray:
    """Rows of a (records at rest before their start) through g / (1 + j f / fc), by the zero-padded FFT: a causal
    filter's first n outputs depend on the first n inputs only, so the truncated record is no approximation."""
    n = a.shape[-1]
    f = np.fft.rfftfreq(4 * n, 1.0 / fs_hz)
    return np.fft.irfft(np.fft.rfft(a, 4 * n, axis=-1) * gain / (1 + 1j * f / corner_hz), 4 * n, axis=-1)[..., :n]


@pytest.fixture(scope="module")
def setup(coarse_plate_run):
    return coarse_plate_run


def test_the_bond_is_first_order_with_the_gain_and_corner_its_stiffnesses_give():
    bond = DiscBond(stiffness_ratio=1.5, loss_time_s=1e-4)
    assert bond.gain == pytest.approx(0.6)
    assert bond.corner_hz == pytest.approx(2.5 / (2 * math.pi * 1e-4))
    assert abs(bond.transfer(bond.corner_hz)) == pytest.approx(bond.gain / math.sqrt(2))
    stiffer = DiscBond(stiffness_ratio=4.0, loss_time_s=1e-4)          # the same disc loss, a stiffer bond
    assert stiffer.gain > bond.gain and stiffer.corner_hz > bond.corner_hz
    back = DiscBond.from_gain_corner(0.45, 3500.0)
    assert back.gain == pytest.approx(0.45) and back.corner_hz == pytest.approx(3500.0)
    with pytest.raises(ConfigError):
        DiscBond.from_gain_corner(1.2, 3500.0)


@pytest.mark.parametrize("gain, corner_hz", [(0.7, 4000.0), (0.45, 2500.0)])
def test_the_bonded_record_is_the_analytic_transfer_function_of_the_unbonded_one(setup, gain, corner_hz):
    rig, params, base = setup
    bond = DiscBond.from_gain_corner(gain, corner_hz)
    got = simulate_voltages(params, rig, X, Y, H, workers=1, disc_bonds=[None, bond, None, None])["volts"]
    np.testing.assert_array_equal(got[:, [0, 2, 3]], base[:, [0, 2, 3]])
    peak = np.abs(base[:, 1]).max()
    err = np.abs(got[:, 1] - through(base[:, 1], rig.fs_hz, gain, corner_hz)).max()
    assert err < 0.01 * peak
    assert np.abs(got[:, 1] - gain * base[:, 1]).max() > 20 * err      # the low-pass is resolved, not a gain
    # gain and -3 dB corner read back from the two records (least squares over both drops)
    fit = least_squares(lambda p: (got[:, 1] - through(base[:, 1], rig.fs_hz, p[0], p[1])).ravel() / peak,
                        x0=[0.6, 3000.0], x_scale=[0.1, 1000.0])
    assert fit.x[0] == pytest.approx(gain, rel=0.01)
    assert fit.x[1] == pytest.approx(corner_hz, rel=0.03)


def test_a_bond_and_a_delay_on_one_disc_compose(setup):
    rig, params, base = setup
    bond = DiscBond.from_gain_corner(0.6, 3000.0)
    both = simulate_voltages(params, rig, X, Y, H, workers=1, disc_bonds=[bond, None, None, None],
                             disc_delays_s=[2.0 / rig.fs_hz, 0.0, 0.0, 0.0])["volts"][:, 0]
    bonded = simulate_voltages(params, rig, X, Y, H, workers=1, disc_bonds=[bond, None, None, None])["volts"][:, 0]
    np.testing.assert_allclose(both[:, 2:], bonded[:, :-2], rtol=0, atol=1e-6 * np.abs(bonded).max())


def test_no_bond_is_the_plain_run_bit_for_bit(setup):
    rig, params, base = setup
    got = simulate_voltages(params, rig, X, Y, H, workers=1, disc_bonds=[None] * 4)["volts"]
    np.testing.assert_array_equal(got, base)
    with pytest.raises(ConfigError, match="fast"):
        simulate_voltages(params, rig, X[:1], Y[:1], H[:1], method="direct",
                          disc_bonds=[DiscBond(1.0, 1e-4), None, None, None])
    with pytest.raises(ConfigError, match="one entry per disc"):
        simulate_voltages(params, rig, X, Y, H, workers=1, disc_bonds=[None])
