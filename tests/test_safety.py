"""Nothing lost, nothing trusted blindly: the one output writer (outputs.py), model folders that cannot run
code (modelfolder.py, forestfile.py), errors instead of wrong numbers (checks.py), record's journal, and a fuzz
of the loaders. Each test is a case an attacker or a careless user tried (issue 18)."""

import hashlib
import json
import pickle
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from impactsense.cli import main
from impactsense.data import load_session, write_session
from impactsense.errors import DataError
from impactsense.outputs import MANIFEST, OutputError, output_folder

ROOT = Path(__file__).resolve().parents[1]


def tree(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def leftovers(parent: Path) -> list:
    return sorted(p.name for p in parent.iterdir() if p.name.endswith((".part", ".old")))


@pytest.fixture(scope="module")
def small(session1, tmp_path_factory):
    """A small session (the bundled session's first 12 cases) and a 5-tree model trained on it."""
    root = tmp_path_factory.mktemp("small")
    rows = np.flatnonzero(session1.case_id < 12)
    s = session1
    path = write_session(root / "s", s.rig, s.x_mm[rows], s.y_mm[rows], s.height_mm[rows], s.adc[rows],
                         s.case_id[rows], s.repetition[rows])
    assert main(["train", str(path), "--out", str(root / "m"), "--trees", "5", "--site-map", "none",
                 "--test-fraction", "0.25"]) == 0
    return path, root / "m"


def copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


# ----- the output writer -----

def test_a_folder_with_a_users_files_is_refused_and_with_force_keeps_every_one(tmp_path, session1):
    out = tmp_path / "out"
    (out / "sub").mkdir(parents=True)
    (out / "sub" / "mine.txt").write_text("mine")
    (out / "impacts.csv").write_text("my own impacts")
    before = tree(out)
    s = session1.subset(np.arange(3))
    with pytest.raises(OutputError, match="did not write"):
        write_session(out, s.rig, s.x_mm, s.y_mm, s.height_mm, s.adc)
    assert tree(out) == before and leftovers(tmp_path) == []
    write_session(out, s.rig, s.x_mm, s.y_mm, s.height_mm, s.adc, force=True)
    assert (out / "sub" / "mine.txt").read_text() == "mine"
    kept = list(out.glob("impacts.csv.replaced-*"))
    assert len(kept) == 1 and kept[0].read_text() == "my own impacts"
    assert len(load_session(out)) == 3
    # the CLI says so: exit 2 naming the folder
    assert main(["simulate-dataset", "--n", "2", "--out", str(out)]) == 2


def test_the_tools_own_folder_is_replaced_whole_and_a_failure_leaves_it(tmp_path):
    out = tmp_path / "out"
    with output_folder(out) as stage:
        (stage / "a.txt").write_text("1")
        (stage / "b.txt").write_text("1")
    with output_folder(out) as stage:      # the tool's own: replaced, the old b.txt gone with it
        (stage / "a.txt").write_text("2")
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "a.txt"] and (out / "a.txt").read_text() == "2"
    with pytest.raises(RuntimeError):
        with output_folder(out) as stage:
            (stage / "a.txt").write_text("3")
            raise RuntimeError("midway")
    assert (out / "a.txt").read_text() == "2" and leftovers(tmp_path) == []
    (out / "a.txt").write_text("edited by the user")      # an edited output is the user's now
    with pytest.raises(OutputError):
        with output_folder(out) as stage:
            pass


def test_leftovers_of_a_killed_writer_are_cleaned_and_a_users_file_in_them_comes_back(tmp_path):
    out = tmp_path / "out"
    with output_folder(out) as stage:
        (stage / "a.txt").write_text("1")
    dead = 2 ** 22 + 12345          # above the default pid_max: no such process
    stage = tmp_path / f".out.{dead}-0123abcd.part"
    stage.mkdir()
    (stage / ".impactsense-staging").touch()
    (stage / "half.bin").write_bytes(b"x")
    swapped = tmp_path / f".out.{dead}-89abcdef.part"    # an old output swapped out, with a user's file
    swapped.mkdir()
    (swapped / "a.txt").write_text("0")
    (swapped / MANIFEST).write_text(json.dumps({"files": {"a.txt": hashlib.sha256(b"0").hexdigest()}}))
    (swapped / "users.txt").write_text("mine")
    with pytest.raises(OutputError, match="users.txt"):    # back in out, it is the user's: out is refused
        with output_folder(out) as stage:
            (stage / "a.txt").write_text("2")
    assert leftovers(tmp_path) == []
    assert (out / "users.txt").read_text() == "mine" and (out / "a.txt").read_text() == "1"


