"""retrain's choice for a bond (bond_choice.choose_left_out): the model that places DATA_NEW's labelled drops
better is kept, and the rule's cross-fitted MAE (each half of the cases placed by the model the other half chose)
is no better than the better model where one is better everywhere, and worse where each wins on its own half."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from impactsense.bond_choice import choose_left_out


class FixedOffsetModel:
    """A model whose position is the declared one plus a per-case offset (mm)."""

    def __init__(self, offset_by_case: np.ndarray, session):
        self.offset = offset_by_case[session.case_id]
        self.session = session

    def featurize(self, adc):
        return adc

    def predict(self, features):
        return {"xy_mm": self.session.xy_mm + self.offset[:, None]}


def offset_session(seed: int, cases: int = 20):
    """A labelled session of `cases` cases x 3 drops at random positions (the stand-in models ignore the adc)."""
    rng = np.random.default_rng(seed)
    case = np.repeat(np.arange(cases), 3)
    return SimpleNamespace(case_id=case, adc=np.zeros((case.size, 4, 8)), xy_mm=rng.uniform(0, 300, (case.size, 2)))


@pytest.fixture
def session():
    return offset_session(3)


def test_the_better_model_is_kept_and_its_cross_fitted_mae_is_its_own(session):
    four = FixedOffsetModel(np.full(20, 3.0), session)
    left = FixedOffsetModel(np.full(20, 2.0), session)
    got = choose_left_out(four, left, session, channel=2, seed=0)
    assert got["chosen"] == "left_out" and got["channel"] == 2
    assert got["four_mae_mm"] == pytest.approx(3.0) and got["left_out_mae_mm"] == pytest.approx(2.0)
    assert got["cross_fitted_mae_mm"] == pytest.approx(2.0)
    assert choose_left_out(left, four, session, channel=2)["chosen"] == "four"


def test_a_choice_that_does_not_carry_over_between_halves_costs_in_the_cross_fitted_figure(session):
    # each model is the better one on a different half of the cases: whichever half chooses, the other loses
    cases = np.random.default_rng(0).permutation(np.unique(session.case_id))
    first = np.isin(np.arange(20), cases[:10])
    four = FixedOffsetModel(np.where(first, 1.0, 4.0), session)
    left = FixedOffsetModel(np.where(first, 4.0, 1.5), session)
    got = choose_left_out(four, left, session, channel=0, seed=0)
    assert min(got["four_mae_mm"], got["left_out_mae_mm"]) < 2.8
    assert got["cross_fitted_mae_mm"] == pytest.approx(4.0)


def test_the_reference_model_is_a_third_candidate_by_the_same_rule(session):
    four = FixedOffsetModel(np.full(20, 3.0), session)
    left = FixedOffsetModel(np.full(20, 2.5), session)
    reference = FixedOffsetModel(np.full(20, 2.0), session)
    got = choose_left_out(four, left, session, channel=1, seed=0, reference_model=reference)
    assert got["chosen"] == "reference" and got["reference_mae_mm"] == pytest.approx(2.0)
    assert got["cross_fitted_mae_mm"] == pytest.approx(2.0)
    # a worse reference is not kept; without one the choice is the two retrained models' as before
    worse = FixedOffsetModel(np.full(20, 3.5), session)
    assert choose_left_out(four, left, session, channel=1, reference_model=worse)["chosen"] == "left_out"
    assert "reference_mae_mm" not in choose_left_out(four, left, session, channel=1)


def test_fit_with_bond_choice_returns_the_reference_model_when_it_places_best(session):
    from impactsense.bond_choice import fit_with_bond_choice
    from impactsense.signal import SignalConfig

    signal = SignalConfig()
    lowpass = SimpleNamespace(effect="channel_lowpass", sensor=2, params={})
    offsets = {0: 3.0, 1: 2.5}   # four channels, channel 2 left out

    def fit(cfg):
        return FixedOffsetModel(np.full(20, offsets[cfg.channel_left_out[2]]), session), "split"

    reference = (FixedOffsetModel(np.full(20, 1.0), session), "reference split")
    kept, choice = fit_with_bond_choice(fit, signal, session, [lowpass], reference=reference)
    assert kept is reference and choice["chosen"] == "reference" and choice["channel"] == 2
    kept, choice = fit_with_bond_choice(fit, signal, session, [lowpass])
    assert choice["chosen"] == "left_out" and kept[0].offset[0] == pytest.approx(2.5)


def test_retrain_says_the_reference_model_was_kept_and_why(capsys):
    from impactsense.commands.retrain import note_bond_choice, print_summary

    choice = {"channel": 1, "chosen": "reference", "four_mae_mm": 2.67, "left_out_mae_mm": 3.13,
              "reference_mae_mm": 2.35, "cross_fitted_mae_mm": 2.40}
    card = {"retrain": {"channels_left_out": []}}
    assert note_bond_choice(card, choice, []) == []   # the reference model flags the channel itself
    assert card["retrain"]["model_kept"] == "reference"
    why = card["retrain"]["model_kept_why"]
    assert "2.35" in why and "2.67" in why and "3.13" in why and "channel 1" in why
    print_summary({}, [], {}, "DATA_NEW", False, "OUT", choice)
    printed = capsys.readouterr().out
    assert "REFERENCE MODEL IS KEPT" in printed and why in printed
    card = {"retrain": {"channels_left_out": []}}
    assert note_bond_choice(card, {**choice, "chosen": "left_out"}, []) == [1] and "model_kept" not in card["retrain"]


def test_retrain_prints_a_dash_where_the_model_reports_no_uncertainty(capsys):
    """Every drop placed by three sensors has no reported uncertainty: the 'within 1u / 2u' shares are undefined,
    printed '-' with the reason, not 'nan'; a model that reports one prints its shares."""
    from impactsense.commands.retrain import print_summary

    row = {"mae_mm": 12.58, "inner_mae_mm": 9.1, "physics_mae_mm": 14.0, "energy_class_accuracy": 0.92}
    rows = {"reference model": {**row, "within_1u": float("nan"), "within_2u": float("nan")},
            "retrained model": {**row, "within_1u": 0.41, "within_2u": 0.87}}
    print_summary({}, [], rows, "DATA_NEW", False, "OUT")
    printed = capsys.readouterr().out
    assert "nan" not in printed
    ref_line = next(line for line in printed.splitlines() if line.startswith("reference model"))
    new_line = next(line for line in printed.splitlines() if line.startswith("retrained model"))
    assert ref_line.split()[-2:] == ["-", "-"] and new_line.split()[-2:] == ["0.41", "0.87"]
    assert "reports no uncertainty" in printed
