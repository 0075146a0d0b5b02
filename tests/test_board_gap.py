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
                       "band_velocity_mm_per_us": 1.6, "band_window_us": 600.0, "dispersion_exponent": 0.4},
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
