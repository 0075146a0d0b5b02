"""The twin height estimate's edge term (twin_edge.py): fitted from out-of-fold residuals per position, kept only
when the positions show it, and the board's term (impactapp::twin_edge_term, through the exported twin) equals the
host's."""

import numpy as np
import pytest

from impactsense.twin_edge import EDGE_RAMPS_MM, edge_distance_mm, edge_term, fit_edge_term

PLATE = (320.0, 300.0)


def _drops(rng, bias, ramp_mm, n_pos=60, reps=5, scatter=0.01):
    """Drops at random positions (reps a position), residuals = bias * ramp at the position + per-position scatter
    + a little per-drop noise; returns (residual, xy, groups)."""
    pos = np.column_stack([rng.uniform(5, PLATE[0] - 5, n_pos), rng.uniform(5, PLATE[1] - 5, n_pos)])
    d = edge_distance_mm(pos, *PLATE)
    site = bias * np.clip(1 - d / ramp_mm, 0, None) + rng.normal(0, scatter, n_pos)
    g = np.repeat(np.arange(n_pos), reps)
    xy = pos[g] + rng.normal(0, 1.0, (g.size, 2))
    return site[g] + rng.normal(0, 0.003, g.size), xy, g


def test_edge_distance_is_to_the_nearest_of_four_edges():
    d = edge_distance_mm(np.array([[10.0, 150.0], [300.0, 150.0], [160.0, 295.0], [160.0, 150.0]]), *PLATE)
    np.testing.assert_allclose(d, [10.0, 20.0, 5.0, 150.0])


def test_a_known_edge_bias_is_recovered_and_pure_scatter_gives_no_term():
    rng = np.random.default_rng(0)
    r, xy, g = _drops(rng, -0.03, 60.0)
    fit = fit_edge_term(r, xy, g, *PLATE)
    assert fit["edge_ramp_mm"] in EDGE_RAMPS_MM and fit["edge_ramp_mm"] >= 45.0
    # b * ramp at 10 mm from an edge within 20 % of the truth's
    got = fit["edge_log10_bias"] * max(0.0, 1 - 10.0 / fit["edge_ramp_mm"])
    assert got == pytest.approx(-0.03 * (1 - 10.0 / 60.0), rel=0.2)
    kept = 0
    for seed in range(10):   # no bias: the 2-standard-error rule keeps a term in few draws (2 of 10 allowed)
        r0, xy0, g0 = _drops(np.random.default_rng(100 + seed), 0.0, 60.0)
        kept += fit_edge_term(r0, xy0, g0, *PLATE)["edge_log10_bias"] != 0.0
    assert kept <= 2


def test_few_positions_give_no_term_and_a_fit_without_one_subtracts_nothing():
    rng = np.random.default_rng(1)
    r, xy, g = _drops(rng, -0.05, 45.0, n_pos=5)
    assert fit_edge_term(r, xy, g, *PLATE)["edge_log10_bias"] == 0.0

    class Old:   # a card from before the term
        pass
    assert np.all(edge_term(Old(), xy, *PLATE) == 0.0)


def test_the_board_applies_the_hosts_edge_term():
    """impactapp::twin_edge_term through the binding's exported twin (a TwinSpec with the edge array) against
    twin_edge.edge_term at positions across the plate."""
    from impactsense import _link
    from impactsense.twin import TwinFit
    fit = TwinFit(offset=[0.0] * 16, slope=[1.0] * 16, weight=[1.0] * 16, ref_log10_height_mm=2.0,
                  edge_ramp_mm=45.0, edge_log10_bias=-0.04)
    xy = np.column_stack([np.linspace(0, PLATE[0], 41), np.linspace(PLATE[1], 0, 41)])
    want = edge_term(fit, xy, *PLATE)
    got = np.array([_link.twin_edge_term(float(x), float(y), fit.edge_log10_bias, fit.edge_ramp_mm, *PLATE)
                    for x, y in xy])
    np.testing.assert_allclose(got, want, atol=1e-6)
    assert (want < 0).any() and (want == 0).any()
