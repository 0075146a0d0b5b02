"""The zero-shot benchmark's other choices of the calibration drops (benchmarks/bench_zeroshot_rigs.py
--drop-draws): each draw is four cases calibrate would accept, one in each plate quadrant, the same for the
same draw and different across draws."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_zeroshot_rigs as bench  # noqa: E402

from impactsense.calibration.drops import case_table, extract, select_drops  # noqa: E402
from impactsense.data import load_session  # noqa: E402


def test_drawn_drops_are_usable_one_per_quadrant_and_differ():
    session = load_session("bundled")
    feats = extract(session)
    rows, _ = case_table(session, feats)
    px, py = session.rig.plate_x_mm, session.rig.plate_y_mm
    draws = [bench.drawn_drops(session, rows, d) for d in (1, 2, 3)]
    for cases in draws:
        assert len(set(cases)) == 4 and all(rows[c]["usable"] for c in cases)
        quadrants = {(rows[c]["x"] >= px / 2, rows[c]["y"] >= py / 2) for c in cases}
        assert len(quadrants) == 4
        select_drops(session, feats, drops=cases)          # calibrate --drops takes them
    assert bench.drawn_drops(session, rows, 2) == draws[1]
    assert len({tuple(c) for c in draws}) == 3
    auto = select_drops(session, feats).case_ids
    assert not any(np.array_equal(sorted(auto), sorted(c)) for c in draws)
