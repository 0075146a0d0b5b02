"""The effect library on its own: signal models do what their docstrings say, and each fit recovers a
known change of the features it reads (measured session-1 recordings, effect put in by apply_signal)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from impactsense import _core
from impactsense import residuals as R
from impactsense.data import load_session
from impactsense.effects import EFFECTS, context
from impactsense.effects._base import frac_shift
from impactsense.signal import core_config, settings


@pytest.fixture(scope="module")
def s1():
    s = load_session("bundled:session-1")
    return s.subset(np.arange(0, len(s), 3))   # 257 drops, every case


@pytest.fixture(scope="module")
def ref_and_features(s1):
    F = R.extract(s1)
    return R.fit_reference(F, "calibrated"), F


def test_frac_shift_matches_a_delayed_pulse():
    t = np.arange(400, dtype=float)
    pulse = lambda t0: np.exp(-0.5 * ((t - t0) / 6.0) ** 2) * np.sin(0.3 * (t - t0))
    out = frac_shift(pulse(150.0)[None], np.array([2.37]))[0]
    assert np.max(np.abs(out - pulse(152.37))) < 1e-6


def test_every_effect_has_units_meaning_and_candidates():
    assert set(EFFECTS) == {"channel_delay", "sensor_gain", "sensor_position", "channel_lowpass",
                            "wave_speed", "damping", "anisotropy", "noise", "clipping"}
    for e in EFFECTS.values():
        assert e.units and e.meaning and e.candidates()


@pytest.mark.parametrize("name,sensor,params,key,tol", [
    ("channel_delay", 1, {"delay_us": 20.0}, "delay_us", 1.5),     # two samples: exact picks
    ("sensor_gain", 2, {"gain": 0.6}, "gain", 0.04),
    ("wave_speed", None, {"change_pct": 5.0}, "change_pct", 1.0),
    ("noise", 0, {"white_rms_counts": 4.0, "hum_counts": 3.0, "hum_hz": 60.0}, "white_rms_counts", 0.4),
])
def test_fit_recovers_applied_change_circular(s1, ref_and_features, name, sensor, params, key, tol):
    ref, _ = ref_and_features
    eff = EFFECTS[name]
    ctx = context(s1, ref.slowness_us_per_mm)
    F = R.extract(replace(s1, adc=eff.apply_signal(s1.adc, sensor, params, ctx, rng=0)))
    got = eff.fit(ref, F, sensor)
    assert abs(got[key] - params[key]) <= tol, got
    # adding the fitted effect to the model raises the likelihood of the changed data
    assert eff.add(ref, sensor, got).ll(F).sum() > ref.ll(F).sum()


def test_clipping_rail_found_exactly_circular(s1, ref_and_features):
    ref, _ = ref_and_features
    eff = EFFECTS["clipping"]
    adc = eff.apply_signal(s1.adc, 2, {"rail_lo_counts": 1000.0, "rail_hi_counts": 3000.0}, context(s1))
    got = eff.fit(ref, R.extract(replace(s1, adc=adc)), 2)
    assert got["rail_hi_counts"] == 3000.0 and got["rail_lo_counts"] == 1000.0


def test_channel_delay_feeds_the_core_circular(s1, ref_and_features):
    """The fitted delay, given to CoreConfig.rig_delay_us, removes the channel's timing offset. (Circular: the
    effect's apply_signal makes the delay its fit reads; what it proves is the core's use of the fit.)"""
    ref, F = ref_and_features
    eff = EFFECTS["channel_delay"]
    adc = eff.apply_signal(s1.adc, 3, {"delay_us": 30.0}, context(s1))
    F2 = R.extract(replace(s1, adc=adc))
    got = eff.fit(ref, F2, 3)
    cfg = core_config(**eff.core_overrides(settings(s1.rig, **R.TIMING_PICKER), 3, got))
    toa = np.asarray(_core.extract_batch(np.ascontiguousarray(adc.astype(np.int16)), cfg)["toa_us"], float)
    shift = np.nanmedian(toa[:, 3] - F.toa_us[:, 3])
    assert abs(shift) <= 1.5


def test_diagnosed_effects_feed_core_and_recordings(s1, ref_and_features):
    from impactsense.effects.apply import apply_effects, core_config_with_effects

    ref, F = ref_and_features
    effects = [{"effect": "channel_delay", "sensor": 2, "params": {"delay_us": 20.0}, "significant": True},
               {"effect": "sensor_gain", "sensor": 0, "params": {"gain": 0.5}, "significant": False}]
    adc = apply_effects(s1.adc, effects, context(s1))
    F2 = R.extract(replace(s1, adc=adc))
    assert abs(np.nanmedian(F2.toa_us[:, 2] - F.toa_us[:, 2]) - 20.0) <= 1.0
    assert abs(np.nanmedian(F2.log_energy[:, 0] - F.log_energy[:, 0])) < 0.01   # not significant: not applied
    cfg = core_config_with_effects(s1.rig, effects, **R.TIMING_PICKER)
    assert list(cfg.rig_delay_us) == [0.0, 0.0, 20.0, 0.0]


def _ringing(n_rec, decay_per_s, fs=100_000.0, samples=5000, onset=200, seed=0):
    """Records of a decaying 3 kHz ring (amplitude 800 counts) starting at `onset`, bias removed."""
    rng = np.random.default_rng(seed)
    t = (np.arange(samples) - onset) / fs
    ring = 800.0 * np.exp(-decay_per_s * np.clip(t, 0, None)) * np.sin(2 * np.pi * 3000.0 * t) * (t >= 0)
    a = np.broadcast_to(ring, (n_rec, 4, samples)).copy()
    return a, np.full((n_rec, 4), float(onset)), rng


def test_hum_lock_in_reads_white_noise_by_its_gain():
    """The tail's lock-in reads white noise of variance v as v x hum_white_gain (its regressors span about a
    cycle of 50 Hz, so they are far from orthogonal): measured on pure noise, within 15 % (800 records x
    channels of a chi-square with 2 dof: 3.5 % standard error)."""
    fs, samples, sigma = 100_000.0, 5000, 5.0
    a = np.random.default_rng(1).normal(0.0, sigma, (200, 4, samples))
    _, _, hum = R.signal_features(a + 2048.0, np.full((200, 4), 100.0), fs, 2048.0)
    measured = (hum ** 2).mean(axis=(0, 1)) / sigma ** 2
    assert measured == pytest.approx(R.hum_white_gain(fs, samples), rel=0.15)


def test_decay_reads_the_signal_not_the_hum_or_noise():
    """The decay observable of a ring decaying at 600/s stays within 5 % of it with 30 counts of 50 Hz hum or
    with 6 counts of white noise on top (before the hum and noise power were taken out, they read as a
    slower decay: damping -49 % / -28 % on the loop's sessions)."""
    a, onset, rng = _ringing(40, 600.0)
    t = np.arange(a.shape[-1]) / 100_000.0
    clean = a + rng.normal(0.0, 1.5, a.shape)
    hum = clean + 30.0 * np.sin(2 * np.pi * 50.0 * t + rng.uniform(0, 2 * np.pi, (40, 1, 1)))
    noisy = a + rng.normal(0.0, 6.0, a.shape)
    for rec in (clean, hum, noisy):
        _, decay, _ = R.signal_features(rec + 2048.0, onset, 100_000.0, 2048.0)
        assert np.nanmedian(decay) == pytest.approx(600.0, rel=0.05)


def test_gain_carries_its_measured_pick_change(s1):
    """A threshold-crossing picker (the timing picker `site_reference.choose_picker` may choose) picks a weaker
    channel later: a gain of 0.6 on S2 reads as a ~13 us delay without the gain's measured pick change
    (`sensor_gain.gain_table`), ~1 us with it (the picks' own scatter between drops is several us)."""
    picker = {"onset_threshold_counts": 20.0, "aic_blend": 0.0}
    F = R.extract(s1, picker)
    ref = R.fit_reference(F, "calibrated")
    ref.probe = {"session": s1.subset(np.arange(0, len(s1), 4)), "picker": picker}
    gain, delay = EFFECTS["sensor_gain"], EFFECTS["channel_delay"]
    weaker = R.extract(replace(s1, adc=gain.apply_signal(s1.adc, 1, {"gain": 0.6}, context(s1))), picker)
    without = delay.fit(gain.add(replace(ref, probe=None), 1, {"gain": 0.6}), weaker, 1)["delay_us"]
    model = gain.add(ref, 1, {"gain": 0.6})
    left = delay.fit(model, weaker, 1)["delay_us"]
    assert without > 5.0, without
    assert model.pick_toa_us[1] > 0 and abs(left) < 0.25 * without, (left, without)
    assert not np.any(model.pick_toa_us[[0, 2, 3]]), model.pick_toa_us
