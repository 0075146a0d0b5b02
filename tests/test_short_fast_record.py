"""A fast logger's short record (e.g. 500 kHz x 2,000 samples: 4 ms, 3.6 ms of it after the hit): what the
commands read on it (docs/findings.md "Session 26: newuser7")."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np


def _ringing_records(fs, n, pre, bias, rng, drops=30, ring=300.0, decay_per_s=150.0):
    """Drops whose plate still rings at the record's end (a lightly damped metal plate, kHz modes), noise 1.5."""
    t = (np.arange(n) - pre) / fs
    on = t >= 0
    out = np.empty((drops, 4, n))
    for r in range(drops):
        for c in range(4):
            f = rng.uniform(2e3, 20e3, 6)
            ph = rng.uniform(0, 2 * np.pi, 6)
            sig = (np.sin(2 * np.pi * f[:, None] * t[None, :] + ph[:, None]).sum(axis=0) * ring / 3
                   * np.exp(-decay_per_s * t) * on)
            out[r, c] = bias + sig + rng.normal(0, 1.5, n)
    return np.clip(np.rint(out), 0, 4095).astype(np.uint16)


def test_info_does_not_report_a_hum_the_logger_could_not_hold():
    """Over a 4 ms record's 2 ms tail (a tenth of a mains period, the plate still ringing) the lock-in's 50 / 60 Hz
    amplitudes were read as 10-18 million counts on a 12-bit logger (and printed as hum, over a floor of 8
    million). A hum over the ADC's half range would clip every record: such a reading is 'n/a', said why; a
    record long enough to read it is reported as before."""
    from impactsense.commands.info import hum_counts, hum_text
    from impactsense.hum import hum_readable

    rng = np.random.default_rng(0)
    fs, n, pre, bias = 500000, 2000, 200, 2048
    adc = _ringing_records(fs, n, pre, bias, rng)
    rig = SimpleNamespace(fs_hz=fs, pretrigger_samples=pre, bias_counts=bias, adc_max=4095)
    amp, where, floor, _, span_ms = hum_counts(SimpleNamespace(adc=adc, rig=rig))
    assert where == "the record's tail" and 1.5 < span_ms < 2.5
    assert np.all(np.maximum(amp, floor) > 4095 / 2)        # what the column printed before: not a hum
    ok = hum_readable(amp, floor, 4095)
    assert not ok.any()
    assert hum_text({"hum_counts": None, "hum_floor_counts": None}) == "n/a"
    # a logger keeping 20 ms before the hit reads a hum of 30 counts there (readable, within its bounds)
    from impactsense.faults import FaultSpec, inject

    fs2, n2, pre2 = 50000, 2000, 1000
    quiet = np.clip(np.rint(bias + rng.normal(0, 1.5, (30, 4, n2))), 0, 4095).astype(np.uint16)
    hummed = inject(quiet, FaultSpec(hum=30.0, hum_hz=50.0, seed=1), fs2, bias, 4095)
    rig2 = SimpleNamespace(fs_hz=fs2, pretrigger_samples=pre2, bias_counts=bias, adc_max=4095)
    amp2, _, floor2, _, _ = hum_counts(SimpleNamespace(adc=hummed, rig=rig2))
    assert hum_readable(amp2, floor2, 4095).all() and np.all((10.0 < amp2) & (amp2 < 35.0))


def test_diagnose_features_on_a_short_record_do_not_extend_an_unreadable_hum():
    """diagnose's host features (residuals.signal_features): the tail's 50 / 60 Hz fit over a 2 ms tail read
    millions of counts of 'hum' and was extended back over the record and subtracted from the decay's blocks,
    and blocks past the record's end read its last sample repeated: the reference's decay read -92 1/s (a
    growing envelope) on a plate decaying at 150. Now such a tail gives hum 0 and only its offset is taken out,
    and blocks past the end are left out; a 50 ms record (the measured rigs') reads the same as before, bit for
    bit."""
    from impactsense.residuals import signal_features

    rng = np.random.default_rng(1)
    fs, n, pre, bias = 500000, 2000, 200, 2048
    adc = _ringing_records(fs, n, pre, bias, rng, drops=20, ring=300.0, decay_per_s=150.0)
    onset = np.full((20, 4), float(pre + 50))
    _, decay_old, hum_old = signal_features(adc, onset, fs, float(bias))
    assert np.median(hum_old) > 4095 / 2                    # before: a hum no 12-bit logger could hold
    _, decay, hum = signal_features(adc, onset, fs, float(bias), 4095)
    assert np.all(hum == 0.0)
    ok = np.isfinite(decay)
    # 3.5 ms after the onset hold only two whole 1 ms blocks from 1 ms on: no decay is read (3 blocks needed)
    assert not ok.any()
    # a long record (50 ms at 100 kHz, 25 ms of quiet tail): the same figures with and without the rule
    fs2, n2, pre2 = 100000, 5000, 500
    long = _ringing_records(fs2, n2, pre2, bias, rng, drops=10, ring=300.0, decay_per_s=300.0)
    on2 = np.full((10, 4), float(pre2 + 20))
    a = signal_features(long, on2, fs2, float(bias))
    b = signal_features(long, on2, fs2, float(bias), 4095)
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)


def test_reference_and_damping_effect_are_quiet_without_a_decay(recwarn):
    """A session whose records are too short for the decay's blocks reads NaN decay on every drop: the reference
    fit and the damping effect say NaN (no decay read) without numpy's all-NaN warnings on the user's terminal."""
    import warnings

    from impactsense.effects.damping import Damping
    from impactsense.residuals import Reference

    ref = Reference(sensor_xy_mm=np.zeros((4, 2)), slowness_us_per_mm=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        F = SimpleNamespace(decay_per_s=np.full((12, 4), np.nan))
        p = Damping().fit(ref, F, None)
    assert np.isnan(p["extra_decay_per_s"])
