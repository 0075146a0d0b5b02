"""An effect's 95 % interval is never narrower than the grid its parameter is fitted on (diagnose._param_ci)."""

import numpy as np
from scipy import stats

from impactsense.diagnose import Candidate, _param_ci, _param_se
from impactsense.effects import EFFECTS
from impactsense.effects.channel_lowpass import REFINE_STEPS


def _cand(effect, sensor, value, key, folds):
    return Candidate(effect, sensor, {key: value}, 10.0, 0.01, True, True, [{key: v} for v in folds])


def test_a_grid_fit_whose_folds_agree_keeps_the_grids_step():
    # every fold on one node of the cut-off grid: the jackknife alone says zero width
    fc = 6915.0
    c = _cand("channel_lowpass", 1, fc, "fc_hz", [fc] * 5)
    se = _param_se(c)
    assert se["fc_hz"] == 0.0
    lo, hi = _param_ci(c, se)["fc_hz"]
    step = fc * (REFINE_STEPS[1] / REFINE_STEPS[0] - 1.0)
    assert lo < hi
    # the neighbouring refine nodes lie inside the interval, the value in its middle
    assert lo <= fc - step * (1 - 1e-9) and hi >= fc + step * (1 - 1e-9)
    assert np.isclose((lo + hi) / 2, fc)


def test_a_spread_of_fold_fits_sets_the_width_where_it_exceeds_the_step():
    fc = 5000.0
    folds = [4000.0, 4500.0, 5000.0, 5500.0, 6000.0]
    c = _cand("channel_lowpass", 0, fc, "fc_hz", folds)
    se = _param_se(c)
    lo, hi = _param_ci(c, se)["fc_hz"]
    assert hi - lo > 2 * fc * (REFINE_STEPS[1] / REFINE_STEPS[0] - 1.0)   # the jackknife's, not the floor
    # a continuous fit: the jackknife's interval as it was, t(0.975, 4) x its standard error each side
    c2 = _cand("channel_delay", 2, -6.0, "delay_us", [-6.0 + 0.3 * k for k in range(-2, 3)])
    se2 = _param_se(c2)["delay_us"]
    lo2, hi2 = _param_ci(c2, _param_se(c2))["delay_us"]
    assert np.isclose(hi2 - (-6.0), stats.t.ppf(0.975, 4) * se2) and np.isclose(-6.0 - lo2, hi2 + 6.0)


def test_continuous_fits_declare_no_grid():
    assert EFFECTS["channel_delay"].resolution({"delay_us": 1.0}) == {}
    assert EFFECTS["sensor_position"].resolution({"dx_mm": 1.0, "dy_mm": 0.0}) == {}
    assert EFFECTS["channel_lowpass"].resolution({"fc_hz": 1000.0})["fc_hz"] > 0


def test_an_amplitude_near_zero_keeps_its_interval_at_or_above_zero():
    """A white-noise session's hum amplitude of ~0.24 counts with fold fits 0..0.9 was reported [-0.73, +1.20]
    (seed-12 loop session): an amplitude's interval stays within its domain; one far from zero is as before."""
    c = _cand("noise", None, 0.24, "hum_counts", [0.0, 0.0, 0.9, 0.3, 0.0])
    se = _param_se(c)
    lo, hi = _param_ci(c, se)["hum_counts"]
    t = stats.t.ppf(0.975, 4)
    assert 0.24 - t * se["hum_counts"] < 0            # the jackknife alone reaches below zero
    assert lo == 0.0 and np.isclose(hi, 0.24 + t * se["hum_counts"])
    c2 = _cand("noise", None, 21.0, "hum_counts", [20.9, 21.0, 21.1, 21.05, 20.95])
    lo2, hi2 = _param_ci(c2, _param_se(c2))["hum_counts"]
    assert np.isclose(21.0 - lo2, hi2 - 21.0) and lo2 > 20.5
    # a parameter without a physical floor (a delay) may be read either side of zero
    c3 = _cand("channel_delay", 0, 0.2, "delay_us", [-0.5, 0.0, 0.2, 0.4, 0.9])
    assert _param_ci(c3, _param_se(c3))["delay_us"][0] < 0
    assert EFFECTS["noise"].bounds({})["white_rms_counts"][0] == 0.0 and EFFECTS["channel_delay"].bounds({}) == {}
