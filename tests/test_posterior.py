"""The localiser's posterior mean (impactcore.h posterior_grid): off it is the Huber fit bit for bit; on, exact
arrivals stay where they are, noisy arrivals from beyond the sensors' hull (where the fit's valley is long) are
placed closer to the truth than by the fit, and inside the hull it does no harm (docs/findings.md "The
posterior mean")."""

import numpy as np

from impactsense import _core

# A 450 x 350 mm plate with its sensors inset, so that a strip along each edge is outside
# their hull.
SX = [50.0, 400.0, 395.0, 60.0]
SY = [45.0, 55.0, 300.0, 290.0]
PLATE = (450.0, 350.0)
V = 1.2


def arrivals(xy, t0=100.0):
    xy = np.atleast_2d(np.asarray(xy, float))
    d = np.hypot(xy[:, None, 0] - np.array(SX)[None], xy[:, None, 1] - np.array(SY)[None])
    return (t0 + d / V).astype(np.float32)


def run(toa, grid, sigma=4.0):
    use = np.ones(toa.shape, np.uint8)
    r = _core.localise_batch(np.ascontiguousarray(toa), use, SX, SY, V, sigma, *PLATE, 4.0, [], [], 4, grid)
    return np.c_[r["x_mm"], r["y_mm"]].astype(float), r


def test_off_is_the_fit_bit_for_bit():
    rng = np.random.default_rng(1)
    toa = arrivals(rng.uniform([20, 20], [430, 330], (40, 2))) + rng.normal(0, 3, (40, 4)).astype(np.float32)
    fit, a = run(toa, 0)
    one, b = run(toa, 1)
    default = _core.localise_batch(toa, np.ones(toa.shape, np.uint8), SX, SY, V, 4.0, *PLATE, 4.0, [], [], 4)
    for key in ("x_mm", "y_mm", "t0_us", "cov", "rms_residual_us"):
        np.testing.assert_array_equal(a[key], default[key])
        np.testing.assert_array_equal(b[key], default[key])


def test_exact_arrivals_stay_put():
    truth = np.array([[225.0, 175.0], [120.0, 240.0], [330.0, 110.0]])
    pos, r = run(arrivals(truth), 15)
    # the posterior of exact arrivals is centred on the truth up to its curvature over +-3 sd (~1 mm here)
    assert np.max(np.abs(pos - truth)) < 0.5
    np.testing.assert_array_equal(r["rms_residual_us"], run(arrivals(truth), 0)[1]["rms_residual_us"])


def noisy(truth, n=300, sd=4.0, seed=7):
    rng = np.random.default_rng(seed)
    return arrivals(np.repeat(np.asarray(truth, float)[None], n, 0)) + rng.normal(0, sd, (n, 4)).astype(np.float32)


def test_beyond_the_hull_closer_than_the_fit():
    # corners beyond the sensors' hull: the fit scatters along a long valley (12-15 mm MAE at 4 us), the
    # posterior over the part of it on the plate much less (8-9.5 mm in these draws)
    for truth in ([430.0, 320.0], [15.0, 20.0], [20.0, 330.0]):
        toa = noisy(truth)
        fit, _ = run(toa, 0)
        post, _ = run(toa, 15)
        assert np.mean(np.abs(post - truth)) < 0.8 * np.mean(np.abs(fit - truth)), truth
        assert ((post >= 0) & (post <= np.array(PLATE))).all()


def test_inside_the_hull_no_harm():
    truth = np.array([225.0, 175.0])
    toa = noisy(truth, seed=3)
    fit, _ = run(toa, 0)
    post, _ = run(toa, 15)
    assert np.mean(np.abs(post - truth)) < 1.05 * np.mean(np.abs(fit - truth))


def test_the_board_budget_counts_it():
    """The board's refit cannot choose it (15 x 15 Huber costs a run are more than the event budget); off it
    costs what the localiser cost before."""
    from impactsense.board.cost import signal_fits, signal_instructions
    from impactsense.signal import SignalConfig

    off = SignalConfig()
    on = SignalConfig.from_dict({**off.to_dict(), "posterior_grid": 15})
    assert signal_fits(off) and not signal_fits(on)
    assert signal_instructions(on)["total"] > signal_instructions(off)["total"]
    assert signal_instructions(SignalConfig.from_dict({**off.to_dict(), "posterior_grid": 1})) == signal_instructions(off)
