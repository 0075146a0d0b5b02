"""A model that leaves a channel out (`impactsense retrain`'s answer to a change the models cannot absorb: the
core's channel_left_out) on the board: `export` keeps the channel left out in the board's models, the board's
core gets it through the generated signal settings, and the firmware app (the emulated board, the exported
tables) reports what the host's model reports on the same captures: the board's forests, trained with the channel
left out (they read none of its arrival times), correcting the three-sensor position, the class from the other
three channels' energies (the three-channel classes, exported per channel), the channel named in the report."""

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import exported_twin_match, small_board_export

from impactsense.board.capture import board_captures, board_samples
from impactsense.board.scores import board_reports
from impactsense.data import load_session, write_session
from impactsense.export import firmware_models
from impactsense.faults import FaultSpec, inject_session
from impactsense.height_class import three_channel_inputs
from impactsense.models import ForestSettings, ImpactModel, impact_energy_j
from impactsense.pipeline import featurize

ROOT = Path(__file__).resolve().parents[1]
LEFT_OUT = 2


@pytest.fixture(scope="module")
def left_out_export(tmp_path_factory):
    """A board-rate model (half of session-1's drops, 5 trees, no twin) leaving channel 2 out, exported."""
    return small_board_export(tmp_path_factory, channel_left_out=[int(c == LEFT_OUT) for c in range(4)])


def host_and_board(model_dir, out, session):
    """(board reports by row, the rows the board captured, the host model's prediction on those captures, their
    features)."""
    models, signal = firmware_models(out)
    got = board_reports(session, models, signal)
    caps, rows, sig = board_captures(session, 50000, signal)
    f = featurize(caps, sig)
    return got, rows, ImpactModel.load(model_dir).predict(f), f


@pytest.mark.parametrize("fault", [FaultSpec(debond=LEFT_OUT, debond_hz=4000, seed=1),
                                   FaultSpec(dead_channel=LEFT_OUT, noise=1, seed=1)], ids=["debonded", "dead"])
def test_the_board_reports_the_hosts_three_sensor_answers(left_out_export, fault):
    """Every drop of a session with the left-out channel debonded (or dead) gets a valid report naming channel 2,
    at the host's position (0.05 mm: the wire's 0.1 mm steps: the forests trained without the channel's arrival
    times on the three-sensor position, closer to the drops than that position) and with the host's class (float32
    on both sides: the same core computes the three-channel inputs; the class may differ only where the host's
    score is within float32 rounding of the boundary)."""
    d, out, summary, test = left_out_export
    assert summary["table_bytes"]["three_channel"] > 0
    session = inject_session(test, fault)
    got, rows, pred, f = host_and_board(d, out, session)
    assert len(got) == len(test) and len(rows) == len(test)
    assert all(got[i]["left_out"] == LEFT_OUT and got[i]["dead"] & (1 << LEFT_OUT) for i in rows)
    assert not pred["three_channel"].any() and np.all(f.no_onset[:, LEFT_OUT])   # the forests' rows
    board_xy = np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in rows])
    np.testing.assert_allclose(board_xy, pred["xy_mm"], atol=0.05 + 1e-3)
    # the forests ran (a four-channel model's would not: its inputs read the channel's arrival times) and their
    # correction places the drops better than the physics three-sensor position they start from
    truth = session.xy_mm[rows]
    assert np.abs(pred["xy_mm"] - f.phys_xy_mm).max() > 0.5
    assert np.abs(pred["xy_mm"] - truth).mean() < np.abs(f.phys_xy_mm - truth).mean()
    board_cls = np.array([got[i]["energy_class"] for i in rows])
    model = ImpactModel.load(d)
    score = model.three_channel_class[LEFT_OUT].score(three_channel_inputs(f.raw, f.phys_xy_mm, LEFT_OUT))
    decided = np.abs(score) > 1e-4
    assert decided.mean() > 0.9
    np.testing.assert_array_equal(board_cls[decided], pred["energy_class"][decided])
    # the class is the drops' (a third of the drops are high: a constant class would score <= ~0.75)
    label = impact_energy_j(session.height_mm[rows], session.rig.ball_mass_g) >= model.energy_threshold_j
    assert np.mean(board_cls == label) > 0.8


def test_without_the_channel_left_out_the_same_tables_report_four_channel_answers(left_out_export):
    """The control: the same tables with the card's channel_left_out cleared run the forests on the clean drops
    (no channel named), so the flag above is the left-out channel's, not the tables'."""
    d, out, _, test = left_out_export
    models, signal = firmware_models(out)
    got = board_reports(test, models, {**signal, "channel_left_out": [0, 0, 0, 0]})
    assert len(got) >= 0.95 * len(test)
    assert all(r["left_out"] == -1 for r in got.values())


