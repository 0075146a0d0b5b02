"""The class floor's measures (benchmarks/bench_class_floor.py): the within-case scatter recovers a known release
scatter under large site offsets, and the floor is the chance of a drop's true energy crossing the cut."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_class_floor as study  # noqa: E402


def test_within_case_sd_reads_the_repetitions_scatter_not_the_sites():
    rng = np.random.default_rng(3)
    case = np.repeat(np.arange(200), 5)
    site = rng.normal(0.0, 0.3, 200)[case]               # site offsets 15 x the scatter
    values = site + rng.normal(0.0, 0.02, case.size)
    got = study.within_case_sd(values, case)
    assert abs(got - 0.02) < 0.02 * 0.1                 # 800 dof: ~2.5 % se
    between, within = study.case_parts(values, case)
    assert abs(between - 0.3) < 0.05 and abs(within - got) < 1e-12


def test_floor_is_the_chance_of_crossing_the_cut():
    cut = np.log(195.0)
    at_cut = np.full(10, cut)
    far = np.log(np.array([100.0, 300.0]))
    assert abs(study.floor_accuracy(at_cut, cut, 0.02) - 0.5) < 1e-12     # a coin toss at the cut
    assert study.floor_accuracy(far, cut, 0.02) > 1 - 1e-9                 # 20+ sigma away: never crosses
    # a boundary height 0.0256 ln from the cut at sigma 0.0165: Phi(-1.55) = 0.060 wrong, as a Monte Carlo says
    rng = np.random.default_rng(0)
    h = np.log(190.0) + rng.normal(0.0, 0.0165, 200_000)
    mc = np.mean(h < cut)
    assert abs(study.floor_accuracy(np.array([np.log(190.0)]), np.log(np.sqrt(190.0 * 200.0)), 0.0165)
               - mc) < 0.003
