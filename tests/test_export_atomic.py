"""`impactsense export` writes all of OUT or nothing: OUT/board-model (the model made again at the board's
rate), the C sources, the emulator's tables and export.json are staged next to OUT and moved in only when
every step succeeded. A failure deep in the path (the zero-shot model's calibration-drop fit, after the
virtual drops' board model was written; the m2cgen source, after the node tables were written) leaves no
half-written file and OUT's earlier contents byte for byte, and says so. A folder holding files impactsense
did not write is refused unless --force, and with --force none of them is lost."""

import json
import shutil
from pathlib import Path

import pytest

from impactsense.cli import main


@pytest.fixture(scope="module")
def zero_shot_model(session1, tmp_path_factory):
    """A sim-trained model (`impactsense demo --zero-shot`'s model-sim), small: the nominal twin, 40 virtual
    drops, no site map."""
    from impactsense.sim import SimParams
    from impactsense.zeroshot import run_zero_shot

    out = tmp_path_factory.mktemp("zs")
    cal = out / "CAL.json"
    cal.write_text(json.dumps({"sim_params": SimParams().to_dict(), "exclude_case_ids": [0, 3, 41, 2]}))
    run_zero_shot(session1, cal, out, n_virtual=40, progress=False, use_twin=False)
    return out / "model-sim"


def files(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def leftovers(parent: Path) -> list:
    return sorted(p.name for p in parent.glob(".*.part"))


def test_a_successful_export_replaces_board_model_whole_and_keeps_other_files(zero_shot_model, tmp_path):
    out = tmp_path / "out"
    (out / "board-model").mkdir(parents=True)
    (out / "board-model" / "stale.joblib").write_text("from an earlier model")
    (out / "notes.txt").write_text("mine")
    before = files(out)
    args = ["export", str(zero_shot_model), "--out", str(out), "--trees", "5", "--no-m2cgen"]
    assert main(args) == 2          # a folder with files impactsense did not write: refused, untouched
    assert files(out) == before and leftovers(tmp_path) == []
    assert main(args + ["--force"]) == 0
    assert [p.name for p in out.glob("board-model.replaced-*/stale.joblib")] == ["stale.joblib"]  # kept aside
    card = json.loads((out / "board-model" / "model_card.json").read_text())
    assert card["board_fs_hz"] == 50000 and "zero_shot" in card
    assert (out / "notes.txt").read_text() == "mine"
    assert "board_held_out" in json.loads((out / "export.json").read_text())
    assert leftovers(tmp_path) == [] and leftovers(out) == []
    # impactsense's own folder: replaced whole, no --force needed
    own = tmp_path / "own"
    assert main(["export", str(zero_shot_model), "--out", str(own), "--trees", "5", "--no-m2cgen"]) == 0
    assert main(["export", str(zero_shot_model), "--out", str(own), "--trees", "3", "--no-m2cgen"]) == 0
    assert json.loads((own / "export.json").read_text())["trees"]["x"] == 3 and leftovers(tmp_path) == []


def test_a_failing_calibration_drop_fit_leaves_out_as_it_was(zero_shot_model, tmp_path, monkeypatch, capsys):
    import impactsense.board.models as board_models  # the board rebuild calls the calibration-drop fit from here

    out = tmp_path / "out"
    assert main(["export", str(zero_shot_model), "--out", str(out), "--trees", "5", "--no-m2cgen"]) == 0
    (out / "notes.txt").write_text("mine")
    before = files(out)
    assert "board-model/model_card.json" in before and "impactsense_forest_tables.c" in before
    half_written = []

    def fail(*args, **kwargs):   # by now the virtual drops' board model is written (staged)
        half_written.extend(str(p) for p in tmp_path.glob(".out.*.part/board-model/*.npz"))
        raise RuntimeError("forced failure in the calibration-drop fit")

    monkeypatch.setattr(board_models, "fit_on_calibration_drops", fail)
    capsys.readouterr()
    assert main(["export", str(zero_shot_model), "--out", str(out), "--trees", "5", "--no-m2cgen", "--force"]) == 2
    err = capsys.readouterr().err
    assert "forced failure in the calibration-drop fit" in err
    assert f"{out}: export failed (RuntimeError" in err and "nothing was written" in err
    assert half_written, "the failure came before anything was staged: the test checks nothing"
    assert files(out) == before
    assert leftovers(tmp_path) == [] and leftovers(out) == []
    # into a fresh folder: not even the folder appears
    fresh = tmp_path / "fresh"
    assert main(["export", str(zero_shot_model), "--out", str(fresh), "--trees", "5", "--no-m2cgen"]) == 2
    assert not fresh.exists() and leftovers(tmp_path) == []


def test_a_failing_c_source_leaves_the_earlier_export(zero_shot_model, tmp_path, monkeypatch, capsys):
    """--rate native (no board model): the header and node tables are written before the m2cgen source."""
    import impactsense.export as export

    # --rate native exports the model's own forests, one pair on the physics position: a sim-trained model whose
    # band picks are on also carries the pick sets' own forests (position_members), which the export refuses, so
    # this copy's card keeps the one pair (what a card without members means).
    model = tmp_path / "model"
    shutil.copytree(zero_shot_model, model)
    card = json.loads((model / "model_card.json").read_text())
    card.pop("position_members", None)
    (model / "model_card.json").write_text(json.dumps(card))
    zero_shot_model = model
    out = tmp_path / "out"
    assert main(["export", str(zero_shot_model), "--out", str(out), "--trees", "3", "--rate", "native",
                 "--no-m2cgen"]) == 0
    before = files(out)
    written = []

    def fail(*args, **kwargs):
        written.extend(p.name for p in tmp_path.glob(".*.part/impactsense_*"))
        raise MemoryError("forced failure in the m2cgen source")

    monkeypatch.setattr(export, "m2cgen_c", fail)
    assert main(["export", str(zero_shot_model), "--out", str(out), "--trees", "5", "--rate", "native"]) == 2
    assert "forced failure in the m2cgen source" in capsys.readouterr().err
    assert sorted(written) == ["impactsense_forest_tables.c", "impactsense_models.h"]
    assert files(out) == before and leftovers(tmp_path) == []
