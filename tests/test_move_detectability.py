"""bench_move_identifiability's figures of what the noise of new positions lets a move test reach
(`expected_evidence`, `short_range`), on the synthetic drops of test_move_or_delay (300 mm square, corner discs,
40 cases x 3 drops, a per-case error on every channel)."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_move_identifiability import (contrast_case_means, expected_evidence, robust_sd,  # noqa: E402
                                        short_range)
from test_move_or_delay import SLOWNESS, _features, _reference  # noqa: E402

ACROSS = np.array([5.0, -5.0])    # disc 2 at (270, 270): across its look direction to the plate's centre
ALONG = np.array([-5.0, -5.0])    # towards the centre


def _fit_move(ref, F, sensor: int) -> np.ndarray:
    """Least squares (dx, dy) of the channel's case-mean contrast on -s u (no constant): the efficient fit when
    each case's contrast carries one independent error."""
    _, _, ux, uy = ref.geometry(F)
    _, first = np.unique(F.case_id, return_index=True)
    X = -SLOWNESS * np.c_[ux[first, sensor], uy[first, sensor]]
    y = contrast_case_means(ref.toa_resid(F), F.case_id, sensor)
    return np.linalg.lstsq(X, y, rcond=None)[0]


def test_the_fit_spreads_as_the_fisher_figure_says():
    """Over 200 synthetic sessions with a 5 mm x sqrt 2 move across the look direction and a known case noise, the
    fitted moves' spread (the covariance's two sd axes) is the Fisher figure's within 20 %, and the share within
    2 mm of the truth is its predicted probability within 0.08 (binomial sd at 200 draws ~0.035)."""
    ref = _reference()
    rng = np.random.default_rng(0)
    F0 = _features(rng, move=ACROSS, case_sd=3.0, drop_sd=0.0)
    # the contrast of independent channel errors of sd 3: channel i less the others' mean, 3 sqrt(1 + 1/3)
    sigma = 3.0 * np.sqrt(4.0 / 3.0)
    e = expected_evidence(ref, F0, 2, ACROSS, sigma, None, tolerance_mm=2.0)
    true = F0.sensor_xy_mm.copy()
    true[2] += ACROSS
    travel = SLOWNESS * np.hypot(F0.x_mm[:, None] - true[None, :, 0], F0.y_mm[:, None] - true[None, :, 1])
    fits = []
    for seed in range(200):   # other draws of the case noise at the same positions
        noise = np.random.default_rng(seed).normal(0, 3.0, (len(np.unique(F0.case_id)), 4))[F0.case_id]
        F = replace(F0, toa_us=20.0 + travel + noise)
        fits.append(_fit_move(ref, F, 2) - ACROSS)
    fits = np.array(fits)
    axes = np.sqrt(np.linalg.eigvalsh(np.cov(fits.T)))
    assert np.all(np.abs(axes / np.array(e["sd_axes_mm"]) - 1) < 0.2), (axes, e)
    within = float(np.mean(np.hypot(fits[:, 0], fits[:, 1]) <= 2.0))
    assert abs(within - e["p_within_tolerance"]) < 0.08, (within, e)


def test_a_move_along_the_look_direction_gains_little_over_a_delay():
    """The expected gain over a constant delay is the gain over no change less the mean path change's share: along
    the look direction most of it (under a quarter left), across it most of it kept (over half)."""
    ref = _reference()
    F = _features(np.random.default_rng(1))
    along = expected_evidence(ref, F, 2, ALONG, 3.5)
    across = expected_evidence(ref, F, 2, ACROSS, 3.5)
    assert along["gain_vs_delay"] < 0.25 * along["gain_vs_none"], along
    assert across["gain_vs_delay"] > 0.5 * across["gain_vs_none"], across
    # four times the noise variance, a quarter of the evidence
    half = expected_evidence(ref, F, 2, ACROSS, 7.0)
    assert abs(half["gain_vs_none"] / across["gain_vs_none"] - 0.25) < 1e-9


def test_short_range_separates_a_smooth_field_from_a_per_case_error():
    """Case means = a smooth field (200 mm scale, 6 us peak) + a white per-case error (2 us) + a within-case share
    (1 us, declared): the excess at 3-6 mm is the white error (within 30 %), the far bins carry the field too."""
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 400, (3000, 2))
    field = 6.0 * np.sin(xy[:, :1] / 200.0 * np.pi) * np.cos(xy[:, 1:] / 200.0 * np.pi)
    means = field + rng.normal(0, 2.0, (3000, 1)) + rng.normal(0, 1.0, (3000, 1))
    var = np.full((3000, 1), 1.0)
    bins = short_range([(xy, means, var)], bins_mm=(0.0, 6.0, 200.0, 1e9))
    assert abs(bins[0]["excess_us"][0] / 2.0 - 1) < 0.3, bins[0]
    assert bins[2]["excess_us"][0] > 1.3 * bins[0]["excess_us"][0], bins


def test_robust_sd_ignores_a_few_outliers():
    rng = np.random.default_rng(0)
    x = np.r_[rng.normal(0, 2.0, 400), np.full(10, 80.0)]
    assert abs(robust_sd(x) / 2.0 - 1) < 0.15
