"""A four-channel board model (what `impactsense train` + `export` ship) carries, per channel, boosted shallow trees
correcting the three-sensor position of a drop without that channel (board.models.board_three_positions, kept
where the training drops say so out of fold). The firmware app (the emulated board, the exported tables) uses
channel c's pair only on a drop whose channel c is out (dead: no onset; debonded: the channel check's flag) and
reports what the host's model reports on the same captures."""

import numpy as np
import pytest
from conftest import small_board_export

from impactsense import _core
from impactsense.board.capture import board_captures
from impactsense.board.scores import board_reports
from impactsense.export import firmware_models
from impactsense.faults import FaultSpec, inject_session
from impactsense.models import ImpactModel
from impactsense.pipeline import FEATURE_NAMES, PAIRS, featurize
from impactsense.three_channel_position import three_channel_position_inputs

OUT = 2


@pytest.fixture(scope="module")
def four_channel_export(tmp_path_factory):
    """A four-channel board-rate model (half of session-1's drops, 5 trees, no twin), exported."""
    return small_board_export(tmp_path_factory)


def _xy(got, rows):
    return np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in rows]).reshape(-1, 2)


def test_the_inputs_read_nothing_of_the_channel_out():
    """impactcore three_position_inputs (the board's and the host's): the three-sensor position, the time
    differences among the other three channels, their log energies less the three's mean, their first peaks;
    the channel out's entries of the vector (NaN, or anything) change nothing."""
    rng = np.random.default_rng(0)
    v = rng.normal(size=(20, len(FEATURE_NAMES))).astype(np.float32)
    pos = rng.uniform(0, 300, size=(20, 2)).astype(np.float32)
    col = FEATURE_NAMES.index
    for c in range(4):
        got = three_channel_position_inputs(v, pos, c)
        others = [k for k in range(4) if k != c]
        e = v[:, [col(f"log_energy_rel_{k}") for k in others]]
        want = np.column_stack([pos, v[:, [col(f"dtoa_{i}{j}_us") for i, j in PAIRS if c not in (i, j)]],
                                e - e.mean(1, keepdims=True), v[:, [col(f"log_first_peak_{k}") for k in others]]])
        assert got.shape == (20, _core.THREE_POSITION_INPUTS)
        np.testing.assert_allclose(got, want, atol=1e-5)
        w = v.copy()
        w[:, [k for k, name in enumerate(FEATURE_NAMES) if name[-1] == str(c) or
              (name.startswith("dtoa_") and str(c) in name[5:7])]] = np.nan
        np.testing.assert_array_equal(three_channel_position_inputs(w, pos, c), got)


@pytest.mark.parametrize("fault", [FaultSpec(debond=OUT, debond_hz=4000, seed=1),
                                   FaultSpec(dead_channel=OUT, noise=1, seed=1)], ids=["debonded", "dead"])
def test_the_board_corrects_the_three_sensor_position_as_the_host(four_channel_export, fault):
    """With channel 2 debonded (flagged by the check) or dead, every held-out drop gets a report naming channel 2 at
    the host's position (0.05 mm: the wire's 0.1 mm steps): the pair moved it off the plain three-sensor position
    (the same tables without the pairs) and closer to the drops on average."""
    d, out, summary, test = four_channel_export
    assert summary["table_bytes"]["three_position"] > 0
    session = inject_session(test, fault)
    models, signal = firmware_models(out)
    got = board_reports(session, models, signal)
    plain = board_reports(session, firmware_models(out, three_position=False)[0], signal)
    caps, rows, sig = board_captures(session, 50000, signal)
    pred = ImpactModel.load(d).predict(featurize(caps, sig))
    named = np.array([got[i]["left_out"] == OUT for i in rows])
    assert named.mean() >= 0.9
    np.testing.assert_allclose(_xy(got, rows), pred["xy_mm"], atol=0.05 + 1e-3)
    moved = np.abs(_xy(got, rows[named]) - _xy(plain, rows[named])).max(1)
    assert np.mean(moved > 0.2) > 0.8
    truth = session.xy_mm[rows[named]]
    assert np.abs(_xy(got, rows[named]) - truth).mean() < np.abs(_xy(plain, rows[named]) - truth).mean()


def test_a_channels_pair_is_used_only_when_that_channel_is_out(four_channel_export):
    """Clean drops: the reports with the pairs are those without them, bit for bit (the four-channel forests).
    Channel 2 dead: without channel 2's pair (the other three's kept) the report is the plain three-sensor one; with
    channel 2's pair alone, the full export's."""
    d, out, _, test = four_channel_export
    models, signal = firmware_models(out)
    clean, clean_plain = (board_reports(test, m, signal) for m in (models, firmware_models(out, False)[0]))
    assert clean == clean_plain and all(r["left_out"] == -1 for r in clean.values())
    dead = inject_session(test, FaultSpec(dead_channel=OUT, noise=1, seed=1))
    rows = sorted(board_reports(dead, models, signal))
    full = _xy(board_reports(dead, models, signal), rows)
    others = _xy(board_reports(dead, firmware_models(out, [c for c in range(4) if c != OUT])[0], signal), rows)
    alone = _xy(board_reports(dead, firmware_models(out, [OUT])[0], signal), rows)
    plain = _xy(board_reports(dead, firmware_models(out, False)[0], signal), rows)
    np.testing.assert_array_equal(others, plain)
    np.testing.assert_array_equal(alone, full)
    assert np.abs(full - plain).max() > 0.2
