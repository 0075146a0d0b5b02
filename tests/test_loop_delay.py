"""A diagnosed channel delay is the retrained model's, not its training recordings' (impactsense.loop): the
training data keeps DATA_REF's samples, and the model's picks take the delay out (rig_delay_us and the band
picks' band_delay_us), as the core takes out any rig delay. Checked with a delay of whole samples, where a
shift of the recordings is exact: the picks of the delayed recordings with the delay carried equal the picks of
the recordings as they were."""

from __future__ import annotations

import numpy as np
import pytest

from impactsense import diagnose as D
from impactsense import residuals as R
from impactsense.data import load_session
from impactsense.loop import channel_delays, measured_training_session, recorded_effects, with_channel_delays
from impactsense.pipeline import featurize
from impactsense.signal import SignalConfig


def _delay(sensor, us):
    return D.Candidate("channel_delay", sensor, {"delay_us": us}, 50.0, 0.0, True, True, [])


def test_a_delay_is_carried_by_the_picks_not_put_into_the_recordings(tmp_path):
    base = load_session("bundled:session-1").subset(np.arange(12))
    ref = R.fit_reference(R.extract(base))
    gain = D.Candidate("sensor_gain", 0, {"gain": 0.8}, 10.0, 0.0, True, True, [])
    effects = [_delay(2, -6.6), gain, _delay(2, 1.1)]
    assert recorded_effects(effects) == [gain]
    assert channel_delays(effects) == pytest.approx([0.0, 0.0, -5.5, 0.0])
    out = measured_training_session(base, [_delay(2, -6.6)], ref, tmp_path / "delay")
    assert np.array_equal(out.adc, base.adc)   # a delay alone: DATA_REF's samples as they were
    with_gain = measured_training_session(base, effects, ref, tmp_path / "gain")
    assert not np.array_equal(with_gain.adc[:, 0], base.adc[:, 0])   # the gain is still put in
    assert np.array_equal(with_gain.adc[:, 2], base.adc[:, 2])       # ... the delayed channel untouched


def test_the_carried_delay_gives_the_undelayed_picks_back():
    base = load_session("bundled:session-1").subset(np.arange(0, 240, 12))
    cfg = SignalConfig.for_rig(base.rig, band_pick_hz=20000.0)
    k = 3                                    # whole samples: the shift of the recordings is the analogue delay
    delay_us = k * 1e6 / float(base.rig.fs_hz)
    late = np.array(base.adc)
    late[:, 1, k:] = base.adc[:, 1, :-k]
    late[:, 1, :k] = base.adc[:, 1, :1]
    carried = with_channel_delays(cfg, [0.0, delay_us, 0.0, 0.0])
    assert carried.rig_delay_us[1] == pytest.approx(cfg.rig_delay_us[1] + delay_us)
    assert carried.band_delay_us[1] == pytest.approx(cfg.band_delay_us[1] + delay_us)
    assert with_channel_delays(cfg, [0.0] * 4) is cfg
    plain, moved, fixed = (featurize(a, c) for a, c in ((base.adc, cfg), (late, cfg), (late, carried)))
    ok = np.isfinite(plain.toa_us[:, 1])
    assert ok.sum() >= 15
    # not carried: channel 1 reads the delay late; carried: the picks as before the delay (the other channels too)
    assert np.median(moved.toa_us[ok, 1] - plain.toa_us[ok, 1]) == pytest.approx(delay_us, abs=0.5)
    # (within a twentieth of a sample: the record's start and end move with the shift, the baseline's hum fit too)
    assert np.abs(fixed.toa_us[ok] - plain.toa_us[ok]).max() < 0.5
    assert np.nanmax(np.abs(fixed.phys_xy_mm - plain.phys_xy_mm)) < 0.5


def test_the_moved_rig_is_a_retrain_option_off_by_default():
    """`retrain --moved-rig` (was the module constant loop.RIG_CARRIES_MOVE, which nobody could set)."""
    import impactsense.loop as L
    from impactsense.cli import build_parser

    parse = build_parser().parse_args
    common = ["retrain", "--baseline", "A", "--data", "B", "--out", "C"]
    assert parse(common).moved_rig is False and parse(common + ["--moved-rig"]).moved_rig is True
    assert not hasattr(L, "RIG_CARRIES_MOVE")
