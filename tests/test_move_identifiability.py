"""bench_move_identifiability's measure of a move's own signature: the channel's contrast regressed on the true
move's path change, as a ratio to the slowness (1: the move model, 0: a constant delay) with a case-level error.
The synthetic drops of test_move_or_delay (300 mm square, corner discs, 40 cases x 3 drops, 3 µs case and 2 µs
drop noise): a move across the disc's look direction reads ~1, a delay ~0, and a move along the look direction
(the path change nearly the same for every impact) has an error as large as its own signature."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_move_identifiability import case_scatter, signature_slope  # noqa: E402
from test_move_or_delay import _features, _reference  # noqa: E402

ACROSS = np.array([5.0, -5.0])    # disc 2 at (270, 270): across its look direction to the plate's centre
ALONG = np.array([-5.0, -5.0])    # towards the centre: every path shorter by nearly the same


def test_a_move_reads_one_and_a_delay_reads_zero():
    """Across the look direction the slope over the slowness is 1 within 3 of its standard errors on each of 5
    draws, and its error is under 0.5 (the signature's spread ~2.4 mm against 3.5 µs case noise over 40 cases); a
    6 µs delay with the same move's path change as regressor reads 0 within 3 errors."""
    for seed in range(5):
        rng = np.random.default_rng(seed)
        m = signature_slope(_reference(), _features(rng, move=ACROSS), 2, ACROSS)
        assert abs(m["slope_ratio"] - 1.0) <= 3 * m["se"] and m["se"] < 0.5, m
        d = signature_slope(_reference(), _features(rng, delay_us=6.0), 2, ACROSS)
        assert abs(d["slope_ratio"]) <= 3 * d["se"], d


def test_a_move_along_the_look_direction_has_little_signature_of_its_own():
    """Along the look direction the mean path change is most of the move (a delay takes it) and its spread is a
    fraction of the across move's: the slope's error is larger, so the same picks tell it from a delay less."""
    rng = np.random.default_rng(7)
    along = signature_slope(_reference(), _features(rng, move=ALONG), 2, ALONG)
    across = signature_slope(_reference(), _features(rng, move=ACROSS), 2, ACROSS)
    assert abs(along["path_mean_mm"]) > 2 * along["path_sd_mm"], along
    assert along["path_sd_mm"] < 0.6 * across["path_sd_mm"], (along, across)
    assert along["se"] > 1.5 * across["se"], (along, across)


def test_case_scatter_finds_the_floor_and_the_excess():
    """Case means with a 3 µs case error over a 2 µs drop error (3 drops): the case-mean sd ~sqrt(9 + 4 / 3) = 3.2 µs,
    the floor 2 / sqrt(3) = 1.15 µs (within 25 % on 480 drops per channel)."""
    rng = np.random.default_rng(0)
    case = np.repeat(np.arange(160), 3)
    r = rng.normal(0, 3.0, (160, 4))[case] + rng.normal(0, 2.0, (480, 4))
    sd, floor = case_scatter(r, case)
    assert np.all(np.abs(sd / np.sqrt(9 + 4 / 3) - 1) < 0.25), sd
    assert np.all(np.abs(floor / (2 / np.sqrt(3)) - 1) < 0.25), floor
