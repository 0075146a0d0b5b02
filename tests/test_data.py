"""The session loader: bad input is a clear error naming the file and the field."""

import json

import numpy as np
import pytest

from impactsense.data import load_session, write_session
from impactsense.errors import DataError


@pytest.fixture()
def small_session(tmp_path, session1):
    rows = np.arange(12)
    s = session1.subset(rows)
    return write_session(tmp_path / "s", session1.rig, s.x_mm, s.y_mm, s.height_mm, s.adc, s.case_id, s.repetition)


def test_bundled_session_loads_and_matches_the_declared_layout(session1):
    assert len(session1) == 771 and session1.n_cases == 159
    assert session1.adc.shape == (771, 4, 5000) and session1.adc.dtype == np.uint16
    assert session1.rig.sensor_xy_mm.shape == (4, 2)


def test_write_then_load_round_trip(small_session):
    s = load_session(small_session)
    assert len(s) == 12 and s.adc.dtype == np.uint16


def expect_error(path, field_fragment, problem_fragment):
    with pytest.raises(DataError) as err:
        load_session(path)
    msg = str(err.value)
    assert field_fragment in msg and problem_fragment in msg, msg


def test_missing_rig_key(small_session):
    rig = json.loads((small_session / "rig.json").read_text())
    del rig["fs_hz"]
    (small_session / "rig.json").write_text(json.dumps(rig))
    expect_error(small_session, "rig.json [fs_hz]", "missing key")


def test_channel_count_not_four(small_session):
    rig = json.loads((small_session / "rig.json").read_text())
    rig["channels"] = 3
    (small_session / "rig.json").write_text(json.dumps(rig))
    expect_error(small_session, "[channels]", "must be 4")


def test_truncated_npz(small_session):
    p = small_session / "recordings.npz"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    expect_error(small_session, "recordings.npz [adc]", "truncated")


@pytest.mark.parametrize("dtype", [np.float32, np.int32])
def test_wrong_dtype(small_session, dtype):
    adc = np.load(small_session / "recordings.npz")["adc"].astype(dtype)
    np.savez(small_session / "recordings.npz", adc=adc)
    expect_error(small_session, "[adc]", "dtype must be uint16")


def test_wrong_shape(small_session):
    adc = np.load(small_session / "recordings.npz")["adc"]
    np.savez(small_session / "recordings.npz", adc=adc[:, :3])
    expect_error(small_session, "[adc]", "4 channels")
    np.savez(small_session / "recordings.npz", adc=adc[:5])
    expect_error(small_session, "[adc]", "impacts.csv lists 12")


def test_nan_in_impacts(small_session):
    p = small_session / "impacts.csv"
    lines = p.read_text().splitlines()
    parts = lines[3].split(",")
    parts[3] = "nan"
    lines[3] = ",".join(parts)
    p.write_text("\n".join(lines) + "\n")
    expect_error(small_session, "impacts.csv [x_mm]", "not finite")


def test_ids_out_of_order(small_session):
    p = small_session / "impacts.csv"
    lines = p.read_text().splitlines()
    lines[2], lines[3] = lines[3], lines[2]
    p.write_text("\n".join(lines) + "\n")
    expect_error(small_session, "[recording_id]", "in order")


def test_missing_file(small_session):
    (small_session / "impacts.csv").unlink()
    expect_error(small_session, "impacts.csv", "file not found")


def test_write_session_refuses_bad_arrays_and_leaves_nothing(tmp_path, session1):
    with pytest.raises(DataError):
        write_session(tmp_path / "bad", session1.rig, [1.0], [1.0], [100.0], np.zeros((1, 4, 10), np.float32))
    assert not (tmp_path / "bad").exists()
    assert not any(p.name.startswith(".bad") for p in tmp_path.iterdir())


@pytest.mark.parametrize("text, problem", [(None, "card gone"), ("{not json", "not valid JSON"),
                                           ("[1, 2]", "must hold a JSON object"), (b"\xff\xfe", "not valid JSON")])
def test_json_files_fail_with_the_file_named(tmp_path, text, problem):
    """rig.json, model cards, CAL.json and --exclude files are read by one reader: a missing, corrupt or
    non-object file is a DataError naming the file, never a traceback."""
    from impactsense.data import read_json

    path = tmp_path / "model_card.json"
    if isinstance(text, bytes):
        path.write_bytes(text)
    elif text is not None:
        path.write_text(text)
    with pytest.raises(DataError) as err:
        read_json(path, missing="card gone")
    assert str(path) in str(err.value) and problem in str(err.value)


def test_train_exclude_names_a_missing_calibration_file(tmp_path):
    from impactsense.commands.train import parse_exclude

    with pytest.raises(DataError, match="CAL.json"):
        parse_exclude(str(tmp_path / "CAL.json"))
