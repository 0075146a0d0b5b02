"""A drop the channel check flags keeps the four channels' position on a channel whose three other sensors lie
nearly on one line (flagged_position.py): the training drops, debonded there, say so out of fold; on a layout
whose every three sensors surround the plate the three-sensor path stays, as before."""

import numpy as np
import pytest

from impactsense.data import rig_from_dict
from impactsense.faults import FaultSpec, inject
from impactsense.flagged_position import choose_flagged_positions, keeps_four_channels
from impactsense.models import ForestSettings, ImpactModel
from impactsense.pipeline import featurize
from impactsense.signal import SignalConfig

# a long plate, sensor 3 inside the triangle of the other three: without sensor 2 (the apex) the three left lie
# within 50 mm of one line 480 mm long
SENSORS = [(60, 40), (540, 50), (300, 220), (330, 95)]


def _session(rig, cfg, synth, n_sites=60, reps=2, seed=0):
    """(adc, xy, heights) of decaying bursts arriving at each sensor after distance / the core's velocity, weaker with
    distance: a non-dispersive plate the core's localiser describes exactly."""
    rng = np.random.default_rng(seed)
    sxy = np.array([[s.x_mm, s.y_mm] for s in rig.sensors])
    xy, adc, h = [], [], []
    while len(xy) < n_sites * reps:
        p = rng.uniform((20, 20), (rig.plate_x_mm - 20, rig.plate_y_mm - 20))
        if np.hypot(*(sxy - p).T).min() < 25:
            continue
        height = rng.choice([100.0, 200.0])
        for _ in range(reps):
            d = np.hypot(*(sxy - p).T)
            onsets = 300 + d / cfg.velocity_mm_per_us * 1e-6 * rig.fs_hz
            chans = [synth([o] * 4, n=rig.samples, amp=6.0 * height * np.sqrt(60.0 / max(di, 60.0)), fs_hz=rig.fs_hz,
                           noise=1.5, seed=int(rng.integers(1 << 30)))[0] for o, di in zip(onsets, d)]   # per channel
            adc.append(np.stack(chans))
            xy.append(p + rng.normal(0, 0.5, 2))
            h.append(height)
    return np.array(adc, np.uint16), np.array(xy), np.array(h)


@pytest.fixture(scope="module")
def fitted(session1, synth):
    rig = rig_from_dict(dict(session1.rig.raw, plate_x_mm=600.0, plate_y_mm=260.0, samples=3000,
                             sensors=[{"name": f"S{k + 1}", "channel": k, "x_mm": float(x), "y_mm": float(y)}
                                      for k, (x, y) in enumerate(SENSORS)]))
    cfg = SignalConfig.for_rig(rig)
    adc, xy, h = _session(rig, cfg, synth)
    f = featurize(adc, cfg)
    model = ImpactModel.fit(f, xy, h, rig.ball_mass_g, cfg, ForestSettings(n_estimators=20),
                            members=False)
    return rig, cfg, model, adc, xy, synth


def test_the_nearly_collinear_channel_keeps_the_four_channel_position(fitted):
    rig, cfg, model, adc, xy, synth = fitted
    assert "channel_check" in model.card
    choose_flagged_positions(model, adc, xy, float(rig.fs_hz), float(rig.bias_counts), int(rig.adc_max))
    check = model.card["channel_check"]
    keep, record = check["three_sensor_position"], check["three_sensor_choice"]
    assert keep[2] is False, record[2]   # the apex: the other three within 50 mm of a line
    assert record[2]["three_sensor_mae_mm"] > 1.2 * record[2]["four_channel_mae_mm"]
    assert keep[3] is True, record[3]    # the inner sensor: the other three surround the plate
    # new drops with channel 2 debonded: flagged, placed by the four channels, nearer the truth than the
    # three-sensor position would be
    new_adc, new_xy, _ = _session(rig, cfg, synth, n_sites=30, reps=1, seed=5)
    deb = inject(new_adc, FaultSpec(debond=2, debond_hz=4000, seed=1), rig.fs_hz, rig.bias_counts, rig.adc_max)
    pred = model.predict(featurize(deb, cfg))
    on = pred["bad_channel"] == 2
    assert on.sum() >= 8   # the check flags most (the debond at 4 kHz on a 20 kHz burst)
    np.testing.assert_array_equal(pred["xy_mm"][on], pred["forest_xy_mm"][on])
    assert not pred["three_channel"][on].any() and np.all(pred["energy_class"][on] >= 0)
    check["three_sensor_position"] = [True] * 4   # as before: the three-sensor path
    before = model.predict(featurize(deb, cfg))
    err = lambda p: np.abs(p["xy_mm"][on] - new_xy[on]).mean()   # noqa: E731
    assert err(pred) < 0.5 * err(before)


def test_the_choice_reads_only_flagged_rows_of_a_channel_it_does_not_keep():
    check = {"three_sensor_position": [True, False, True, True]}
    np.testing.assert_array_equal(keeps_four_channels(check, np.array([-1, 0, 1, 2, 3, 1])),
                                  [False, False, True, False, False, True])
    assert not keeps_four_channels({}, np.array([1, 2])).any()   # a card from before: the three-sensor path


def test_evaluate_says_why_a_channel_keeps_four_channels():
    """evaluate's line for a flagged channel whose drops keep the four channels' position gives the card's
    measured reason (before: "the other three lie too near one line" whatever the layout, also where they span
    a wide triangle and the out-of-fold figures alone chose four)."""
    from impactsense.commands.evaluate import flagged_placement

    card = {"channel_check": {"three_sensor_position": [True, True, False, True],
                              "three_sensor_choice": [None, None, {"three_sensor_mae_mm": 27.06,
                                                                   "four_channel_mae_mm": 19.35, "gain_sigmas": 1.64},
                                                      None]}}
    text = flagged_placement(card, 2)
    assert "placed by all four" in text and "19.4" in text and "27.1" in text and "line" not in text
    assert flagged_placement(card, 0) == "placed and classified from the other three channels"
    assert flagged_placement({}, 1) == "placed and classified from the other three channels"
