"""The sensor-line study's geometry (benchmarks/bench_sensor_lines.py): the distance to the lines through two
sensors and the TDOA dilution, which grows where the sensors' directions from the point stop spanning the plane."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_sensor_lines as study  # noqa: E402

SQUARE = np.array([[0.0, 0.0], [300.0, 0.0], [300.0, 300.0], [0.0, 300.0]])


def test_line_distance_is_the_nearest_of_the_six_lines():
    xy = np.array([[150.0, 10.0], [150.0, 150.0], [-40.0, 100.0], [100.0, 90.0]])
    # (150, 150) lies on both diagonals; (100, 90) is 10 mm from the diagonal y = x (10 / sqrt 2)
    assert np.allclose(study.line_distance(xy, SQUARE), [10.0, 0.0, 40.0, 10.0 / np.sqrt(2.0)])


def test_dilution_is_small_inside_and_grows_beyond_a_pair_along_its_line():
    d_centre, _ = study.dilution(np.array([[150.0, 150.0]]), SQUARE)
    d_out, worst = study.dilution(np.array([[150.0, -60.0], [150.0, -300.0]]), SQUARE)
    assert d_centre[0] < 1.5
    assert d_out[1] > d_out[0] > d_centre[0]                 # farther outside the square: less and less determined
    assert abs(worst[1, 1]) > 0.9                            # the poorly held direction is across the near side
    assert np.allclose(np.linalg.norm(worst, axis=1), 1.0)


def test_band_rows_split_the_error_between_physics_and_reported():
    rng = np.random.default_rng(0)
    t = rng.uniform(20.0, 280.0, (200, 2))
    arrays = {"true_xy": t, "phys_xy": t + 4.0, "pred_xy": t + 1.0, "case": np.arange(200), "sensors": SQUARE,
              "plate": np.array([300.0, 300.0])}
    r = study.band_rows(arrays)
    assert np.isclose(r["all"]["physics_mm"], 4.0) and np.isclose(r["all"]["reported_mm"], 1.0)
    line_bands = [v for k, v in r.items() if k.startswith("line")]
    assert sum(v["n"] for v in line_bands) == 200 and np.isclose(sum(v["share"] for v in line_bands), 1.0)


def test_neighbour_rows_tell_a_smooth_offset_field_from_a_site_own_one():
    g = np.stack(np.meshgrid(np.arange(20.0, 290.0, 25.0), np.arange(20.0, 290.0, 25.0)), -1).reshape(-1, 2)
    base = {"xy": g, "scatter": np.zeros(len(g)), "sensors": SQUARE, "plate": np.array([300.0, 300.0])}
    smooth = study.neighbour_rows({**base, "offset": np.stack([0.02 * g[:, 0], np.zeros(len(g))], 1)})
    rough = np.random.default_rng(2).normal(0.0, 5.0, g.shape)
    own = study.neighbour_rows({**base, "offset": rough})
    assert smooth["all"]["left_mm"] < 0.2 * smooth["all"]["offset_mm"]
    assert own["all"]["left_mm"] > own["all"]["offset_mm"]
