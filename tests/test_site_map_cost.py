"""simulate-dataset's site-map line: the grid's points, the solver and its estimated CPU time (sitemap.site_map_cost)
instead of "a large or thin plate takes minutes" (a 1200 x 800 x 1.5 mm sheet: 37,209 points, ~20 CPU-min)."""

import pytest

from impactsense.data import rig_from_dict
from impactsense.sim import SimParams
from impactsense.sitemap import grid, site_map_cost


def test_cost_grows_with_the_plate(session1):
    small = session1.rig
    big = rig_from_dict(dict(small.raw, plate_x_mm=2 * small.plate_x_mm, plate_y_mm=2 * small.plate_y_mm))
    a, b = site_map_cost(SimParams.from_rig(small), small), site_map_cost(SimParams.from_rig(big), big)
    _, _, nx, ny = grid(small, 5.0, 10.0)
    assert a["points"] == nx * ny and a["solver"] in ("direct", "modal") and a["cpu_s"] > 0
    assert b["points"] == pytest.approx(4 * a["points"], rel=0.1)   # the grid keeps a margin from the edges
    assert b["cpu_s"] > 2 * a["cpu_s"]
