"""retrain's choice between the retrained model and the reference model (model_choice): the reference model is kept
only when it places DATA_NEW's labelled drops better overall and on each half of its cases; a lead that turns on one
case keeps the retrained model; the choice and why are in the card."""

from __future__ import annotations

import numpy as np
import pytest

from impactsense.model_choice import choose_model, keep_retrained_or_reference

from test_bond_choice import FixedOffsetModel, offset_session  # the same stand-in model and session

CASES = 20


@pytest.fixture
def session():
    return offset_session(5, CASES)


def test_the_lowest_mae_is_chosen_and_a_missing_candidate_is_skipped(session):
    a = FixedOffsetModel(np.full(CASES, 3.0), session)
    b = FixedOffsetModel(np.full(CASES, 1.5), session)
    got = choose_model({"a": a, "b": b, "c": None}, session)
    assert got["chosen"] == "b" and set(got["mae_mm"]) == {"a", "b"}
    assert got["mae_mm"]["b"] == pytest.approx(1.5) and got["cross_fitted_mae_mm"] == pytest.approx(1.5)
    with pytest.raises(ValueError):
        choose_model({"a": None}, session)


def test_a_reference_better_on_every_case_is_kept(session):
    retrained = FixedOffsetModel(np.full(CASES, 4.0), session)
    reference = FixedOffsetModel(np.full(CASES, 3.0), session)
    got = keep_retrained_or_reference(retrained, reference, session, seed=1)
    assert got["chosen"] == "reference"
    assert got["reference_mae_mm"] == pytest.approx(3.0) and got["retrained_mae_mm"] == pytest.approx(4.0)


def test_a_reference_lead_that_turns_on_one_case_keeps_the_retrained_model(session):
    """The reference model is better overall only by one case the retrained model places 20 mm off; on every other
    case it is 0.2 mm worse, so on the half of the cases without that one the retrained model is the better."""
    bad = np.full(CASES, 2.0)
    bad[7] = 20.0
    retrained = FixedOffsetModel(bad, session)
    good = np.full(CASES, 2.2)
    good[7] = 0.0
    reference = FixedOffsetModel(good, session)
    assert choose_model({"retrained": retrained, "reference": reference}, session)["chosen"] == "reference"
    for seed in range(4):
        assert keep_retrained_or_reference(retrained, reference, session, seed)["chosen"] == "retrained"


def test_retrain_writes_the_reference_model_and_says_why(session):
    from impactsense.commands.retrain import keep_better

    retrained = FixedOffsetModel(np.full(CASES, 4.0), session)
    reference = FixedOffsetModel(np.full(CASES, 3.0), session)
    card = {"retrain": {}}
    model, split = keep_better(card, retrained, {"s": "retrained"}, reference, {"s": "reference"}, session, 0)
    assert model is reference and split == {"s": "reference"}
    assert card["retrain"]["model_kept"] == "reference" and card["retrain"]["model_choice"]["chosen"] == "reference"
    assert "3.00" in card["retrain"]["model_kept_why"] and "4.00" in card["retrain"]["model_kept_why"]
    assert "+1.00 mm, SE 0.00" in card["retrain"]["model_kept_why"]   # the steady 1 mm lead, no scatter
    card = {"retrain": {}}
    model, _ = keep_better(card, reference, {}, retrained, {}, session, 0)   # the retrained one now the better
    assert model is reference and "model_kept" not in card["retrain"]
    assert card["retrain"]["model_choice"]["chosen"] == "retrained"


def test_the_paired_lead_and_its_standard_error_over_the_cases(session):
    """The reference's lead is the mean per-case difference of the two models' MAE and its standard error the
    scatter of that difference over the cases: a steady 1 mm lead has none; a lead of +1 / -0.5 mm on alternate
    cases is 0.25 mm with the sample SE of the differences; the choice's record carries both."""
    from impactsense.model_choice import drop_errors, paired_lead

    steady = keep_retrained_or_reference(FixedOffsetModel(np.full(CASES, 4.0), session),
                                         FixedOffsetModel(np.full(CASES, 3.0), session), session, seed=1)
    assert steady["reference_lead_mm"] == pytest.approx(1.0) and steady["reference_lead_se_mm"] == pytest.approx(0.0)
    ref_off = np.where(np.arange(CASES) % 2 == 0, 2.0, 3.5)   # the reference 1 mm better, then 0.5 mm worse
    retrained = FixedOffsetModel(np.full(CASES, 3.0), session)
    reference = FixedOffsetModel(ref_off, session)
    lead = paired_lead(drop_errors(retrained, session), drop_errors(reference, session), session.case_id)
    d = np.where(np.arange(CASES) % 2 == 0, 1.0, -0.5)
    assert lead["cases"] == CASES and lead["lead_mm"] == pytest.approx(0.25)
    assert lead["lead_se_mm"] == pytest.approx(np.std(d, ddof=1) / np.sqrt(CASES))
    got = keep_retrained_or_reference(retrained, reference, session, seed=1)
    assert got["reference_lead_mm"] == pytest.approx(0.25)
    assert got["reference_lead_se_mm"] == pytest.approx(lead["lead_se_mm"])