WRITER = """
import os, sys
from pathlib import Path
from impactsense.outputs import output_folder
out = Path(sys.argv[1])
gen = 0
while True:
    gen += 1
    with output_folder(out) as stage:
        for k in range(40):
            (stage / f"f{k:02d}.txt").write_text(f"{os.getpid()}-{gen}\\n" * 200)
    print(gen, flush=True)
"""


def check_whole(out: Path) -> str | None:
    """The generation of a complete output folder (every file of one generation), None if absent."""
    if not out.exists():
        return None
    names = sorted(p.name for p in out.iterdir())
    assert names == [MANIFEST] + [f"f{k:02d}.txt" for k in range(40)], names
    gens = {p.read_text().split()[0] for p in out.glob("f*.txt")}
    assert len(gens) == 1, gens
    return gens.pop()


def test_kill_9_of_a_writer_at_random_moments_leaves_the_old_or_the_new_folder_whole(tmp_path):
    out = tmp_path / "out"
    rng = random.Random(0)
    seen = set()
    for _ in range(12):
        proc = subprocess.Popen([sys.executable, "-c", WRITER, str(out)], stdout=subprocess.PIPE, text=True)
        proc.stdout.readline()                       # at least one generation written
        time.sleep(rng.uniform(0.0, 0.3))
        proc.kill()
        proc.wait()
        seen.add(check_whole(out))
    assert None not in seen and len(seen) > 3        # many different moments were hit
    with output_folder(out) as stage:                # the next run cleans the killed runs' staging
        (stage / "x").write_text("x")
    assert leftovers(tmp_path) == []


def run_killed(args, at_s: float, cwd: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "impactsense.cli", *args], cwd=cwd,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(at_s)
    proc.kill()
    proc.wait()


def model_state(m: Path) -> str:
    """The model folder loads and every file matches the card (a whole model); returns its card's hash."""
    from impactsense.models import ImpactModel

    ImpactModel.load(m)
    return hashlib.sha256((m / "model_card.json").read_bytes()).hexdigest()


def test_kill_9_of_train_and_export_near_their_end_leaves_a_whole_old_or_new_output(small, tmp_path):
    sess, _ = small
    m, e = tmp_path / "m", tmp_path / "e"
    train = ["train", str(sess), "--out", str(m), "--trees", "5", "--site-map", "none", "--test-fraction", "0.25"]
    export = ["export", str(m), "--out", str(e), "--trees", "3", "--no-m2cgen"]
    t0 = time.time()
    assert subprocess.run([sys.executable, "-m", "impactsense.cli", *train], capture_output=True).returncode == 0
    t_train = time.time() - t0
    t0 = time.time()
    assert subprocess.run([sys.executable, "-m", "impactsense.cli", *export], capture_output=True).returncode == 0
    t_export = time.time() - t0
    trees_x = json.loads((e / "export.json").read_text())["trees"]["x"]   # 3, or every boosted tree (board.boosted)
    rng = random.Random(1)
    states = {model_state(m)}
    for _ in range(2):
        run_killed(train, t_train * rng.uniform(0.6, 1.05), tmp_path)
        states.add(model_state(m))
        run_killed(export, t_export * rng.uniform(0.6, 1.05), tmp_path)
        from impactsense.export import load_tables

        assert json.loads((e / "export.json").read_text())["trees"]["x"] == trees_x
        load_tables(e / "forest_tables.npz")
        manifest = json.loads((e / MANIFEST).read_text())["files"]
        assert sorted(manifest) == sorted(p.name for p in e.iterdir() if p.name != MANIFEST)
    for args in (train, export):      # the next runs clean up what the killed ones staged
        assert subprocess.run([sys.executable, "-m", "impactsense.cli", *args], capture_output=True).returncode == 0
    assert leftovers(tmp_path) == []


# ----- model folders that cannot run code -----

