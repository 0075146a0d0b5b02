"""The board's model against the host's (board.gap): what the host's model uses that the board's does not run,
and both models' accuracy on the same drops, so that `impactsense export` never leaves a board several times
worse than the host unsaid."""

import numpy as np

from impactsense.board.cost import EVENT_BUDGET, signal_instructions
from impactsense.board.gap import TARGET_RATIO, band_pick_cost, board_lacks, compare
from impactsense.signal import SignalConfig

BOARD = {"fs_hz": 50000, "localiser_starts": 1, "band_pick_hz": 0.0, "band_velocity_mm_per_us": 0.0}


def host_card(band_hz: float, starts: int = 4) -> dict:
    return {"signal": {"fs_hz": 100000, "localiser_starts": starts, "band_pick_hz": band_hz,
                       "band_velocity_mm_per_us": 1.6, "band_window_us": 600.0, "dispersion_exponent": 0.4,
                       "posterior_grid": 15},
            "position_members": ["threshold", "band"], "forest": {"n_estimators": 100}}


def test_a_band_above_the_boards_nyquist_frequency_is_named_as_such():
    """The host's band picks at 34.5 kHz cannot be made from 4 x 50 kHz samples: no cost, the reason is the rate."""
    host = host_card(34500.0)
    assert band_pick_cost(host["signal"], BOARD) is None
    lacks = board_lacks(host, {"signal": BOARD}, board_trees=2)
    assert "Nyquist" in lacks[0] and "34.5 kHz" in lacks[0]
    assert any("position members" in x for x in lacks)
    assert any("4 on the host, 1 on the board" in x for x in lacks)
    assert any("dispersive" in x for x in lacks)
    assert any("posterior mean (15 x 15" in x for x in lacks)
    assert any("100 on the host, 2 on the board" in x for x in lacks)


def test_a_band_the_board_could_sample_is_named_with_its_cost():
    """At 11 kHz the board could demodulate the band: the cost is the demodulator's samples on four channels plus
    the band localiser's run (board.cost's rates), more than the event budget's room above the features."""
    host = host_card(11000.0)
    cost = band_pick_cost(host["signal"], BOARD)
    base = signal_instructions(SignalConfig.from_dict(BOARD))["total"]
    assert cost is not None and base + cost > EVENT_BUDGET
    assert f"~{cost:,} instructions" in board_lacks(host, {"signal": BOARD})[0]


def test_a_board_running_what_the_host_runs_lacks_nothing():
    card = {"signal": {**BOARD, "fs_hz": 50000}, "forest": {"n_estimators": 5}}
    assert board_lacks(card, card, board_trees=5) == []


def test_compare_scores_both_on_the_drops_both_place():
    rng = np.random.default_rng(0)
    truth = rng.uniform(0, 400, (40, 2))
    host = truth + rng.normal(0, 2.0, truth.shape)
    board = truth + rng.normal(0, 8.0, truth.shape)
    board[:5] = np.nan                      # five drops the board did not place
    out = compare(truth, host, board)
    assert out["scored"] == 35
    assert abs(out["host"]["mae_mm"] - np.abs(host[5:] - truth[5:]).mean()) < 1e-9
    assert 2.5 < out["ratio_mae"] < 6 and not out["within_target"]
    same = compare(truth, host, host)
    assert same["ratio_mae"] == 1.0 and same["within_target"] and TARGET_RATIO >= 1.0
    assert compare(truth, host, np.full_like(host, np.nan)) == {"scored": 0}


