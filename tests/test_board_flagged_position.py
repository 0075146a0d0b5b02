"""The board follows the host's per-channel choice of a flagged drop's position (flagged_position.py): a board model
whose card keeps the four channels' position on a channel (channel_check["three_sensor_position"] false there;
`export` retrains with the rig's model's choice, board.models.retrain_for_board) reports, on a drop the check flags
on that channel, the forests' four-channel position with the three-channel class, as the host does; its clean
drops are reported exactly as without the choice."""

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

FOUR = 1   # the channel whose flagged drops keep the four channels' position


@pytest.fixture(scope="module")
def four_export(tmp_path_factory):
    """small_board_export with channel FOUR's choice the four channels; beside it the same tables without the
    choice (four_channel_mask 0: the three-sensor path on every channel, as before)."""
    d, out, summary, test = small_board_export(
        tmp_path_factory, three_sensor_position=[c != FOUR for c in range(4)])
    z = dict(np.load(out / "forest_tables.npz"))
    scores = z["check_scores"].copy()
    assert scores[5] == 1 << FOUR
    scores[5] = 0
    before = tmp_path_factory.mktemp("before")
    np.savez(before / "forest_tables.npz", **{**z, "check_scores": scores})
    return d, out, before, summary, test


def _xy(got, rows):
    return np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in rows])


def test_the_export_carries_the_choice(four_export):
    d, out, _, summary, _ = four_export
    card = json.loads((d / "model_card.json").read_text())
    assert card["channel_check"]["three_sensor_position"] == [c != FOUR for c in range(4)]
    assert summary["table_bytes"]["channel_check"] == 2 * 4 * 12 * 4 + 6 * 4
    assert summary["flagged_four_channels"] == [FOUR]
    body = (out / "impactsense_forest_tables.c").read_text().split("impactsense_check = {")[1].split("};")[0]
    assert body.rsplit(",", 1)[1].strip() == str(1 << FOUR)   # four_channel_mask, the struct's last field


def test_a_flagged_drop_on_a_four_channel_choice_keeps_the_four_channel_position(four_export):
    """Debonded channel FOUR: the board names it on exactly the drops the host's model flags, and there reports the
    host's position, the forests' four-channel one (0.05 mm: the wire's 0.1 mm steps) with the three-channel class;
    without the choice the same tables report the three-sensor position, away from it."""
    d, out, before, _, test = four_export
    session = inject_session(test, FaultSpec(debond=FOUR, debond_hz=4000, seed=3))
    models, signal = firmware_models(out)
    got = board_reports(session, models, signal)
    old = board_reports(session, firmware_models(before)[0], signal)
    caps, rows, sig = board_captures(session, 50000, signal)
    pred = ImpactModel.load(d).predict(featurize(caps, sig))
    board_bad = np.array([got[i]["left_out"] for i in rows])
    np.testing.assert_array_equal(board_bad, pred["bad_channel"])
    on = board_bad == FOUR
    assert on.mean() >= 0.9
    np.testing.assert_array_equal(pred["xy_mm"][on], pred["forest_xy_mm"][on])   # the host: the four channels
    np.testing.assert_allclose(_xy(got, rows)[on], pred["xy_mm"][on], atol=0.05 + 1e-3)
    board_cls = np.array([got[i]["energy_class"] for i in rows])
    assert np.mean(board_cls[on] == pred["energy_class"][on]) >= 0.95
    assert np.all(np.array([old[i]["left_out"] for i in rows]) == board_bad)
    moved = np.abs(_xy(old, rows)[on] - _xy(got, rows)[on]).max(1)
    assert np.mean(moved > 0.5) >= 0.8   # the three-sensor position is elsewhere


def test_clean_drops_are_reported_as_without_the_choice(four_export):
    d, out, before, _, test = four_export
    models, signal = firmware_models(out)
    got = board_reports(test, models, signal)
    old = board_reports(test, firmware_models(before)[0], signal)
    assert got == old and len(got) == len(test)
    assert all(r["left_out"] == -1 for r in got.values())


def test_the_budgeted_export_keeps_the_choice_only_where_a_four_channel_flagged_drop_fits():
    """`export --trees auto`: a drop flagged on a four-channel choice runs the three-sensor path's localiser and class
    and the forests; the choice goes to the board when that fits the event budget, else the mask is 0 (the
    three-sensor path on every channel) and export.json says why. The clean event's forests are not cut for it."""
    from types import SimpleNamespace

    from impactsense import export_check
    from impactsense.board.cost import EVENT_BUDGET, check_instructions
    from impactsense.signal import SignalConfig

    cfg = SignalConfig()
    three = {c: SimpleNamespace(terms=[0] * 14) for c in range(4)}
    flagged = check_instructions(cfg, 14)["flagged"]
    signal = 50000
    for forests, kept in ((EVENT_BUDGET - signal - flagged, True), (EVENT_BUDGET - signal - flagged + 1, False)):
        models = SimpleNamespace(channel_check={"scores": np.array([400, 300, 5, 3, 8, 1 << FOUR], np.float32)},
                                 three_channel=three, signal=cfg.to_dict(), four_channel_note=None)
        export_check.four_channel_within(models, {"total": signal}, forests)
        assert (export_check.mask_of(models.channel_check) == 1 << FOUR) == kept
        summary = export_check.four_channel_summary(models)["flagged_four_channels"]
        assert summary == [FOUR] if kept else "three-sensor path on every channel" in summary
