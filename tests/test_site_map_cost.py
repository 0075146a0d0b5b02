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


def test_refine_is_exact_on_a_linear_field_and_keeps_the_simulated_points():
    import numpy as np

    from impactsense.sitemap import coarse_indices, refine

    nx, ny = 23, 14
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    field = np.stack([0.3 * i - 0.2 * j + 1.0, 0.05 * i + 0.7 * j], -1)   # linear: the triangulation's exact case
    v = np.full_like(field, np.nan)
    ci, cj = coarse_indices(nx, 3), coarse_indices(ny, 3)
    assert ci[-1] == nx - 1 and cj[-1] == ny - 1 and ci[1] - ci[0] == 3   # the edges simulated, never extrapolated
    v[np.ix_(ci, cj)] = field[np.ix_(ci, cj)]
    v[3, 3] = 99.0                                                  # a simulated point is kept as it is
    out = refine(v).reshape(nx, ny, 2)
    assert out[3, 3, 0] == 99.0
    far = (np.abs(i - 3) > 3) | (np.abs(j - 3) > 3)                  # away from the perturbed node
    assert np.allclose(out[far], field[far], atol=1e-9)
    assert np.isfinite(out).all()


def test_plan_every_one_is_every_point_off_the_discs_and_coarser_keeps_the_edges(session1):
    import numpy as np

    from impactsense.sitemap import EDGE_BAND_MM, plan

    rig = session1.rig
    (x0, y0, nx, ny), on_disc, all_pts = plan(rig, 5.0, 10.0, 1)
    assert np.array_equal(all_pts, ~on_disc)
    _, _, sim2 = plan(rig, 5.0, 10.0, 2)
    _, _, sim3 = plan(rig, 5.0, 10.0, 3)
    assert not (sim2 & on_disc).any() and (sim3 <= all_pts).all()
    assert sim3.sum() < sim2.sum() < all_pts.sum()
    from impactsense.sitemap import grid_xy

    xy = grid_xy(x0, y0, 5.0, nx, ny)
    edge = np.minimum.reduce([xy[:, 0], rig.plate_x_mm - xy[:, 0], xy[:, 1], rig.plate_y_mm - xy[:, 1]])
    assert sim3[(edge <= EDGE_BAND_MM) & ~on_disc].all()            # the edge band is all simulated
    interior = (edge > EDGE_BAND_MM + 20) & ~on_disc
    assert sim3[interior].mean() == pytest.approx(1 / 9, abs=0.04)   # the lattice's share inside


def test_budget_chooses_the_fewest_drops_that_fit(session1):
    from impactsense.sitemap import MAX_EVERY, every_for_budget

    big = session1.rig   # any plate: the budget is relative to its own full map
    params = SimParams.from_rig(big)
    free = every_for_budget(params, big, None)
    assert free["every"] == 1 and free["fits"] and free["simulated"] > 0
    tight = every_for_budget(params, big, 0.4 * free["cpu_s"])
    assert tight["every"] > 1 and tight["cpu_s"] < free["cpu_s"]
    assert tight["fits"] or tight["every"] == MAX_EVERY
    assert tight["fits"] == (tight["cpu_s"] <= 0.4 * free["cpu_s"])
    from impactsense.sitemap import site_map_cost

    finer = site_map_cost(params, big, every=tight["every"] - 1)   # the smallest step that fits: one finer would not
    assert finer["cpu_s"] > 0.4 * free["cpu_s"]


def test_budget_narrows_the_edge_band_when_the_coarsest_lattice_is_over(session1):
    from impactsense.sitemap import BUDGET_PLANS, MAX_EVERY, every_for_budget, site_map_cost

    rig = session1.rig
    params = SimParams.from_rig(rig)
    coarsest = site_map_cost(params, rig, every=MAX_EVERY)
    tight = every_for_budget(params, rig, 0.9 * coarsest["cpu_s"])
    assert tight["every"] == MAX_EVERY and tight["edge_band_mm"] < coarsest["edge_band_mm"]
    assert tight["simulated"] < coarsest["simulated"]
    assert tight["fits"] == (tight["cpu_s"] <= 0.9 * coarsest["cpu_s"])
    none = every_for_budget(params, rig, 1e-6)        # nothing fits: the last plan, said so
    assert (none["every"], none["edge_band_mm"]) == BUDGET_PLANS[-1] and not none["fits"]
