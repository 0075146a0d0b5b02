"""The channel check on the board (impactcore's channel_check_scores / channel_check_flag, impactapp's App and
TableModels): `export` writes a board model's check (its cubics read at the four-channel physics position) into the
generated C and forest_tables.npz, and the firmware app (the emulated board) flags a debonded channel and reports the
three-sensor answer on the drops the host's model flags on the same captures, at the host's position and class."""

import json

import numpy as np
import pytest
from conftest import small_board_export

from impactsense.board.capture import board_captures
from impactsense.board.scores import board_reports
from impactsense.export import firmware_models
from impactsense.faults import FaultSpec, inject_session
from impactsense.models import ImpactModel
from impactsense.pipeline import featurize

DEBONDED = 1


@pytest.fixture(scope="module")
def check_export(tmp_path_factory):
    """A board-rate model without a twin (half of session-1's drops, 5 trees), exported; its held-out drops."""
    return small_board_export(tmp_path_factory)


def board_and_host(model_dir, out, session):
    models, signal = firmware_models(out)
    got = board_reports(session, models, signal)
    caps, rows, sig = board_captures(session, 50000, signal)
    return got, rows, ImpactModel.load(model_dir).predict(featurize(caps, sig))


def test_the_export_carries_the_check(check_export):
    d, out, summary, _ = check_export
    card = json.loads((d / "model_card.json").read_text())
    assert card["channel_check"]["version"] == 2
    assert summary["table_bytes"]["channel_check"] == 2 * 4 * 12 * 4 + 6 * 4
    assert "#define IMPACTSENSE_CHANNEL_CHECK 1" in (out / "impactsense_models.h").read_text()
    assert "impactsense_check = {" in (out / "impactsense_forest_tables.c").read_text()


def test_the_board_flags_a_debonded_channel_as_the_host_does(check_export):
    """Debonded channel 1 (x0.4, 4 kHz): the board names it on >= 95 % of the drops and on exactly the drops the
    host's model flags, at the host's three-sensor position (0.05 mm: the wire's 0.1 mm steps) with its class."""
    d, out, _, test = check_export
    session = inject_session(test, FaultSpec(debond=DEBONDED, debond_hz=4000, seed=3))
    got, rows, pred = board_and_host(d, out, session)
    assert len(got) == len(rows) == len(test)
    board_bad = np.array([got[i]["left_out"] for i in rows])
    np.testing.assert_array_equal(board_bad, pred["bad_channel"])
    assert np.mean(board_bad == DEBONDED) >= 0.95 and np.all(board_bad[board_bad >= 0] == DEBONDED)
    on = board_bad == DEBONDED
    board_xy = np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in rows])
    np.testing.assert_allclose(board_xy[on], pred["xy_mm"][on], atol=0.05 + 1e-3)
    board_cls = np.array([got[i]["energy_class"] for i in rows])
    assert np.mean(board_cls[on] == pred["energy_class"][on]) >= 0.95


def test_a_flagged_drops_three_sensor_run_is_capped_and_places_it_as_well(check_export):
    """A flagged drop's three-sensor position is the localiser without the channel at most FLAGGED_EVALUATIONS
    evaluations a run (impactcore three_sensor_position; the host's flag_events the same): on the debonded drops the
    board and the host report that position (corrected by the channel's pair, when the model keeps one:
    board.models.board_three_positions), and it places them as well as the uncapped run (mean error within
    0.5 mm of it or better; the capped run stops on the drops whose refinement creeps along a flat valley)."""
    from impactsense import _core
    from impactsense.edge_travel import three_sensor_positions
    from impactsense.three_channel_position import corrected_positions

    d, out, _, test = check_export
    session = inject_session(test, FaultSpec(debond=DEBONDED, debond_hz=4000, seed=3))
    got, rows, pred = board_and_host(d, out, session)
    on = pred["bad_channel"] == DEBONDED
    caps, _, sig = board_captures(session, 50000, firmware_models(out)[1])
    feats = featurize(caps, sig)
    capped = three_sensor_positions(feats.raw, sig, DEBONDED, max_evaluations=_core.FLAGGED_EVALUATIONS)
    free = three_sensor_positions(feats.raw, sig, DEBONDED)
    served = capped.copy()
    corrected_positions(ImpactModel.load(d).three_channel_position, feats.vector, np.flatnonzero(on),
                        np.full(on.sum(), DEBONDED), served)
    np.testing.assert_allclose(pred["xy_mm"][on], served[on])
    board_xy = np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in rows])
    np.testing.assert_allclose(board_xy[on], served[on], atol=0.05 + 1e-3)
    truth = session.xy_mm[rows][on]
    err_capped = np.linalg.norm(capped[on] - truth, axis=1).mean()
    err_free = np.linalg.norm(free[on] - truth, axis=1).mean()
    assert err_capped <= err_free + 0.5


def test_the_board_flags_no_channel_of_clean_drops(check_export):
    d, out, _, test = check_export
    got, rows, pred = board_and_host(d, out, test)
    assert len(got) == len(test)
    assert all(got[i]["left_out"] == -1 for i in rows) and np.all(pred["bad_channel"] == -1)


def test_the_budgeted_export_keeps_the_check_only_where_a_flagged_event_fits():
    """`export --trees auto`: the check takes its share from the forests' when an event it flags (a localiser run
    without the channel and the three-channel class) fits the event budget with it; otherwise the board does not get
    it and the export says why (board.cost's bound: a rig whose features and localiser leave ~4k does not fit)."""
    from types import SimpleNamespace

    from impactsense import export_check
    from impactsense.board.cost import CHECK_INSTRUCTIONS, EVENT_BUDGET, check_instructions
    from impactsense.signal import SignalConfig

    cfg = SignalConfig()
    three = {c: SimpleNamespace(terms=[0] * 14) for c in range(4)}
    flagged = check_instructions(cfg, 14)["flagged"]
    for total, kept in ((EVENT_BUDGET - CHECK_INSTRUCTIONS - flagged, True),
                        (EVENT_BUDGET - CHECK_INSTRUCTIONS - flagged + 1, False)):
        models = SimpleNamespace(channel_check={"level": 1}, three_channel=three, signal=cfg.to_dict(), check_note=None)
        taken = export_check.budgeted(models, {"total": total}, EVENT_BUDGET)
        assert (taken == CHECK_INSTRUCTIONS) == kept and (models.channel_check is not None) == kept
        assert (models.check_note is None) == kept
