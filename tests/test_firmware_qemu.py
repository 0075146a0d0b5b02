"""The portable firmware cross-compiled for the Cortex-M4F and run on qemu (mps2-an386): the bare-metal
image processes recorded drops and checks its reports, features and model outputs against the host's, with
the energy class on the twin's site map as the board sees it (a coarse 20 mm map here, to keep it quick)."""

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(
    not (shutil.which("arm-none-eabi-gcc") and shutil.which("qemu-system-arm")),
    reason="needs gcc-arm-none-eabi, libnewlib-arm-none-eabi and qemu-system-arm (scripts/setup-debian.sh)")


def test_qemu_image_compiles_with_the_boards_flags(tmp_path):
    """The instructions timed on qemu (the 64,000 budget) are the board's: the image uses the float ABI that
    platformio.ini gives the board and the optimisation level our libraries set in their library.json."""
    p = subprocess.run(["make", "-s", "-f", str(ROOT / "firmware/test/qemu/Makefile"), f"BUILD={tmp_path}",
                        "--eval", "print-%: ; @echo $($*)", "print-COMMON"], capture_output=True, text=True,
                       timeout=60, env={k: v for k, v in os.environ.items() if k != "OPT"})
    assert p.returncode == 0, p.stderr
    qemu_flags = p.stdout.split()
    board_abi = re.search(r"^build_flags\s*=.*?(-mfloat-abi=\w+)", (ROOT / "platformio.ini").read_text(), re.M).group(1)
    assert board_abi in qemu_flags and "-mfpu=fpv4-sp-d16" in qemu_flags
    for lib in ("impactcore", "impactlink", "impactapp"):
        flags = json.loads((ROOT / "firmware/lib" / lib / "library.json").read_text())["build"]["flags"]
        assert [f for f in flags if f.startswith("-O")] == [f for f in qemu_flags if f.startswith("-O")], lib


def test_qemu_image_matches_host(tmp_path):
    p = subprocess.run([str(ROOT / "firmware/test/qemu/run.sh"), str(tmp_path), "--drops", "6", "--trees", "8",
                        "--site-map-step", "20"],
                       capture_output=True, text=True, timeout=600, env=dict(os.environ, QEMU_EXTRA="", PYTHON=sys.executable))
    out = p.stdout + p.stderr
    assert p.returncode == 0, out
    assert "FAILURES 0" in out
    # arm-none-eabi-size was printed for the libraries and the image
    assert re.search(r"\(TOTALS\)", out) and "test.elf" in out
    assert not re.search(r"FAIL \w", out)
    assert re.search(r"^DROP twin_points [1-9]", out, re.M)  # the twin ran on the board's events
    # a drop the board cannot report says why (the report's reason): two dead channels, every channel clipped
    assert "REJECT channels_missing: two or more channels without an onset" in out
    assert "REJECT clipped: every channel with an onset clipped" in out
    assert "impactsense_twin_map" in (tmp_path / "models" / "impactsense_forest_tables.c").read_text()


def test_qemu_image_reports_every_drop_of_a_short_record_16_bit_logger(tmp_path, session1):
    """A 16-bit logger's 8 ms records with 30 samples before the hit (test_board_short_records): the image's app
    reports every fixture drop once, as the fixture's native app did (gen_fixture replays board_frames and writes
    the rig's rails and trigger counts for the image's app). It used to stop at "not one report from the native
    app", and then the image cut other captures than the fixture's (the board's 12-bit defaults)."""
    import numpy as np
    from test_board_short_records import sixteen_bit_short_records

    short = sixteen_bit_short_records(session1, np.arange(0, 771, 8), tmp_path)
    p = subprocess.run([str(ROOT / "firmware/test/qemu/run.sh"), str(tmp_path / "build"), "--data", str(short.path),
                        "--drops", "8", "--trees", "4", "--site-map", "none"],
                       capture_output=True, text=True, timeout=900, env=dict(os.environ, QEMU_EXTRA="", PYTHON=sys.executable))
    out = p.stdout + p.stderr
    assert p.returncode == 0, out
    assert "FAILURES 0" in out and not re.search(r"FAIL \w", out)
    fixture = json.loads((tmp_path / "build" / "fixture.json").read_text())
    assert len(fixture["rows"]) == 8 and not fixture["skipped_rows"], fixture


