"""The twin-directivity study's path geometry (benchmarks/bench_twin_directivity.py): a path's angle to the
material's first axis, whatever way the axis is turned."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_twin_directivity as study  # noqa: E402


def test_path_angle_to_the_fibres_and_length():
    sensors = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]])
    xy = np.array([[50.0, 0.0]])                        # on the line through sensors 0 and 1
    r, theta = study.path_geometry(xy, sensors, 0.0)
    assert np.allclose(r[0], [50.0, 50.0, np.hypot(50, 100), np.hypot(50, 100)])
    assert np.allclose(np.degrees(theta[0, :2]), 0.0)   # along the fibres, either way along the line
    assert np.allclose(np.degrees(theta[0, 2:]), np.degrees(np.arctan2(100.0, 50.0)))   # 63.4 deg off the axis
    _, turned = study.path_geometry(xy, sensors, 90.0)  # fibres along y: the same paths now run across them
    assert np.allclose(np.degrees(turned[0, :2]), 90.0)
