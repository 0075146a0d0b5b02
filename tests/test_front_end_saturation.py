"""A front end that saturates inside the ADC's rails (flat tops below full scale): where a session's recordings
hold them the core's clipping rails sit there (signal.saturation_counts; docs/findings.md "Session 27: newuser8")."""

from __future__ import annotations

from dataclasses import replace

import numpy as np


def _rig(**over):
    from impactsense.data import rig_from_dict

    raw = {"plate_material": "aluminium", "plate_x_mm": 500.0, "plate_y_mm": 400.0, "thickness_mm": 3.0,
           "density_kg_m3": 2700.0, "plate_support": "rubber feet",
           "sensors": [{"name": f"S{k + 1}", "channel": k, "x_mm": x, "y_mm": y}
                       for k, (x, y) in enumerate([(80, 60), (420, 70), (400, 330), (90, 340)])],
           "sensor_type": "PZT disc", "sensor_diameter_mm": 10.0, "ball_material": "steel",
           "ball_diameter_mm": 8.0, "ball_mass_g": 2.09, "channels": 4, "fs_hz": 100000, "samples": 2000,
           "adc_bits": 12, "vref": 3.3, "bias_counts": 2048}
    return rig_from_dict({**raw, **over})


def _drops(amplitude, rng, drops=12, n=2000, pre=200, bias=2048, swing=None, top=4095):
    """Decaying 8 kHz bursts of `amplitude` counts (one per drop) with noise 1.5; `swing`: the front end's output
    ends that far from the bias (flat tops there, noise-free as an amplifier at its rail reads), then the ADC's
    own rails."""
    t = (np.arange(n) - pre) / 100000.0
    on = t >= 0
    out = np.empty((drops, 4, n))
    for r in range(drops):
        for c in range(4):
            sig = amplitude[r] * np.sin(2 * np.pi * 8000.0 * t + c) * np.exp(-300.0 * t) * on
            if swing is not None:
                sig = np.clip(sig, -swing, swing)
            flat = np.abs(sig) >= (swing if swing is not None else np.inf)
            out[r, c] = bias + sig + np.where(flat, 0.0, rng.normal(0, 1.5, n))
    return np.clip(np.rint(out), 0, top).astype(np.uint16)


def test_saturation_inside_the_rails_is_found_and_nothing_otherwise():
    from impactsense.signal import saturation_counts

    rng = np.random.default_rng(0)
    rig = _rig()
    amp = np.linspace(300, 4000, 12)
    # drops that reach the ADC's own rails, and ringing up to 0.9 of the range without a flat top: nothing
    assert saturation_counts(_drops(amp, rng), rig) is None
    assert saturation_counts(_drops(np.full(12, 0.9 * 2047), rng), rig) is None
    # a front end whose swing ends 1,850 counts from the bias: its flat tops
    low, high = saturation_counts(_drops(amp, rng, swing=1850.0), rig)
    assert high == 2048 + 1850 and low == 2048 - 1850
    # a coarse oversampled logger (8 bits at 1 MHz, a 2 kHz ring to 0.85 of its range): its smooth peaks repeat a
    # level for many samples, but creep up to it
    t = np.arange(4000) / 1e6
    ring = 0.85 * 127 * np.sin(2 * np.pi * 2000.0 * t[None, None, :] + np.arange(4)[None, :, None])
    coarse = np.clip(np.rint(128 + ring * np.linspace(0.8, 1.0, 12)[:, None, None]
                             + rng.normal(0, 0.4, (12, 4, 4000))), 0, 255).astype(np.uint16)
    coarse[..., :200] = np.clip(np.rint(128 + rng.normal(0, 0.4, (12, 4, 200))), 0, 255)
    assert saturation_counts(coarse, _rig(adc_bits=8, bias_counts=128, fs_hz=1000000, samples=4000)) is None
    # a single flat-topped record is not a saturation level (SATURATION_MIN_RECORDS)
    one = _drops(np.r_[4000.0, np.full(11, 500.0)], rng, swing=1850.0)
    assert saturation_counts(one, rig) is None


def test_the_core_flags_clipping_at_the_saturation_level():
    from impactsense.pipeline import featurize
    from impactsense.signal import SignalConfig, saturation_counts

    rng = np.random.default_rng(1)
    rig = _rig()
    adc = _drops(np.linspace(300, 4000, 12), rng, swing=1850.0)
    at_rails = featurize(adc, SignalConfig.for_rig(rig))
    assert not at_rails.clipped.any()                    # the ADC's rails are never reached
    sat = replace(rig, saturation_counts=saturation_counts(adc, rig))
    flagged = featurize(adc, SignalConfig.for_rig(sat)).clipped
    reaching = (np.abs(adc.astype(int) - 2048).max(axis=2) >= 1850)
    assert np.array_equal(flagged, reaching) and reaching.sum() >= 8


def test_a_model_with_saturation_rails_still_reads_its_logger():
    """checks.py: a model's rails inside the logger's are the same logger; another resolution is not."""
    from impactsense.checks import check_rig
    from impactsense.errors import DataError

    rig = _rig()
    signal = {"adc_max": 3898, "sample_offset": 0}
    check_rig({"signal": signal}, rig, "card", "here")
    for other in (8191, 2047):
        try:
            check_rig({"signal": {"adc_max": other, "sample_offset": 0}}, rig, "card", "here")
        except DataError as e:
            assert "ADC range" in str(e)
        else:
            raise AssertionError(f"a model for 0..{other} read a 12-bit logger")