def _run_image_on(tmp_path, s, name, model):
    """The qemu image on 4 drops of session s (written to tmp_path / name) with model's first 4 trees; asserts it
    ran and every check passed, returns its output."""
    from impactsense.data import write_session

    data = write_session(tmp_path / name, s.rig.to_dict(), s.x_mm, s.y_mm, s.height_mm, s.adc, s.case_id,
                         s.repetition)
    p = subprocess.run([str(ROOT / "firmware/test/qemu/run.sh"), str(tmp_path / "build"), "--data", str(data),
                        "--model-dir", str(model), "--trees", "4", "--drops", "4"],
                       capture_output=True, text=True, timeout=600, env=dict(os.environ, QEMU_EXTRA="", PYTHON=sys.executable))
    out = p.stdout + p.stderr
    assert p.returncode == 0, out
    assert "FAILURES 0" in out and not re.search(r"FAIL \w", out)
    return out


def test_qemu_image_checks_the_models_on_a_session_with_a_debonded_channel(tmp_path, session1):
    """A model trained on healthy sensors, a session whose channel 2 came loose (debonded: x0.4 through a 3..5 kHz
    low-pass): the twin cannot explain that channel's energies and twin_match leaves it out (its three-sensor
    positions). The image's models check then compares the board's answer with what the host serves for those drops
    (ImpactModel.predict) and names the same channel; the fixture's reference used to be compared with the models
    run without the localiser's geometry, and every such drop failed "table x/y vs sklearn"."""
    import numpy as np

    from impactsense.board.models import board_site_map, train_board_models
    from impactsense.faults import FaultSpec, inject_session
    from impactsense.sitemap import resolve_site_map

    debonded = 2
    clean = session1.subset(np.arange(0, len(session1), 4))
    board_map = board_site_map(resolve_site_map("auto", clean.rig), clean.rig, 50000, step_mm=20,
                               cache=tmp_path / "map.npz", progress=False)
    model = train_board_models(clean, tmp_path / "model", n_trees=4, site_map=board_map)
    s = inject_session(session1.subset(np.arange(1, len(session1), 97)), FaultSpec(debond=debonded, seed=0))
    out = _run_image_on(tmp_path, s, "debonded", model)
    left_out = [int(v) for v in re.findall(r"^DROP left_out (\d+)$", out, re.M)]
    assert len(left_out) >= 3 and left_out.count(debonded) >= len(left_out) - 1, left_out


def test_qemu_image_corrects_a_four_channel_models_three_sensor_position_as_the_host(tmp_path, session1):
    """A four-channel model without a twin (what `impactsense train` + `export` ship) carries per channel the pair
    correcting the three-sensor position (board.models.board_three_positions); on a session whose channel 2 is dead
    the image's TableModels::predict_event reports the corrected position the host serves (ImpactModel.predict,
    its three-sensor path) and names channel 2, and the correction moved the drops off the plain physics position."""
    import numpy as np

    from impactsense.board.models import train_board_models
    from impactsense.faults import FaultSpec, inject_session

    dead = 2
    clean = session1.subset(np.arange(0, len(session1), 3))
    model = train_board_models(clean, tmp_path / "model", n_trees=4)
    card = json.loads((model / "model_card.json").read_text())
    assert card["board_three_position"]["channels"][str(dead)]["kept"]
    s = inject_session(session1.subset(np.arange(1, len(session1), 97)), FaultSpec(dead_channel=dead, noise=1, seed=0))
    out = _run_image_on(tmp_path, s, "dead", model)
    assert "impactsense_model_position_without" in (tmp_path / "build" / "models" / "impactsense_forest_tables.c").read_text()
    left_out = [int(v) for v in re.findall(r"^DROP left_out (-?\d+)$", out, re.M)]
    assert len(left_out) >= 3 and all(c == dead for c in left_out), left_out
