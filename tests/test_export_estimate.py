"""Export's per-event estimate (board.cost's parts, board.drop_cost's drops) against qemu's measurements.

tests/data/board_cost_measured.json holds runs of `benchmarks/bench_firmware_cost.py --json` as
`benchmarks/bench_export_estimate.py --store` keeps them: what the estimate reads of each model, the host's counts
on each drop, and qemu's slowest clean and flagged events (docs/findings.md "Session 26: exportest").
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from impactsense.board import cost, drop_cost
from impactsense.export_check import estimate_total, flagged_total
from impactsense.signal import SignalConfig

RUNS = json.loads((Path(__file__).parent / "data" / "board_cost_measured.json").read_text())


def fixed(run: dict) -> int:
    return drop_cost.forests_fixed(run["walks"], run["trees"], run["inputs"], run["linear_terms"])


def estimate(run: dict) -> dict:
    cfg = SignalConfig.from_dict(run["signal"])
    est = cost.event_parts(cfg, run["front_end"], walks=run["walks"], trees=run["trees"], inputs=run["inputs"],
                           linear_terms=run["linear_terms"], twin=run["twin"], check=run["check"],
                           check_terms=run["check_terms"])
    per = drop_cost.drop_instructions(run["counts"], est, cfg, run["twin"] is not None, fixed(run))
    est["drops"] = drop_cost.slowest(per, est, np.arange(len(per)), drop_cost.beyond_base(run["counts"]),
                                     drop_cost.any_hum(run["counts"]))
    return est


@pytest.mark.parametrize("run", RUNS, ids=[r["run"] for r in RUNS])
def test_the_estimate_is_its_parts_and_bounds_what_qemu_measured(run):
    est = estimate(run)
    assert est["total"] == sum(est[k] for k in ("base", "band", "localiser", "check", "models", "twin"))
    if run["twin"]:   # a drop the twin doubts runs the cued search in place of the clean match
        assert est["flagged"] - est["total"] == cost.twin_instructions(run["twin"])["cued"] - est["twin"] > 0
    # the verdict's estimate never passes what qemu measured (at most 1 % below its slowest clean event, flagged too)
    assert estimate_total(est) >= 0.99 * run["measured"]["clean_max"]
    if run["measured"]["flagged_max"]:
        assert flagged_total(est) >= 0.99 * run["measured"]["flagged_max"]


def test_a_model_that_ran_over_on_qemu_is_called_over():
    over = [r for r in RUNS if r["measured"]["clean_max"] > cost.EVENT_BUDGET]
    assert over, "the stored runs must hold one whose clean events ran over the budget"
    for run in over:
        assert estimate_total(estimate(run)) > cost.EVENT_BUDGET


def test_a_drop_costs_more_with_more_work():
    run = RUNS[0]
    cfg = SignalConfig.from_dict(run["signal"])
    est = estimate(run)
    counts = {k: np.asarray(v) for k, v in run["counts"].items()}
    base = drop_cost.drop_instructions(counts, est, cfg, run["twin"] is not None, fixed(run))
    more = dict(counts, evaluations=counts["evaluations"] + 1, walk=counts["walk"] + 2)
    k = 0 if cost.isotropic((cfg.travel_metric_xx, cfg.travel_metric_xy, cfg.travel_metric_yy)) else 1
    step = drop_cost.drop_instructions(more, est, cfg, run["twin"] is not None, fixed(run)) - base
    assert np.allclose(step, cost.LOCALISER_PER_EVALUATION[k] + 2 * cost.FOREST_PER_NODE)


def test_the_twin_bound_counts_the_lattice_points_of_each_match():
    # a disc of radius 2 steps holds 13 points centred on one and 14 centred between four; a coarse match takes
    # every other point within its own cutoff
    assert cost.lattice_points_within(2.0, 1.0) == 14
    assert cost.lattice_points_within(1.9, 1.0) == 13
    assert cost.twin_points_bound([61, 60, 10, 10, 5], [2.2, 7, 10, 0.5, 0, -1]) == 14
    assert cost.twin_points_bound([61, 60, 10, 10, 5], [2.2, 7, 10, 0.5, 20, -1]) == 28
