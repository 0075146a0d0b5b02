"""The twin's pick-velocity curve read backwards (plate_scan): the crossing of a curve that is flat for the first
steps and steep after (as rig-b's picks are) is the steep part's, not a single exponent's; size_plate_change carries the readings into the wave_speed effect
and passes other effects through."""

from __future__ import annotations

import numpy as np
import pytest

from impactsense import plate_scan
from impactsense.diagnose import Candidate, _param_ci, _param_se


def _kinked(n=0.4, flat=0.02):
    """ln s(ln E) of a pick that ignores the first `flat` of E and then goes as E^-n (a 0.02 grid)."""
    scales = 1.0 - 0.02 * np.arange(8)
    le = np.log(scales)
    return le, -n * np.minimum(le - np.log(1 - flat), 0.0)


def test_the_crossing_reads_the_curve_where_the_target_meets_it():
    le, ls = _kinked()
    for e_true in (0.95, 0.91, 0.89):
        target = -0.4 * (np.log(e_true) - np.log(0.98))
        got, slope = plate_scan.crossing(le, ls, target)
        assert np.exp(got) == pytest.approx(e_true, abs=1e-3)
        assert slope == pytest.approx(-0.4, abs=0.05)
    # a single exponent from E to the first grid point would read a 10x larger E change (it sees the flat part)
    n_first = -(ls[1] - ls[0]) / (le[1] - le[0])
    assert n_first < 0.05


def test_size_plate_change_carries_the_readings_and_passes_other_effects(monkeypatch):
    folds = [{"change_pct": -4.0 + d, "velocity_m_s": 800.0} for d in (-0.3, -0.1, 0.0, 0.1, 0.3)]
    cand = Candidate("wave_speed", None, {"change_pct": -4.0, "velocity_m_s": 800.0}, 50.0, 1e-6, True, True, folds)
    seen = {}

    def scan(params, data, picker, change, base, ci, seed, workers):
        seen.update(change=change, ci=ci, base=base)
        return {"e_scale": 0.91, "readings": {"change": 0.90, "pick": 0.92, "band": 0.905}, "exponent": 0.4,
                "first_guess": 0.88, "e_scale_lo": 0.87, "e_scale_hi": 0.95, "curve": []}

    monkeypatch.setattr(plate_scan, "e_scale_scan", scan)
    (out,) = plate_scan.size_plate_change(None, None, [cand], None, base="REF")
    assert seen["change"] == -4.0 and seen["base"] == "REF"
    assert seen["ci"] == pytest.approx(_param_ci(cand, _param_se(cand))["change_pct"])
    p = out.params
    assert (p["e_scale"], p["e_scale_change"], p["e_scale_pick"], p["e_scale_band"], p["e_exponent"],
            p["e_scale_curve"]) == (0.91, 0.90, 0.92, 0.905, 0.4, 0.88)
    assert p["e_scale_lo"] < p["e_scale"] < p["e_scale_hi"]
    other = Candidate("channel_delay", 1, {"delay_us": 5.0}, 5.0, 0.01, True, True, [])
    assert plate_scan.size_plate_change(None, None, [other], None)[0] is other


def test_a_damping_change_is_sized_by_the_twin_decay_curve_and_read_by_the_corrected_twin(monkeypatch):
    """size_plate_change puts the twin's decay-curve reading into a damping candidate (damping_scale), and
    corrected_twin scales D_s by it rather than adding twice the extra decay."""
    import dataclasses

    from impactsense.loop import corrected_twin
    from impactsense.data import load_session
    from impactsense.sim import SimParams

    cand = Candidate("damping", None, {"extra_decay_per_s": 40.0, "change_pct": 8.0}, 20.0, 1e-6, True, True, [])
    monkeypatch.setattr(plate_scan, "damping_scale_scan",
                        lambda *a, **k: {"damping_scale": 1.19, "readings": {"change": 1.18, "same_drops": 1.19}})
    (out,) = plate_scan.size_plate_change(None, None, [cand], None, base="REF")
    assert out.params["damping_scale"] == 1.19 and out.params["damping_scale_change"] == 1.18
    rig = load_session("bundled:session-1").rig
    p = dataclasses.replace(SimParams.from_rig(rig), damping_per_s=400.0)
    eff = [{"effect": "damping", "sensor": None, "params": out.params}]
    assert corrected_twin(p, rig, eff)[0].damping_per_s == pytest.approx(476.0)
    eff[0]["params"] = {"extra_decay_per_s": 40.0}
    assert corrected_twin(p, rig, eff)[0].damping_per_s == pytest.approx(480.0)   # without the curve: 2 x 40


