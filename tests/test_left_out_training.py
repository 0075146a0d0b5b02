"""Training with a channel left out (the core's channel_left_out, which gives that channel no onset by design):
the travel fit, the onset threshold's choice and the usable drops count only the channels in use, and the
forests read none of the left-out channel's arrival times."""

from dataclasses import replace

import numpy as np
import pytest

from impactsense.commands.retrain import leave_out
from impactsense.errors import DataError
from impactsense.models import ForestSettings
from impactsense.pipeline import FEATURE_NAMES, featurize, onset_columns
from impactsense.signal import SignalConfig
from impactsense.travel import fit_travel, travel_distances
from impactsense.workflow import train

SENSORS = np.array([[50.0, 45.0], [400.0, 55.0], [395.0, 300.0], [60.0, 290.0]])


def synthetic_toa(left_out_channel: int, delays, v=1.7, n=200, seed=4):
    """The travel model's own ToAs (0.5 us pick noise) with one channel without an onset (NaN)."""
    rng = np.random.default_rng(seed)
    xy = np.c_[rng.uniform(10, 440, n), rng.uniform(10, 340, n)]
    toa = rng.uniform(900, 1100, (n, 1)) + travel_distances(xy, SENSORS) / v + np.asarray(delays)[None]
    toa = toa + rng.normal(0, 0.5, toa.shape)
    toa[:, left_out_channel] = np.nan
    return toa, xy


@pytest.mark.parametrize("channel", [0, 2])
def test_fit_travel_with_a_channel_left_out_recovers_the_other_channels(channel):
    """Three channels determine the velocity and their delays relative to each other (the first channel in
    use is the reference; 0.3 us is ~4 sd of a delay fitted from 200 drops at 0.5 us noise); the left-out
    channel's delay is 0. Without the channel left out the same picks have no drop with every onset."""
    delays = np.array([0.0, -2.0, 4.0, 1.5])
    toa, xy = synthetic_toa(channel, delays)
    flags = [int(c == channel) for c in range(4)]
    fit = fit_travel(toa, xy, SENSORS, anisotropic=False, left_out=flags)
    use = np.array(flags) == 0
    first = int(np.flatnonzero(use)[0])
    assert fit.velocity_mm_per_us == pytest.approx(1.7, rel=0.01)
    assert fit.delays_us[channel] == 0.0
    assert np.allclose(np.asarray(fit.delays_us)[use], (delays - delays[first])[use], atol=0.3)
    with pytest.raises(DataError, match="every channel in use"):
        fit_travel(toa, xy, SENSORS, anisotropic=False)


def test_two_channels_in_use_are_a_clear_error():
    toa, xy = synthetic_toa(1, [0.0] * 4)
    with pytest.raises(DataError, match="need 3"):
        fit_travel(toa, xy, SENSORS, anisotropic=False, left_out=[0, 1, 1, 0])


@pytest.fixture(scope="module")
def left_out_models(session1):
    """Four-channel and channel-2-left-out models on half of session-1 (10 trees, the same split)."""
    sub = session1.subset(np.arange(0, len(session1), 2))
    settings = ForestSettings(n_estimators=10, seed=0)
    four, split = train(sub, None, 0.3, 0, None, settings=settings, site_map=None)
    sig = leave_out(SignalConfig.for_rig(sub.rig), [2])
    three, split3 = train(sub, None, 0.3, 0, None, settings=settings, signal=sig, site_map=None)
    assert split3["test_recordings"] == split["test_recordings"]
    test = sub.subset(np.flatnonzero(np.isin(sub.recording_id, split["test_recordings"])))
    return four, three, test


def held_out_mae(model, test) -> tuple[float, dict]:
    out = model.predict(featurize(test.adc, model.signal))
    return float(np.mean(np.abs(out["xy_mm"] - test.xy_mm))), out


