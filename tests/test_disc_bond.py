"""`calibrate --disc-bond fit`: the discs' bond (SimParams disc_stiffness_scale) from the band group delays."""

from pathlib import Path

import numpy as np
import pytest
from impactsense.calibration import disc_bond
from impactsense.errors import ConfigError


def test_disc_bond_option_validated():
    from impactsense.calibration.pipeline import CalibrateOptions
    with pytest.raises(ConfigError, match="--disc-bond must be 'off' or 'fit'"):
        CalibrateOptions(disc_bond="on").validate()
    with pytest.raises(ConfigError, match="--disc-bond fit .* needs the FEM"):
        CalibrateOptions(disc_bond="fit", fem=False).validate()
    CalibrateOptions(disc_bond="fit").validate()
    assert CalibrateOptions().disc_bond == "off"


def test_disc_bond_option_reaches_the_options_from_the_command_line():
    import argparse

    from impactsense.commands import calibrate
    sub = argparse.ArgumentParser().add_subparsers()
    calibrate.register(sub)
    args = sub.choices["calibrate"].parse_args(["bundled", "--out", "x.json"])
    assert args.disc_bond == "off"
    assert sub.choices["calibrate"].parse_args(["bundled", "--out", "x.json", "--disc-bond", "fit"]).disc_bond == "fit"


@pytest.mark.parametrize("s_true", [0.31, 0.51, 0.68])
def test_search_finds_a_skewed_minimum_in_few_evaluations(s_true):
    """A chi^2 curve as skewed as the rig's (steep towards a soft bond, shallow towards the bonded disc: 1174 /
    318 / 788 at 0.25 / 0.5 / 1): the coarse scan and the parabola steps end within 0.02 of its minimum after at
    most len(COARSE) + REFINE evaluations."""
    calls = []

    def chi2_dof(s):
        calls.append(s)
        return 300.0 + 9000.0 * (s - s_true) ** 2 / (0.3 + s)

    best, table = disc_bond.search(chi2_dof)
    assert abs(best - s_true) < 0.02, table
    assert len(calls) == len(set(calls)) <= len(disc_bond.COARSE) + disc_bond.REFINE
    assert all(disc_bond.BOUNDS[0] <= s <= disc_bond.BOUNDS[1] for s in calls)
    assert table[best] == min(table.values())


@pytest.mark.parametrize("slope, edge", [(-1.0, disc_bond.BOUNDS[1]), (1.0, disc_bond.BOUNDS[0])])
def test_search_stays_within_bounds_when_the_minimum_is_outside(slope, edge):
    """A monotone chi^2 (the best bond beyond the range): the search ends at the edge, never outside."""
    best, table = disc_bond.search(lambda s: 100.0 + slope * 50.0 * s)
    assert best == pytest.approx(edge, abs=0.05), table
    assert all(disc_bond.BOUNDS[0] <= s <= disc_bond.BOUNDS[1] for s in table)


def test_disc_bond_recovers_the_scale_that_made_the_drops_same_model(tmp_path):
    """Four cases the FEM made with discs at 0.4 of their bonded stiffness (off the coarse scan; 3 repetitions,
    rig noise, 1 mm position jitter; coarse mesh; ~20 s): the stage finds the scale within 0.03 (0.407 measured:
    the parabola steps' spacing and the position fit's noise), the twin at the fit explains the group delays to
    their noise (chi^2 / dof < 3; 1.05 measured) and the bonded disc does not (over 20x worse; 104x measured)."""
    from impactsense.calibration import fem
    from impactsense.data import load_session
    from test_calibrate import fem_calibration_drops

    rig = load_session(Path(__file__).resolve().parents[1] / "host/impactsense/data/session-1").rig
    # d31 -300 pC/N: the seed's -738 clips the ADC with the softer discs (the plate bends more under them)
    truth = dict(fem.base_params(rig, 4500.0, 0.36), damping_per_s=850.0, pzt_d31_pc_n=-300.0,
                 disc_stiffness_scale=0.4)
    # Eq. 35 with 20 us of tolerance: case 3's sensors 1 and 3 are near-equidistant, and the coarse mesh's picks
    # there are 10-20 us apart in two of three repetitions (the test is about the group delays, not the rule)
    drops = fem_calibration_drops(tmp_path, rig, truth, reps=3, tol_us=20.0)
    start = {k: v for k, v in truth.items() if k != disc_bond.FIELD}
    out = disc_bond.fit(drops, start)
    assert abs(out["scale"] - 0.4) < 0.03, out["chi2_dof"]
    assert out["chi2_dof_fit"] < 3.0, out["chi2_dof"]
    assert out["chi2_dof_bonded"] > 20 * out["chi2_dof_fit"], out["chi2_dof"]
    assert np.isfinite(out["chi2_dof_fit"]) and out["seconds"] > 0