class Payload:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_a_crafted_pickle_in_a_model_folder_never_runs(small, tmp_path):
    _, model = small
    marker = tmp_path / "PWNED"
    evil = pickle.dumps(Payload(str(marker)))
    for variant in ("joblib_name", "npz_name_rehashed"):
        m = copy(model, tmp_path / variant)
        card = json.loads((m / "model_card.json").read_text())
        name = "forest_dx.joblib" if variant == "joblib_name" else "forest_dx.npz"
        (m / name).write_bytes(evil)
        card["files"]["x"] = name
        card["sha256"][name] = hashlib.sha256(evil).hexdigest()
        (m / "model_card.json").write_text(json.dumps(card))
        assert main(["evaluate", str(small[0]), "--model", str(m), "--json", str(tmp_path / "r.json")]) == 2
        assert main(["export", str(m), "--out", str(tmp_path / "e"), "--rate", "native"]) == 2
        assert not marker.exists()


@pytest.mark.parametrize("name", ["/etc/passwd", "../m/forest_dx.npz", "sub/forest_dx.npz", ".hidden"])
def test_card_file_names_are_confined_to_the_folder(small, tmp_path, name):
    m = copy(small[1], tmp_path / "m")
    card = json.loads((m / "model_card.json").read_text())
    card["files"]["x"] = name
    (m / "model_card.json").write_text(json.dumps(card))
    from impactsense.models import ImpactModel

    with pytest.raises(DataError, match="plain file name"):
        ImpactModel.load(m)