def test_a_model_trained_with_a_channel_left_out_reads_the_other_three(left_out_models):
    """The threshold is chosen and the travel fitted on three channels; the forests read no arrival time of the
    left-out channel and run on every held-out drop (not the three-sensor physics fallback). Their correction is
    scaled by its out-of-fold choice (correction_scale), so the held-out MAE is not above the fallback's (the
    four-channel model told to leave the channel out at prediction: the three-sensor physics position) beyond
    5 %, and within 2 x the four-channel model's (one of four arrival times fewer). On half of session-1 the
    three-sensor forests add little: 3.72 mm and 3.72 for the fallback, 2.25 with four channels."""
    four, three, test = left_out_models
    assert three.signal.channel_left_out == [0, 0, 1, 0]
    assert three.signal.rig_delay_us[2] == 0.0
    assert not set(onset_columns(2, FEATURE_NAMES)) & set(three.location_features)
    assert {"dtoa_01_us", "dtoa_13_us", "rel_toa_1_us"} <= set(three.location_features)
    mae3, out = held_out_mae(three, test)
    assert np.isfinite(out["xy_mm"]).all() and not out["three_channel"].any()
    mae4, _ = held_out_mae(four, test)
    fallback, _ = held_out_mae(replace(four, signal=leave_out(four.signal, [2])), test)
    print(f"held-out MAE: four {mae4:.2f}, three-trained {mae3:.2f}, left out at prediction {fallback:.2f} mm")
    assert mae3 <= 1.05 * fallback and mae3 < 2.0 * mae4


def test_a_four_channel_model_with_the_channel_left_out_after_training_keeps_the_physics_answer(left_out_models):
    """A model trained on four channels and told to leave one out (retrain's unabsorbed channel, the board's
    left-out export) does not feed its forests a NaN arrival time: the three-sensor physics position, corrected
    by the host's pair for that channel out (three_channel_position.py; the board's models have none)."""
    from impactsense.three_channel_position import corrected_positions

    four, _, test = left_out_models
    left = replace(four, signal=leave_out(four.signal, [2]))
    f = featurize(test.adc, left.signal)
    out = left.predict(f)
    assert out["three_channel"].all() and 2 in four.three_channel_position
    assert np.allclose(replace(left, three_channel_position={}).predict(f)["xy_mm"], f.phys_xy_mm, equal_nan=True)
    want = np.array(f.phys_xy_mm, float)
    corrected_positions(four.three_channel_position, f.vector, np.arange(len(f)), np.full(len(f), 2), want)
    assert np.isfinite(out["xy_mm"]).all() and np.allclose(out["xy_mm"], want)


def test_a_model_trained_with_a_channel_left_out_saves_and_loads(left_out_models, tmp_path):
    """The card keeps the three-channel location features (and the members they need); the loaded model
    predicts what the trained one does."""
    from impactsense.models import ImpactModel

    _, three, test = left_out_models
    three.save(tmp_path / "m")
    loaded = ImpactModel.load(tmp_path / "m")
    assert loaded.location_features == three.location_features
    assert loaded.members.keys() == three.members.keys()
    f = featurize(test.adc, three.signal)
    assert np.allclose(loaded.predict(f)["xy_mm"], three.predict(f)["xy_mm"], atol=1e-6)


def test_a_left_out_models_class_does_not_read_the_left_out_channel(left_out_models):
    """The class of a model trained with a channel left out is the three-channel one (the other three channels'
    energies; three_channel_position.left_out_class, as the board's TableModels): the same drops with that channel
    dead (its disc silent: its whole-record energy gone) keep their classes (one drop in 30 may cross: the
    three-channel position it reads moves with the noise) and still get the forests' position."""
    from impactsense.faults import FaultSpec, inject_session
    from impactsense.height_class import three_channel_inputs

    _, three, test = left_out_models
    f = featurize(test.adc, three.signal)
    dead = featurize(inject_session(test, FaultSpec(dead_channel=2, noise=1, seed=1)).adc, three.signal)
    out, out_dead = three.predict(f), three.predict(dead)
    want = three.three_channel_class[2].predict(three_channel_inputs(f.raw, f.phys_xy_mm, 2))
    np.testing.assert_array_equal(out["energy_class"], want)
    assert np.mean(out_dead["energy_class"] == out["energy_class"]) >= 0.97
    assert np.isfinite(out_dead["xy_mm"]).all()
