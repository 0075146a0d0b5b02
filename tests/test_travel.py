"""The travel-time model of an anisotropic plate: the core's localiser with a travel metric, and its fit."""

import numpy as np
import pytest

from impactsense import _core
from impactsense.travel import fit_travel, metric_of, travel_distances

SENSORS = np.array([[50.0, 45.0], [400.0, 55.0], [395.0, 300.0], [60.0, 290.0]])
PLATE = (450.0, 350.0)


def synthetic_toa(xy, v, metric, delays=(0.0, 0.0, 0.0, 0.0), t0=100.0):
    return (t0 + travel_distances(xy, SENSORS, metric) / v + np.asarray(delays)[None]).astype(np.float32)


def localise(toa, v, metric=None):
    kw = {} if metric is None else {"travel_metric": list(metric)}
    return _core.localise_batch(np.ascontiguousarray(toa), np.ones(toa.shape, np.uint8), SENSORS[:, 0].tolist(),
                                SENSORS[:, 1].tolist(), v, 1.0, *PLATE, 4.0, **kw)


def test_localiser_with_the_plates_metric_finds_exact_positions():
    """ToAs made with elliptical wavefronts (speed along x 1.5x that along y): the metric's localiser
    recovers the position inside the sensors' hull to 0.05 mm; the Euclidean one misses by millimetres."""
    rng = np.random.default_rng(1)
    xy = np.c_[rng.uniform(80, 370, 30), rng.uniform(80, 270, 30)]
    q = metric_of(-0.385, 0.0)   # (1 - a) / (1 + a) = 2.25 = 1.5^2
    toa = synthetic_toa(xy, 1.6, q)
    got = localise(toa, 1.6, q)
    err = np.hypot(got["x_mm"] - xy[:, 0], got["y_mm"] - xy[:, 1])
    assert np.all(got["status"] == 0) and err.max() < 0.05
    iso = localise(toa, 1.6)
    assert np.median(np.hypot(iso["x_mm"] - xy[:, 0], iso["y_mm"] - xy[:, 1])) > 2.0


def test_identity_metric_is_the_isotropic_localiser_bit_for_bit():
    rng = np.random.default_rng(2)
    xy = np.c_[rng.uniform(20, 430, 20), rng.uniform(20, 330, 20)]
    toa = synthetic_toa(xy, 1.9, (1.0, 0.0, 1.0)) + rng.normal(0, 2.0, (20, 4)).astype(np.float32)
    a, b = localise(toa, 1.9), localise(toa, 1.9, (1.0, 0.0, 1.0))
    for key in ("x_mm", "y_mm", "t0_us", "cov"):
        assert np.array_equal(a[key], b[key])


def test_a_metric_that_is_not_positive_definite_is_a_config_error():
    toa = synthetic_toa(np.array([[200.0, 150.0]]), 1.5, (1.0, 0.0, 1.0))
    r = localise(toa, 1.5, (1.0, 2.0, 1.0))
    assert r["status"][0] != 0 and np.isnan(r["x_mm"][0])


@pytest.mark.parametrize("a, b", [(0.0, 0.0), (-0.3, 0.1), (0.25, -0.15)])
def test_fit_travel_recovers_velocity_delays_and_metric(a, b):
    """Known DToA (the model's own form, 1 us pick noise, 5 % cycle-skipped picks 15 us late). The soft-L1
    loss still feels a late pick (~3 us of pull each), so a channel's delay moves with its share of them:
    0.5 us allowed (the draw's shares differ by a few percent between channels)."""
    rng = np.random.default_rng(3)
    xy = np.c_[rng.uniform(10, 440, 300), rng.uniform(10, 340, 300)]
    delays = (0.0, -2.0, 4.0, 1.5)
    toa = synthetic_toa(xy, 1.7, metric_of(a, b), delays, t0=rng.uniform(900, 1100, (300, 1)))
    toa = toa + rng.normal(0, 1.0, toa.shape)
    toa[rng.random(toa.shape) < 0.05] += 15.0
    fit = fit_travel(toa, xy, SENSORS, anisotropic=True)
    assert fit.velocity_mm_per_us == pytest.approx(1.7, rel=0.01)
    assert np.allclose(fit.delays_us, delays, atol=0.5)
    assert np.allclose(fit.metric, metric_of(a, b), atol=0.01)
    assert 0.7 < fit.spread_us < 2.0
