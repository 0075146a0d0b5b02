"""The step-by-step zero-shot chain's bookkeeping: a virtual session remembers its calibration; evaluate scores
a sim-trained model on the calibrated session's drops but the calibration drops. (The chain's accuracy on the
bundled rig is measured by the chain itself (README "Zero-shot, step by step"), not here: it simulates
hundreds of drops; the slow tests/test_readme_commands.py runs it and holds the README's figures.)"""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from impactsense.chain import measured_session, record_calibration, session_calibration
from impactsense.data import load_session, write_session
from impactsense.errors import DataError
from impactsense.sitemap import BUNDLED
from impactsense.workflow import evaluation_rows

CAL = BUNDLED.parent / "calibration.json"


@pytest.fixture(scope="module")
def s1():
    return load_session()


def tiny_virtual(tmp_path, s1):
    return write_session(tmp_path / "V", s1.rig, [100.0, 200.0], [100.0, 150.0], [150.0, 150.0], s1.adc[:2])


def test_virtual_session_remembers_its_calibration(tmp_path, s1):
    v = tiny_virtual(tmp_path, s1)
    assert session_calibration(load_session(v)) is None
    record_calibration(v, CAL)
    path = session_calibration(load_session(v))
    kept = json.loads(path.read_text())
    assert kept["sim_params"] == json.loads(CAL.read_text())["sim_params"]
    assert kept["source"]["path"] == str(CAL.resolve())
    session, cal = measured_session(path)
    assert session.fingerprint() == s1.fingerprint() and cal["exclude_recording_ids"]


def test_a_changed_measured_session_is_named(tmp_path, s1):
    v = tiny_virtual(tmp_path, s1)
    path = record_calibration(v, CAL)
    cal = json.loads(path.read_text())
    cal["data_sha256"] = "0" * 64
    path.write_text(json.dumps(cal))
    with pytest.raises(DataError, match="data_sha256"):
        measured_session(path)


def test_sim_trained_model_is_scored_on_all_but_the_calibration_drops(s1):
    cal = json.loads(CAL.read_text())
    held = np.setdiff1d(np.arange(len(s1)), cal["exclude_recording_ids"])
    model = SimpleNamespace(card={"split": {"data_hash": "virtual"},
                                  "zero_shot": {"data_hash": s1.fingerprint(), "test_recordings": held.tolist()}})
    rows, scope = evaluation_rows(s1, model)
    assert np.array_equal(rows, held) and not np.isin(rows, cal["exclude_recording_ids"]).any()
    other = load_session("bundled:session-2")
    rows2, _ = evaluation_rows(other, model)
    assert rows2.size == len(other)
