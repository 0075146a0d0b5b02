"""A channel diagnose flags as one the models cannot absorb has its timing left out (`Reference.timing_out`).

A debonded disc's threshold picks come late by an amount that grows with distance (tens to 150 us). Kept in the
per-drop centring, that misfit reaches the other three channels: each gets a residual that a move of its disc
or a delay fits, and diagnose named moves of 20-30 mm on two sensors that had not moved (docs/findings.md,
Session 26: fr4loop). With the flagged channel left out, the centring runs over the other three: their
residuals are those of the clean drops, the physics localiser and the DToA use the three, and a delay or a
move on the flagged channel is not kept (it would describe timing the retrained models do not use)."""

from __future__ import annotations

import numpy as np

from impactsense import diagnose as D
from impactsense import move_or_delay as MD
from impactsense import residuals as R
from impactsense.effects import EFFECTS

SENSORS = np.array([[30.0, 30.0], [270.0, 30.0], [270.0, 270.0], [30.0, 270.0]])
SLOWNESS = 1.0   # us/mm
SIGMA = {"timing": 2.0, "energy": 0.1, "spectrum": 0.1, "decay": 10.0, "noise": 0.1, "hum": 0.1}


def _features(late_per_mm: float = 0.0, seed: int = 0) -> R.Features:
    rng = np.random.default_rng(seed)
    case = np.repeat(np.arange(40), 3)
    xy = rng.uniform(40.0, 260.0, (40, 2))[case]
    d = np.hypot(xy[:, 0, None] - SENSORS[None, :, 0], xy[:, 1, None] - SENSORS[None, :, 1])
    toa = SLOWNESS * d + rng.normal(0.0, 2.0, d.shape)
    toa[:, 2] += late_per_mm * d[:, 2]          # channel 2 late, more so the farther the hit
    z = np.zeros((len(case), 4))
    return R.Features(x_mm=xy[:, 0], y_mm=xy[:, 1], height_mm=np.full(len(case), 150.0), case_id=case,
                      order=np.linspace(0, 1, len(case)), toa_us=toa + 20.0, log_energy=z, clipped=z.astype(bool),
                      log_centroid=z, decay_per_s=z, log_noise=z, hum_counts=np.zeros((len(case), 4, 2)),
                      plateau_hi=z - 1, plateau_lo=z - 1, sensor_xy_mm=SENSORS.copy(), plate_mm=(300.0, 300.0),
                      fs_hz=100e3, adc_max=4095)


def _ref(out=()) -> R.Reference:
    return R.Reference(sensor_xy_mm=SENSORS.copy(), slowness_us_per_mm=SLOWNESS, sigma=dict(SIGMA),
                       timing_out=tuple(out))


def test_the_other_channels_residuals_are_the_clean_drops_once_the_late_channel_is_out():
    clean, late = _features(0.0), _features(0.6)
    spread = _ref().toa_resid(late) - _ref().toa_resid(clean)
    assert np.sqrt(np.mean(spread[:, [0, 1, 3]] ** 2)) > 20.0      # the late channel's misfit, spread by the centring
    out = _ref([2]).toa_resid(late)
    assert np.all(out[:, 2] == 0.0)
    # over the three others the residual is the clean drops' own, centred over the three
    assert np.allclose(out, _ref([2]).toa_resid(clean), atol=1e-9)
    assert np.sqrt(np.mean(out[:, [0, 1, 3]] ** 2)) < 3.0


def test_no_move_is_fitted_on_another_disc_once_the_late_channel_is_out():
    late = _features(0.6)
    shadow = EFFECTS["sensor_position"].fit(_ref(), late, 0)["offset_mm"]
    kept = EFFECTS["sensor_position"].fit(_ref([2]), late, 0)["offset_mm"]
    assert shadow > 15.0, shadow           # a move of S1 that did not happen
    assert kept < 3.0, kept


def test_dtoa_and_the_localiser_use_the_channels_kept():
    late = _features(0.6)
    with_it, without = R.metrics(_ref(), late), R.metrics(_ref([2]), late)
    assert with_it["dtoa_rms_us"] > 30.0 and without["dtoa_rms_us"] < 5.0
    assert without["mae_mm"] < 0.5 * with_it["mae_mm"]
    assert R.metrics(_ref(), _features(0.0)) == R.metrics(R.Reference(sensor_xy_mm=SENSORS.copy(),
                                                                       slowness_us_per_mm=SLOWNESS,
                                                                       sigma=dict(SIGMA)), _features(0.0))


def test_a_delay_or_move_on_the_flagged_channel_is_not_kept_its_gain_and_low_pass_are():
    ref = _ref()
    acc = [D.Candidate(e, s, {"offset_mm": 5.0} if e == "sensor_position" else {}, 10.0, 0.01, True, True, [])
           for e, s in
           (("sensor_gain", 2), ("channel_delay", 2), ("channel_lowpass", 2), ("channel_delay", 1),
            ("sensor_position", 2), ("sensor_position", 0))]
    kept, flagged_now = MD.leave_out_flagged_timing(ref, acc, {2: {}})
    assert flagged_now and ref.timing_out == (2,)
    assert MD.leave_out_flagged_timing(ref, kept, {2: {}}) == (kept, False)   # once
    assert [(c.effect, c.sensor) for c in kept] == [("sensor_gain", 2), ("channel_lowpass", 2),
                                                     ("channel_delay", 1), ("sensor_position", 0)]


def test_the_clipping_group_is_the_plateaus_bernoulli_likelihood_and_finite_at_rate_zero():
    """A drop-channel shows a plateau off the rails with the reference's rate p: the group is sum(k log p +
    (n - k) log(1 - p)) per drop; a reference that saw none (p = 0) gives 0 for drops without one (0 log 0 = 0),
    -inf for a drop with one, never NaN."""
    F = _features()
    F.plateau_hi[:3, 1] = 2000.0                    # three drops with a plateau mid-range on channel 1
    ref = _ref()
    ref.rail_lo, ref.rail_hi = np.zeros(4), np.full(4, 4095.0)
    ref.plateau_rate = 0.1
    got = ref.ll_groups(F)["clipping"]
    assert np.allclose(got[:3], np.log(0.1) + 3 * np.log(0.9)) and np.allclose(got[3:], 4 * np.log(0.9))
    ref.plateau_rate = 0.0
    got = ref.ll_groups(F)["clipping"]
    assert not np.isnan(got).any()
    assert np.all(got[3:] == 0.0) and np.all(np.isneginf(got[:3]))