def test_export_of_a_retrained_model_keeps_the_channel_left_out(tmp_path, capsys):
    """`impactsense export` of a 100 kHz model with channel_left_out set (as `impactsense retrain` writes it):
    the board's models, trained again on the captures, keep it (card signal) with the three-channel classes;
    every held-out drop gets a report on the emulated board; the printout says the board leaves it out."""
    from impactsense.cli import main
    from impactsense.commands.retrain import leave_out
    from impactsense.workflow import train

    s1 = load_session()
    sub = s1.subset(np.arange(0, len(s1), 2))
    data = write_session(tmp_path / "data", sub.rig, sub.xy_mm[:, 0], sub.xy_mm[:, 1], sub.height_mm, sub.adc,
                         case_id=sub.case_id, repetition=sub.repetition)
    model, split = train(load_session(data), None, 0.2, 0, settings=ForestSettings(n_estimators=5), site_map=None)
    model.signal = leave_out(model.signal, [LEFT_OUT])
    model.save(tmp_path / "m100")
    assert main(["export", str(tmp_path / "m100"), "--out", str(tmp_path / "out"), "--no-m2cgen"]) == 0
    card = json.loads((tmp_path / "out" / "board-model" / "model_card.json").read_text())
    assert card["board_fs_hz"] == 50000 and card["signal"]["channel_left_out"] == [0, 0, 1, 0]
    assert sorted(card["three_channel_class"]) == ["0", "1", "2", "3"]
    header = (tmp_path / "out" / "impactsense_models.h").read_text()
    assert "#define IMPACTSENSE_THREE_CHANNEL_CLASS 1" in header
    acc = json.loads((tmp_path / "out" / "export.json").read_text())["board_held_out"]
    assert acc["n"] == len(split["test_recordings"]) and acc["reported"] == acc["n"]
    assert acc["energy_class_accuracy"] > 0.8
    assert f"the board leaves [{LEFT_OUT}] out too" in capsys.readouterr().out


CXX = shutil.which("g++") or shutil.which("c++")


@pytest.mark.slow
@pytest.mark.skipif(CXX is None or shutil.which("gcc") is None, reason="no host C/C++ compiler")
def test_the_generated_three_channel_tables_build_and_run_in_the_firmware(left_out_export, tmp_path):
    """The exported C (header with IMPACTSENSE_THREE_CHANNEL_CLASS, the per-channel tables) compiled with the
    portable firmware under the sanitizers (firmware/test/native/sanitize_main.cpp, impactapp_models.h's
    exported_models): a debonded channel's drops all give valid reports."""
    _, out, _, test = left_out_export
    session = inject_session(test.subset(np.arange(0, len(test), 3)), FaultSpec(debond=LEFT_OUT, debond_hz=4000))
    frames = board_samples(session.adc, session.rig.fs_hz, 50000)
    (tmp_path / "frames.bin").write_bytes(frames.tobytes())
    lib = ROOT / "firmware/lib"
    srcs = [*sorted((lib / "impactcore/src").glob("*.cpp")), lib / "impactlink/src/impactlink.cpp",
            *sorted((lib / "impactapp/src").glob("*.cpp")), ROOT / "firmware/test/native/sanitize_main.cpp"]
    exe = tmp_path / "run"
    san = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
    subprocess.run(["gcc", "-c", "-O1", *san, f"-I{out}", str(out / "impactsense_forest_tables.c"),
                    "-o", str(tmp_path / "tables.o")], check=True)
    subprocess.run([CXX, "-std=c++17", "-O1", *san, "-Wall", "-Wextra", "-Werror",
                    *(f"-I{lib / d / 'src'}" for d in ("impactcore", "impactlink", "impactapp")), f"-I{out}",
                    *map(str, srcs), str(tmp_path / "tables.o"), "-o", str(exe)], check=True)
    p = subprocess.run([str(exe), str(tmp_path / "frames.bin"), str(frames.shape[0]), str(frames.shape[1])],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    words = p.stdout.split()
    assert words[words.index("twin") + 1] == "0"
    assert int(words[words.index("reports") + 1]) == len(session)
    assert int(words[words.index("valid") + 1]) == len(session)


def test_a_twin_model_leaves_the_channel_out_on_the_board_as_the_host_does():
    """The shipped tables (a twin model) with channel 2 left out in their signal settings: every drop of a session
    with that channel debonded gets a valid report naming it, at the core's twin_match position on the board's
    captures (the host's ImpactModel.predict calls the same function; 0.05 mm: the wire's 0.1 mm steps)."""
    from impactsense.board.capture import signal_for_board
    from impactsense.export import load_tables

    models, signal = firmware_models(ROOT / "models")
    signal = {**signal, "channel_left_out": [int(c == LEFT_OUT) for c in range(4)]}
    s2 = load_session("bundled:session-2")
    session = inject_session(s2.subset(np.arange(0, len(s2), 16)), FaultSpec(debond=LEFT_OUT, debond_hz=4000, seed=1))
    got = board_reports(session, models, signal)
    assert len(got) == len(session) and all(r["left_out"] == LEFT_OUT for r in got.values())
    caps, rows, _ = board_captures(session, 50000, signal)
    sig = signal_for_board(session.rig, signal, 50000)
    f = featurize(caps, sig)
    assert np.all(f.no_onset[:, LEFT_OUT])
    weak = int(load_tables(ROOT / "models" / "forest_tables.npz")["twin"]["config"][5])
    m = exported_twin_match(f, sig, np.full((len(f), 2), np.nan), ROOT / "models", weak_channel=weak)
    assert np.all(m["status"] == 0) and np.all(m["left_out"] == LEFT_OUT)
    np.testing.assert_allclose(np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in rows]), m["xy_mm"], atol=0.051)
