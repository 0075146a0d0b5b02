"""The class-field study's measures (benchmarks/bench_class_field.py): the spacing of the training cases and
the length scale the learnt position field finds."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_class_field as study  # noqa: E402


def test_nearest_case_is_the_grid_spacing_whatever_the_repetitions():
    gx, gy = np.meshgrid(np.arange(0.0, 200.0, 25.0), np.arange(0.0, 150.0, 25.0))
    cases = np.c_[gx.ravel(), gy.ravel()]
    reps = np.repeat(np.arange(len(cases)), 3)                  # three drops a case
    assert study.nearest_case_mm(cases[reps], reps) == pytest.approx(25.0)


@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")   # noise: scale at its bound
def test_field_finds_the_scale_of_a_smooth_offset_and_not_of_white_noise():
    rng = np.random.default_rng(1)
    xy = rng.uniform(0.0, 300.0, (300, 2))
    smooth = 0.1 * np.sin(xy[:, 0] / 40.0) * np.cos(xy[:, 1] / 40.0)      # varies on ~40 mm
    gp = study.field(xy, smooth + rng.normal(0.0, 0.005, len(xy)))
    assert 20.0 < gp.kernel_.k1.k2.length_scale < 80.0
    # it predicts the offset between the drops it was fitted on
    probe = rng.uniform(20.0, 280.0, (50, 2))
    truth = 0.1 * np.sin(probe[:, 0] / 40.0) * np.cos(probe[:, 1] / 40.0)
    assert np.sqrt(np.mean((gp.predict(probe) - truth) ** 2)) < 0.02
    # pure noise: the fitted signal variance is small against the noise's, so the field predicts ~0
    noise = study.field(xy, rng.normal(0.0, 0.05, len(xy)))
    assert np.sqrt(np.mean(noise.predict(probe) ** 2)) < 0.02