class _Drops:
    """A stand-in session: per drop, each statistic's ln slowness (the statistic of a set: exp of their mean)."""

    def __init__(self, case_id, value):
        self.case_id, self.value = np.asarray(case_id), value

    def subset(self, rows):
        return _Drops(self.case_id[rows], {k: v[rows] for k, v in self.value.items()})


def _stats(session):
    return {k: float(np.exp(np.mean(v))) for k, v in session.value.items()}


LN_S0 = {"pick": np.log(0.60), "band": np.log(0.81)}
SLOPE = {"pick": -0.3, "band": -0.3}          # d ln s / d ln E, the same for both statistics
ROW_SD = 1e-3                                 # each drop's pick noise (ln s), the same for both statistics


def _drops(cases, reps, e_scale, position_sd, seed):
    """`cases` positions x `reps` drops at E x e_scale; each case's statistic off the twin's by its own landing
    term (sd position_sd[statistic]), each drop by the noise."""
    rng = np.random.default_rng(seed)
    case = np.repeat(np.arange(cases), reps)
    return _Drops(case, {k: LN_S0[k] + SLOPE[k] * np.log(e_scale) + rng.normal(0, position_sd[k], cases)[case]
                         + rng.normal(0, ROW_SD, case.size) for k in LN_S0})


def _twins(params, session, e_scale, draws=6, seed=0, workers=2):
    """The stand-in twin: the declared positions (no landing term), its own noise per draw."""
    n = session.case_id.size
    return [_Drops(session.case_id, {k: LN_S0[k] + SLOPE[k] * np.log(e_scale)
                                     + np.random.default_rng([seed, draw, n, i]).normal(0, ROW_SD, n)
                                     for i, k in enumerate(LN_S0)})
            for draw in range(draws)]


def test_position_set_sd_scales_the_halves_to_a_readings_two_position_sets():
    """The halves' miss difference beyond the twin's own noise draws', scaled to 40 new cases against 80
    reference cases, is the sd of a reading's landing term: sqrt(v (1/40 + 1/80)) for a per-case variance v; the
    data's noise (the twin's too) is not in it; a reference the twin reproduces but for noise has none."""
    pos = {"pick": 0.02, "band": 0.0}
    base = _drops(80, 3, 1.0, pos, 1)
    got = plate_scan.position_set_sd(base, _twins(None, base, 1.0), _stats, new_cases=40, splits=40)
    assert got["pick"] == pytest.approx(0.02 * np.sqrt(1 / 40 + 1 / 80), rel=0.3), got
    noise_only = ROW_SD / np.sqrt(3) * np.sqrt(1 / 40 + 1 / 80)     # what the halves alone would read for band
    assert got["band"] < 0.5 * noise_only, got
    few = base.subset(np.arange(39 * 3))                             # 39 cases: too few to split
    assert plate_scan.position_set_sd(few, _twins(None, few, 1.0), _stats, 40) == {}


def test_a_reading_with_a_large_position_set_term_weighs_less(monkeypatch):
    """Two readings of E on the same drops, the twin's noise the same on both (so the twin's draw scatter weighs
    them alike), but the threshold picks' statistic moves by 0.03 per landing position and the band's by 0.001:
    the scan's answer sits by the band reading, and the interval widens to the band reading's sd (the pick's
    position-set error alone, ~2 % of E here, is what a draw-scatter weight would average in by half)."""
    import impactsense.loop as loop

    pos = {"pick": 0.03, "band": 0.001}
    monkeypatch.setattr(plate_scan, "Statistics", lambda base, picker: _stats)
    monkeypatch.setattr(plate_scan, "twin_sessions", _twins)
    monkeypatch.setattr(loop, "e_scale_for_speed", lambda *a: 1.0)
    truth = 0.92
    ref, new = _drops(80, 3, 1.0, pos, 2), _drops(40, 3, truth, pos, 3)
    change = 100.0 * (_stats(ref)["pick"] / _stats(new)["pick"] - 1.0)
    scan = plate_scan.e_scale_scan(None, new, None, change, base=ref, seed=5)
    pick, band = scan["readings"]["pick"], scan["readings"]["band"]
    assert abs(np.log(pick / truth)) > 0.005 > abs(np.log(band / truth)), scan["readings"]   # the draw's setup
    terms = scan["sd_terms"]
    assert terms["pick"]["draws"] == pytest.approx(terms["band"]["draws"], rel=0.5)   # the old weights: alike
    assert scan["reading_sd"]["pick"] > 4 * scan["reading_sd"]["band"]
    # the answer moves to the band reading: within a tenth of the way to the pick's (the old weights: ~half)
    assert abs(np.log(scan["e_scale"] / band)) < 0.1 * abs(np.log(pick / band)), scan
    assert scan["e_scale"] == pytest.approx(truth, abs=0.003)
    assert scan["e_scale_lo"] < truth < scan["e_scale_hi"]
