"""`impactsense diagnose` and `retrain` from the command line: the JSON schema of issue 5, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from impactsense.cli import main
from impactsense.data import load_session, write_session


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    s = load_session("bundled:session-1")
    rows = np.flatnonzero(s.case_id < 60)
    path = tmp_path_factory.mktemp("d") / "s1-small"
    write_session(path, s.rig, s.x_mm[rows], s.y_mm[rows], s.height_mm[rows], s.adc[rows],
                  s.case_id[rows], s.repetition[rows])
    return path


def test_diagnose_json_schema_and_report(small, tmp_path, capsys):
    out = tmp_path / "d.json"
    assert main(["diagnose", "--baseline", str(small), "--data", str(small), "--json", str(out),
                 "--report", str(tmp_path / "rep")]) == 0
    r = json.loads(out.read_text())
    assert {"effects", "before", "after"} <= set(r)
    for part in ("before", "after"):
        assert set(r[part]) >= {"mae_mm", "dtoa_rms_us", "energy_rms"}
        assert all(np.isfinite(v) for v in r[part].values())
    names = {"channel_delay", "sensor_gain", "sensor_position", "channel_lowpass", "wave_speed", "damping",
             "anisotropy", "noise", "clipping", "none"}
    scores = [e["score"] for e in r["effects"] if e["significant"]]
    assert scores == sorted(scores, reverse=True)
    for e in r["effects"]:
        assert e["effect"] in names and set(e) >= {"effect", "sensor", "params", "score", "significant"}
        assert e["sensor"] is None or e["sensor"] in range(4)
    assert (tmp_path / "rep" / "summary.md").is_file()
    assert (tmp_path / "rep" / "dtoa_residual_map_before.png").is_file()
    page = (tmp_path / "rep" / "report.html").read_text()   # one self-contained page: the figures inside
    assert page.count("data:image/png;base64,") == 4 and "Tried and rejected" in page and "src='http" not in page
    assert "before" in capsys.readouterr().out


def test_diagnose_bad_input_is_a_clear_error(tmp_path, capsys):
    rc = main(["diagnose", "--baseline", str(tmp_path / "missing"), "--data", "bundled",
               "--json", str(tmp_path / "x.json")])
    assert rc == 2
    assert "missing" in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists()


def test_retrain_bad_fraction(small, tmp_path, capsys):
    rc = main(["retrain", "--baseline", str(small), "--data", str(small), "--out", str(tmp_path / "m"),
               "--test-fraction", "1.5"])
    assert rc == 2 and "test-fraction" in capsys.readouterr().err