def test_export_prints_the_boards_expected_accuracy_beside_the_hosts(tmp_path, capsys):
    """`impactsense export` of a 100 kHz model: the board's model is trained again at 4 x 50 kHz; the printout and
    export.json give both models' MAE on the same held-out drops (the host's at the rig's rate, as
    ImpactModel.predict reports) and their ratio; a board worse than the target names what it lacks."""
    import json

    from impactsense.api import predict
    from impactsense.cli import main
    from impactsense.data import load_session, write_session
    from impactsense.models import ForestSettings, ImpactModel
    from impactsense.workflow import train

    s1 = load_session()
    sub = s1.subset(np.arange(0, len(s1), 2))
    data = write_session(tmp_path / "data", sub.rig, sub.xy_mm[:, 0], sub.xy_mm[:, 1], sub.height_mm, sub.adc,
                         case_id=sub.case_id, repetition=sub.repetition)
    session = load_session(data)
    model, split = train(session, None, 0.2, 0, settings=ForestSettings(n_estimators=5), site_map=None)
    model.save(tmp_path / "m100")
    assert main(["export", str(tmp_path / "m100"), "--out", str(tmp_path / "out"), "--no-m2cgen"]) == 0
    got = capsys.readouterr()
    acc = json.loads((tmp_path / "out" / "export.json").read_text())["board_held_out"]
    vs = acc["versus_host"]
    # the host's figure is the host model's own positions of those drops
    index = {int(r): k for k, r in enumerate(session.recording_id)}
    rows = np.asarray([index[int(r)] for r in split["test_recordings"]])
    host = np.asarray(predict(ImpactModel.load(tmp_path / "m100"), session.adc[rows])["xy_mm"], float)
    ok = np.isfinite(host).all(1)
    assert acc["reported"] == acc["n"] and vs["scored"] == ok.sum()     # every held-out drop placed by both
    assert abs(vs["host"]["mae_mm"] - np.abs(host[ok] - session.xy_mm[rows][ok]).mean()) < 1e-6
    assert abs(vs["ratio_mae"] - vs["board"]["mae_mm"] / vs["host"]["mae_mm"]) < 1e-9
    assert f"board MAE {vs['board']['mae_mm']:.2f} mm, host {vs['host']['mae_mm']:.2f} mm" in got.out
    if not vs["within_target"]:
        assert "WARNING" in got.err and acc["board_lacks"]


def test_the_boards_threshold_is_lowered_only_when_its_physics_is_clearly_better(monkeypatch):
    """choose_board_threshold: the carried threshold unless a lower one's training-drop physics MAE on the board's
    captures is below BOARD_THRESHOLD_GAIN x its own; a threshold that gives no onsets is skipped."""
    from types import SimpleNamespace

    import impactsense.board.models as bm

    truth = np.zeros((20, 2))
    board = SimpleNamespace(adc=np.zeros((20, 4, 8)), xy_mm=truth, rig=None)
    sig = SignalConfig.from_dict({"onset_threshold_counts": 100.0})

    def run(errors):
        def fit(board, rows, cfg, choose_threshold=False, fits=None):
            e = errors[round(float(cfg.onset_threshold_counts))]
            if e is None:
                raise ValueError("no onset")
            return cfg

        monkeypatch.setattr(bm, "fit_localiser", fit)
        monkeypatch.setattr(bm, "featurize", lambda adc, cfg: SimpleNamespace(
            phys_xy_mm=truth[:len(adc)] + errors[round(float(cfg.onset_threshold_counts))]))
        out, record = bm.choose_board_threshold(board, np.arange(20), sig)
        return float(out.onset_threshold_counts), record

    assert run({100: 10.0, 60: 9.8, 40: 9.9})[0] == 100.0          # 2 % better: not clearly
    thr, record = run({100: 10.0, 60: 8.0, 40: 9.0})
    assert thr == 60.0 and record["chosen"] == 0.6 and record["physics_mae_mm"] == [10.0, 8.0, 9.0]
    assert run({100: 10.0, 60: None, 40: 5.0})[0] == 40.0


def test_the_boards_acquisition_is_named_where_it_loses_drops_or_aliases():
    """A rig recorded faster than the board without a declared front end aliases on the board; a trigger that missed
    or took late more than TRIGGER_SHARE of the drops is named with its counts; neither where the board has both."""
    from impactsense.board.gap import TRIGGER_SHARE

    host = {"signal": BOARD, "rig": {"fs_hz": 96000.0}}
    fine = {"signal": BOARD, "board_fs_hz": 50000, "board_front_end": {"anti_alias_hz": 10000, "anti_alias_poles": 4},
            "board_trigger": {"threshold_counts": 158.4, "drops": 100, "captured": 100, "late": 0}}
    assert board_lacks(host, fine) == []
    aliasing = {**fine}
    aliasing.pop("board_front_end")
    assert any("anti-alias front end" in x and "25 kHz" in x for x in board_lacks(host, aliasing))
    late = {**fine, "board_trigger": {**fine["board_trigger"], "late": int(100 * TRIGGER_SHARE) + 1}}
    missed = {**fine, "board_trigger": {**fine["board_trigger"], "captured": 100 - int(100 * TRIGGER_SHARE) - 1}}
    for card in (late, missed):
        lacks = board_lacks(host, card)
        assert len(lacks) == 1 and "trigger" in lacks[0] and "158.4" in lacks[0]
    # a board that records itself (the rig's rate is the board's) needs no front end
    assert board_lacks({**host, "rig": {"fs_hz": 50000.0}}, aliasing) == []
