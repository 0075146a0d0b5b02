"""The zero-shot benchmark's other choices of the calibration drops (benchmarks/bench_zeroshot_rigs.py
--drop-draws): each draw is four cases calibrate accepts with its defaults, one in each plate quadrant, the same
for the same draw and different across draws."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_zeroshot_rigs as bench  # noqa: E402

from impactsense.calibration.drops import case_table, extract, select_drops  # noqa: E402
from impactsense.calibration.options import CalibrateOptions  # noqa: E402
from impactsense.calibration.problem import measured_core_config  # noqa: E402
from impactsense.data import load_session  # noqa: E402


def test_drawn_drops_are_accepted_one_per_quadrant_and_differ():
    session = load_session("bundled")
    feats = extract(session, measured_core_config(session.rig, CalibrateOptions()))
    rows, _ = case_table(session, feats)
    px, py = session.rig.plate_x_mm, session.rig.plate_y_mm
    choices = bench.drop_choices("bundled", 4)
    assert choices[0] == [] and len(choices) == 4          # draw 0: calibrate's auto choice
    draws = choices[1:]
    for cases in draws:
        assert len(set(cases)) == 4
        quadrants = {(rows[c]["x"] >= px / 2, rows[c]["y"] >= py / 2) for c in cases}
        assert len(quadrants) == 4
        select_drops(session, feats, drops=cases)          # calibrate --drops takes them (raises otherwise)
    assert bench.drawn_drops(session, rows, 2) == draws[1]
    assert len({tuple(c) for c in draws}) == 3
    auto = select_drops(session, feats).case_ids
    assert not any(np.array_equal(sorted(auto), sorted(c)) for c in draws)