def test_a_damaged_model_file_or_a_card_without_checksums_is_refused(small, tmp_path, capsys):
    m = copy(small[1], tmp_path / "m")
    data = bytearray((m / "forest_dy.npz").read_bytes())
    for i in range(0, 200 * 37, 37):
        data[len(data) // 3 + i] ^= 0x5A
    (m / "forest_dy.npz").write_bytes(bytes(data))
    assert main(["evaluate", str(small[0]), "--model", str(m), "--json", str(tmp_path / "r.json")]) == 2
    assert "forest_dy.npz" in capsys.readouterr().err
    m2 = copy(small[1], tmp_path / "m2")
    card = json.loads((m2 / "model_card.json").read_text())
    del card["sha256"]
    (m2 / "model_card.json").write_text(json.dumps(card))
    assert main(["export", str(m2), "--out", str(tmp_path / "e"), "--rate", "native"]) == 2
    assert "sha256" in capsys.readouterr().err


def test_forest_files_give_the_fitted_forests_numbers_and_refuse_broken_trees(tmp_path):
    from sklearn.ensemble import RandomForestClassifier, RandomForestRegressor

    from impactsense.forestfile import load_forest, save_forest

    rng = np.random.default_rng(0)
    X = rng.normal(size=(200, 6))
    reg = RandomForestRegressor(8, random_state=0).fit(X, X[:, 0] * 2 + X[:, 1])
    cls = RandomForestClassifier(8, random_state=0).fit(X, X[:, 2] > 0)
    for forest in (reg, cls):
        save_forest(tmp_path / "f.npz", forest)
        back = load_forest(tmp_path / "f.npz")
        np.testing.assert_array_equal(back.predict(X), forest.predict(X))
    save_forest(tmp_path / "f.npz", reg)
    with np.load(tmp_path / "f.npz") as z:
        arrays = {k: z[k] for k in z.files}
    for field, value in (("left_child", 10 ** 6), ("right_child", 0), ("feature", 99)):
        bad = {k: v.copy() for k, v in arrays.items()}
        split = int(np.flatnonzero(bad["left_child"] != -1)[0])
        bad[field][split] = value
        np.savez(tmp_path / "bad.npz", **bad)
        with pytest.raises(DataError):
            load_forest(tmp_path / "bad.npz")


# ----- errors instead of wrong numbers -----

def edited_session(src: Path, dst: Path, edit) -> Path:
    d = copy(src, dst)
    rig = json.loads((d / "rig.json").read_text())
    edit(rig)
    (d / "rig.json").write_text(json.dumps(rig))
    return d


def test_evaluate_refuses_a_session_of_another_rig_and_knows_its_own_by_content(small, tmp_path, capsys):
    sess, m = small
    def moved(r):
        r["sensors"][1]["x_mm"] -= 20
    other = edited_session(sess, tmp_path / "moved", moved)
    assert main(["evaluate", str(other), "--model", str(m), "--json", str(tmp_path / "r.json")]) == 2
    assert "rig" in capsys.readouterr().err
    half = edited_session(sess, tmp_path / "fs", lambda r: r.update(fs_hz=r["fs_hz"] / 2))
    assert main(["evaluate", str(half), "--model", str(m), "--json", str(tmp_path / "r.json")]) == 2
    assert "fs_hz" in capsys.readouterr().err
    notes = edited_session(sess, tmp_path / "notes", lambda r: r.update(notes="edited by hand"))
    assert main(["evaluate", str(notes), "--model", str(m), "--json", str(tmp_path / "r.json")]) == 0
    report = json.loads((tmp_path / "r.json").read_text(), parse_constant=lambda c: pytest.fail(f"bare {c}"))
    assert report["scope"] == "held-out drops of the training session"


@pytest.mark.parametrize("edit, field", [
    (lambda r: r["sensors"][1].update(x_mm=r["sensors"][0]["x_mm"], y_mm=r["sensors"][0]["y_mm"]), "sensors[1]"),
    (lambda r: r.update(fs_hz=1e-9), "fs_hz"),
    (lambda r: r.update(bias_counts=70000), "bias_counts"),
])
def test_rig_json_that_no_rig_can_have_is_refused(small, tmp_path, edit, field):
    d = edited_session(small[0], tmp_path / "s", edit)
    with pytest.raises(DataError) as info:
        load_session(d)
    assert info.value.field == field


@pytest.mark.parametrize("exclude", ["-1", "99999", "1" * 30])
def test_exclude_ids_must_be_drops_of_the_session(small, tmp_path, exclude, capsys):
    assert main(["train", str(small[0]), "--out", str(tmp_path / "m"), "--exclude", exclude]) == 2
    assert "--exclude" in capsys.readouterr().err and not (tmp_path / "m").exists()


def test_one_case_only_and_unknown_labels_are_clear_errors(session1, tmp_path, capsys):
    s = session1.subset(np.flatnonzero(session1.case_id == session1.case_id[0]))
    one = write_session(tmp_path / "one", s.rig, s.x_mm, s.y_mm, s.height_mm, s.adc, np.zeros(len(s), int))
    assert main(["train", str(one), "--out", str(tmp_path / "m")]) == 2
    assert "case" in capsys.readouterr().err
    unk = write_session(tmp_path / "unk", s.rig, np.full(len(s), np.nan), s.y_mm, s.height_mm, s.adc)
    assert np.isnan(load_session(unk).x_mm).all()
    assert main(["train", str(unk), "--out", str(tmp_path / "m"), "--test-fraction", "0"]) == 2
    assert "x_mm" in capsys.readouterr().err


def damaged_inputs(sess: Path, tmp: Path):
    """(name, folder) pairs the CLI once answered with a traceback."""
    import zipfile

    out = []
    d = copy(sess, tmp / "npz")                       # corrupted compressed npz (zlib error)
    raw = bytearray((d / "recordings.npz").read_bytes())
    with zipfile.ZipFile(d / "recordings.npz") as z:
        info = z.infolist()[0]
    start = info.header_offset + 30 + len(info.filename) + len(info.extra) + 10
    raw[start:start + 64] = bytes(64)
    (d / "recordings.npz").write_bytes(bytes(raw))
    out.append(("compressed npz", d))
    d = copy(sess, tmp / "utf8")
    (d / "impacts.csv").write_bytes((d / "impacts.csv").read_bytes().replace(b"recording_id", b"recording\xff_id"))
    out.append(("non-UTF-8 CSV", d))
    d = copy(sess, tmp / "huge")
    lines = (d / "impacts.csv").read_text().splitlines()
    lines[1] = ",".join([lines[1].split(",")[0], "1" + "0" * 30, *lines[1].split(",")[2:]])
    (d / "impacts.csv").write_text("\n".join(lines) + "\n")
    out.append(("case_id 10^30", d))
    d = copy(sess, tmp / "deep")
    (d / "rig.json").write_text("[" * 100000 + "]" * 100000)
    out.append(("deep JSON", d))
    return out


def test_damaged_inputs_are_exit_2_naming_the_file_never_a_traceback(small, tmp_path, capsys):
    for name, d in damaged_inputs(small[0], tmp_path):
        for args in (["info", str(d)], ["evaluate", str(d), "--model", str(small[1]), "--json", str(tmp_path / "r")]):
            assert main(args) == 2, name
            err = capsys.readouterr().err
            assert str(d) in err and "Traceback" not in err, (name, err)
    cal = tmp_path / "CAL.json"
    cal.write_text(json.dumps({"drops": "0,1,2"}))
    assert main(["train", str(small[0]), "--out", str(tmp_path / "m"), "--exclude", str(cal)]) == 2
    assert "drops" in capsys.readouterr().err
    m = copy(small[1], tmp_path / "trunc")
    (m / "forest_dx.npz").write_bytes((m / "forest_dx.npz").read_bytes()[:1000])
    assert main(["evaluate", str(small[0]), "--model", str(m), "--json", str(tmp_path / "r")]) == 2


def test_dead_or_clipped_channels_in_every_drop_are_a_clear_error(small, tmp_path, capsys):
    s = load_session(small[0])
    for name in ("dead", "clipped"):
        adc = s.adc.copy()
        if name == "dead":
            adc[:, 2, :] = s.rig.bias_counts
        else:
            adc = np.clip((adc.astype(int) - s.rig.bias_counts) * 50 + s.rig.bias_counts, 0,
                          s.rig.adc_max).astype(np.uint16)
        d = write_session(tmp_path / name, s.rig, s.x_mm, s.y_mm, s.height_mm, adc, s.case_id, s.repetition)
        rc = main(["train", str(d), "--out", str(tmp_path / f"m-{name}"), "--trees", "5", "--site-map", "none"])
        err = capsys.readouterr().err
        assert rc in (0, 2) and "Traceback" not in err and "internal error" not in err, (name, err)


def test_an_unforeseen_exception_is_one_line_with_the_log_path(monkeypatch, tmp_path, capsys):
    import impactsense.commands.info as info

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(info, "run", lambda args: 1 / 0)      # register() binds run when main builds the parser
    assert main(["info", "bundled"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "ZeroDivisionError" in err and str(tmp_path) in err
    assert "Traceback" in (tmp_path / "impactsense" / "impactsense-errors.log").read_text()


# ----- monitor and record -----

def test_monitor_exits_non_zero_when_the_port_cannot_be_opened(capfd):
    assert main(["monitor", "--port", "/dev/no-such-port"]) == 2
    assert "cannot open" in capfd.readouterr().err


def test_monitor_says_when_the_link_ends_and_stops_quietly_on_ctrl_c():
    import io

    from impactsense.link import monitor

    class Port:
        def __init__(self, exc):
            self.exc, self.is_open = exc, True

        def read(self, n):
            raise self.exc

        def close(self):
            pass

    from impactsense.link.transport import PortClosed

    for exc, said in ((PortClosed("gone"), "link ended"), (KeyboardInterrupt(), "Ctrl-C")):
        err = io.StringIO()
        monitor.run(lambda: Port(exc), out=io.StringIO(), err=err)
        assert said in err.getvalue()


def test_the_journal_keeps_every_capture_up_to_a_cut(tmp_path):
    from impactsense.link.journal import CaptureJournal, read_journal

    j = CaptureJournal(tmp_path / "j", {"rig": {}, "fs_hz": 50000})
    caps = [np.full((4, 300), k, np.int16) for k in range(5)]
    for k, c in enumerate(caps):
        j(c, {"seq": k, "x_mm": 1.5})
    j.close()
    raw = (tmp_path / "j" / "captures.bin").read_bytes()
    (tmp_path / "j" / "captures.bin").write_bytes(raw[:-100])     # a kill in the middle of the last one
    _, got, clean = read_journal(tmp_path / "j")
    assert not clean and len(got) == 4 and all(np.array_equal(g[0], c) for g, c in zip(got, caps))


def start_emulator(limit: int, speed: str):
    proc = subprocess.Popen([sys.executable, "-m", "impactsense.cli", "emulate", "--pty", "--speed", speed,
                             "--models", str(ROOT / "models"), "--limit", str(limit)], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    return proc, proc.stdout.readline().strip()


# A shell starts a background job (`cmd &` in a script or a CI runner) with SIGINT ignored, and Python then never
# raises KeyboardInterrupt; record's processes start so, whatever the shell that runs pytest did.
AS_A_BACKGROUND_JOB = ("sh", "-c", 'trap "" INT; exec "$@"', "sh")


def test_record_labels_from_a_truth_csv_and_ctrl_c_or_kill_9_loses_no_capture(tmp_path):
    truth = tmp_path / "truth.csv"
    truth.write_text("x_mm,y_mm,height_mm\n100,120,150\n,,\n200,80,100\n")
    emu, port = start_emulator(5, "0")
    try:
        r = subprocess.run([sys.executable, "-m", "impactsense.cli", "record", "--port", port, "--out",
                            str(tmp_path / "a"), "--max-events", "4", "--truth", str(truth)], capture_output=True,
                           text=True, timeout=300)
    finally:
        emu.kill()
    assert r.returncode == 0, r.stderr
    s = load_session(tmp_path / "a")
    assert len(s) == 4 and s.x_mm[0] == 100 and s.height_mm[2] == 100
    assert np.isnan(s.x_mm[[1, 3]]).all() and np.isnan(s.height_mm[3])   # unknown, never the board's
    assert "INCOMPLETE" not in s.rig.raw["notes"] and (tmp_path / "a" / "board_reports.csv").is_file()
    for how in (signal.SIGINT, signal.SIGKILL):
        out = tmp_path / f"rec-{how.name}"
        emu, port = start_emulator(400, "0.05")
        rec = subprocess.Popen([*AS_A_BACKGROUND_JOB, sys.executable, "-m", "impactsense.cli", "record", "--port",
                                port, "--out", str(out)], stderr=subprocess.PIPE, text=True)
        journal = tmp_path / f".{out.name}.record-journal" / "captures.bin"
        deadline = time.time() + 120
        while time.time() < deadline and (not journal.exists() or journal.stat().st_size < 3 * 8000):
            time.sleep(0.2)
        time.sleep(1.5)              # past a batch's fsync
        try:
            rec.send_signal(how)
            rec.wait(60)         # the save takes about a second, on a loaded machine too
        finally:
            rec.kill()
            emu.kill()
        if how == signal.SIGKILL:
            assert not out.exists() and journal.exists()
            assert main(["record", "--port", "/dev/null", "--out", str(out)]) == 1   # saves the journal first
        s = load_session(out)
        assert len(s) >= 3 and "INCOMPLETE" in s.rig.raw["notes"] and np.isnan(s.x_mm).all()
        assert ("interrupted" if how == signal.SIGINT else "crash") in s.rig.raw["notes"]
        assert not journal.parent.exists()


def test_record_started_with_sigint_ignored_stops_and_saves_on_sigint_or_sigterm(tmp_path):
    """`record ... &` (SIGINT ignored from the shell) stopped by `kill -INT` or `kill` (SIGTERM): the recording
    stops within seconds and its journal becomes the folder (here no capture: the port is pyserial's loop, so the
    journal is removed). The two recordings run side by side (their start is most of the test's time)."""
    recs = {}
    for how in (signal.SIGINT, signal.SIGTERM):
        out = tmp_path / f"rec-{how.name}"
        recs[how] = out, subprocess.Popen([*AS_A_BACKGROUND_JOB, sys.executable, "-m", "impactsense.cli", "record",
                                           "--port", "loop://", "--out", str(out)], stderr=subprocess.PIPE, text=True)
    try:
        for how, (out, rec) in recs.items():
            journal = tmp_path / f".{out.name}.record-journal"
            deadline = time.time() + 120
            while time.time() < deadline and not (journal / "captures.bin").exists() and rec.poll() is None:
                time.sleep(0.1)
            time.sleep(0.3)      # into record()'s read loop
            rec.send_signal(how)
            rc = rec.wait(30)
            err = rec.stderr.read()
            assert rc == 1 and "no complete capture received" in err, (how.name, rc, err)
            assert not journal.exists() and not out.exists()
    finally:
        for _, rec in recs.values():
            rec.kill()


# ----- fuzz -----

def test_fuzzed_loader_inputs_give_right_numbers_or_exit_2_never_a_crash(tmp_path):
    """A few hundred random corruptions of a session's npz/CSV/rig.json, a model folder's card and forests
    and a CAL.json (benchmarks/bench_fuzz_loaders.py runs 10,000); a subprocess, so a crash shows."""
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_fuzz_loaders.py"), "--n", "300",
                        "--seed", "7"], capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "tracebacks: 0" in r.stdout
