"""The record's span after the first arrival against the far arrivals (record_window.py): geometry, physics and
what `info` says on a record cut short."""

import json
import numpy as np
import pytest

from impactsense.data import rig_from_dict
from impactsense.record_window import longest_path_difference_mm, slowest_velocity_mm_per_us, window_check


def _rig(session1, **over):
    raw = dict(session1.rig.raw, **over)
    return rig_from_dict(raw)


def _corners(x, y, inset):
    xy = [(inset, inset), (x - inset, y - inset), (x - inset, inset), (inset, y - inset)]   # not in geometric order
    return [{"name": f"S{k + 1}", "channel": k, "x_mm": float(a), "y_mm": float(b)} for k, (a, b) in enumerate(xy)]


def test_path_difference_is_the_geometry(session1):
    # sensors at the plate's corners: the largest difference is at a corner, the plate's diagonal
    rig = _rig(session1, plate_x_mm=400.0, plate_y_mm=300.0, sensors=_corners(400, 300, 0.0))
    assert longest_path_difference_mm(rig) == pytest.approx(500.0, abs=0.5)
    # moved in by 100 mm on a 1200 x 800 plate: a corner is 141 mm from its sensor, ~1305 from the opposite one
    rig = _rig(session1, plate_x_mm=1200.0, plate_y_mm=800.0, sensors=_corners(1200, 800, 100.0))
    far = np.hypot(1100, 700) - np.hypot(100, 100)
    assert longest_path_difference_mm(rig) == pytest.approx(far, rel=0.01)


def test_velocity_follows_the_flexural_law(session1):
    # thin (Kirchhoff): v ~ sqrt(h) at one frequency, so 4x the thickness nearly doubles it; thicker, the shear
    # deformation and rotary inertia (Mindlin) hold it back more and more: the shear wave speed caps it
    v = {h: slowest_velocity_mm_per_us(_rig(session1, thickness_mm=h)) for h in (0.5, 2.0, 6.0, 24.0)}
    assert v[2.0] / v[0.5] == pytest.approx(2.0, rel=0.05)
    assert v[24.0] / v[6.0] < 0.8 * v[2.0] / v[0.5]


def test_short_record_is_said(session1):
    rig = _rig(session1, plate_x_mm=1200.0, plate_y_mm=800.0, thickness_mm=1.5, sensors=_corners(1200, 800, 100.0),
               fs_hz=50000, samples=4096)
    need = window_check(rig, 4096, 1024)
    assert not need["short"] and need["after_first_arrival_ms"] == pytest.approx(3072 / 50.0)
    cut = int(1024 + 0.5 * need["far_arrival_ms"] * 50)   # half the span the far arrivals need
    assert window_check(rig, cut, 1024)["short"]
    assert not window_check(rig, cut, None)["short"]        # unknown first arrival: nothing claimed
    from impactsense.signal import CORE_MAX_SAMPLES, QUIET_KEPT_MIN_SAMPLES

    # what the core reads of a longer record: CORE_MAX_SAMPLES from QUIET_KEPT_MIN_SAMPLES before the first
    # arrival (1 ms at 50 kHz is fewer), so all but that quiet start lies after the first arrival
    longer = window_check(rig, 4 * CORE_MAX_SAMPLES, 1024)
    assert longer["after_first_arrival_ms"] == pytest.approx((CORE_MAX_SAMPLES - QUIET_KEPT_MIN_SAMPLES) / 50.0)
    kept_whole = window_check(rig, 4 * CORE_MAX_SAMPLES, 100)  # less quiet start than that: read from sample 0
    assert kept_whole["after_first_arrival_ms"] == pytest.approx((CORE_MAX_SAMPLES - 100) / 50.0)


def test_info_says_a_cut_record_is_short(tmp_path, session1, capsys):
    """`info` on the bundled session cut 0.3 ms after its first arrival (its quiet start doubled, a record keeps
    at least 256 samples): the record line says SHORT (before, only channels read as dead or without an onset)."""
    from impactsense.cli import main

    quiet = session1.rig.pretrigger_samples - 10
    cut = int(session1.rig.pretrigger_samples + 0.3e-3 * session1.rig.fs_hz)
    rows = np.arange(0, len(session1), 40)
    adc = np.concatenate([session1.adc[rows, :, :quiet], session1.adc[rows, :, :cut]], axis=2)
    n, pre = adc.shape[2], quiet + session1.rig.pretrigger_samples
    folder = tmp_path / "cut"
    folder.mkdir()
    (folder / "rig.json").write_text(json.dumps(dict(session1.rig.raw, samples=n, pretrigger_samples=int(pre))))
    lines = (session1.path / "impacts.csv").read_text().splitlines()
    head = lines[0].split(",")
    out = [lines[0]]
    for k, r in enumerate(rows):
        cells = lines[1 + r].split(",")
        cells[head.index("recording_id")] = str(k)
        out.append(",".join(cells))
    (folder / "impacts.csv").write_text("\n".join(out) + "\n")
    np.savez_compressed(folder / "recordings.npz", adc=adc)
    assert main(["info", str(folder), "--json", str(tmp_path / "i.json")]) == 0
    assert "SHORT" in capsys.readouterr().out
    summary = json.loads((tmp_path / "i.json").read_text())
    assert summary["record_window"]["short"]
    assert main(["info", "bundled"]) == 0
    full = capsys.readouterr().out
    assert "record after the first arrival" in full and "SHORT" not in full
