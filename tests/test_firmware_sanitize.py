"""The portable firmware (core + app + codec) under AddressSanitizer and UndefinedBehaviorSanitizer over the
recordings at the board rate, with models whose energy class reads the twin's site map (a coarse board map)."""

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from impactsense.data import load_session
from impactsense.export import export_models
from impactsense.board.capture import board_samples

ROOT = Path(__file__).resolve().parents[1]
CXX = shutil.which("g++") or shutil.which("c++")


def build_and_run(tmp_path, rows, board_map, n_trees=5, data=None):
    from impactsense.board.models import train_board_models

    s = load_session()
    model_dir = train_board_models(s.subset(np.arange(0, len(s), 3)), tmp_path / "model", n_trees=n_trees,
                                   site_map=board_map)
    export_models(model_dir, tmp_path / "models", write_m2cgen=False)
    sub = load_session(data).subset(rows)
    frames = board_samples(sub.adc, sub.rig.fs_hz, 50000)
    (tmp_path / "frames.bin").write_bytes(frames.tobytes())
    lib = ROOT / "firmware/lib"
    srcs = [*sorted((lib / "impactcore/src").glob("*.cpp")), lib / "impactlink/src/impactlink.cpp",
            *sorted((lib / "impactapp/src").glob("*.cpp")), ROOT / "firmware/test/native/sanitize_main.cpp"]
    exe = tmp_path / "sanitize"
    subprocess.run(["gcc", "-c", "-O1", "-g", "-fsanitize=address,undefined", f"-I{tmp_path / 'models'}",
                    str(tmp_path / "models/impactsense_forest_tables.c"), "-o", str(tmp_path / "tables.o")],
                   check=True)
    subprocess.run([CXX, "-std=c++17", "-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                    "-fno-omit-frame-pointer", *(f"-I{lib / d / 'src'}" for d in ("impactcore", "impactlink", "impactapp")),
                    f"-I{tmp_path / 'models'}", *map(str, srcs), str(tmp_path / "tables.o"), "-o", str(exe)],
                   check=True)
    p = subprocess.run([str(exe), str(tmp_path / "frames.bin"), str(frames.shape[0]), str(frames.shape[1])],
                       capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "runtime error" not in p.stderr and "AddressSanitizer" not in p.stderr
    out = p.stdout.split()
    assert out[out.index("twin") + 1] == "1"  # the energy class ran on the twin's estimate ...
    assert int(out[out.index("valid") + 1]) >= 0.9 * int(out[1])  # ... on (nearly) every report
    return int(out[1])


@pytest.mark.skipif(CXX is None, reason="no host C++ compiler")
def test_sanitizers_on_some_drops(tmp_path, board_site_map_20mm):
    assert build_and_run(tmp_path, np.arange(0, 771, 40), board_site_map_20mm) == 20


@pytest.mark.slow
@pytest.mark.skipif(CXX is None, reason="no host C++ compiler")
def test_sanitizers_on_all_recordings(tmp_path, board_site_map_20mm):
    from impactsense.data import bundled_session_path

    for name in ("session-1", "session-2"):
        path = bundled_session_path(name)
        n = len(load_session(path))
        assert build_and_run(tmp_path / name, np.arange(n), board_site_map_20mm, data=path) == n
