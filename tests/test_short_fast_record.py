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


def _modal_ringing(fs, n, onset, decay_per_s, rng, bias=2048.0, noise=1.5):
    """One drop's four channels: 40 random modes (1-20 kHz) each, decaying as exp(-decay t) from `onset`."""
    t = (np.arange(n) - onset) / fs
    out = np.empty((1, 4, n))
    for c in range(4):
        f = rng.uniform(1e3, 20e3, 40)
        ph = rng.uniform(0, 2 * np.pi, 40)
        wave = np.sin(2 * np.pi * f[:, None] * t[None] + ph[:, None]).sum(axis=0) * 60.0
        out[0, c] = np.where(t >= 0, wave * np.exp(-decay_per_s * np.clip(t, 0, None)), 0.0)
    out += rng.normal(0, noise, out.shape) + bias
    return np.clip(np.rint(out), 0, 4095).astype(np.uint16)


def _core_cfg(fs):
    from impactsense.signal import core_config
    return core_config(fs_hz=fs)


def test_calibrate_decay_blocks_fit_a_short_record_and_read_its_decay():
    """500 kHz x 2,000 samples, 200 before the hit (3.6 ms after it): the 1 ms blocks from 1 ms after the onset
    to 8 ms ran past the record's end (its last sample repeated: the decay read fast). The blocks are cut to
    what the record keeps (three of ~0.87 ms, none past the end) and read the known decay: over 12 drops of 40
    random modes per channel, the median within 3 robust standard errors (the modes' beating over a short
    block is the read's noise: its SE is what calibrate reports) and that SE under a third of the decay."""
    from impactsense.calibration import damping
    fs, n, onset, bias = 500_000.0, 2000, 200, 2048.0
    cfg = _core_cfg(fs)
    rng = np.random.default_rng(7)
    for lam in (150.0, 500.0):
        reads = []
        for _ in range(12):
            adc = _modal_ringing(fs, n, onset, lam, rng, bias)
            blocks = damping.record_blocks(adc, cfg)
            assert blocks.count == damping.MIN_BLOCKS and 0.5 < blocks.width_ms < damping.BLOCK_MS
            power = damping.block_power(adc, cfg, bias, blocks)
            assert np.isfinite(power).all()                       # no block past the end
            mask = damping.window_mask(power, np.full((1, 4), 1.5))
            reads.append(damping.decay_rates(power, mask, blocks.width_ms))
        se = damping.robust_se(np.asarray(reads))
        assert se < lam / 3 and abs(np.median(reads) - lam) < 3 * se, (lam, np.median(reads), se)


def test_calibrate_decay_blocks_of_a_long_record_are_the_1_ms_blocks_bit_for_bit():
    """A record that keeps 8 ms after the onset (a 50 ms record at 100 kHz) reads the seven 1 ms blocks from 1 ms
    exactly as before the blocks were sized to the record; a 5 ms record keeps whole 1 ms blocks (fewer)."""
    from impactsense.calibration import damping
    fs, n, onset, bias = 100_000.0, 5000, 300, 2048.0
    cfg = _core_cfg(fs)
    adc = _modal_ringing(fs, n, onset, 300.0, np.random.default_rng(3), bias)
    blocks = damping.record_blocks(adc, cfg)
    assert blocks == damping.Blocks(1.0, 7)
    # the former reading: fixed 1 ms blocks to MAX_MS, index clipped at the record's end
    from impactsense import _core
    from impactsense.signal import core_samples
    feats = _core.extract_batch(core_samples(adc, cfg), cfg)
    on = np.nan_to_num(np.asarray(feats["toa_aic"], float), nan=0.0).astype(int)
    idx = np.clip(on[..., None] + 100 + np.arange(700)[None, None, :], 0, n - 1)
    seg = np.take_along_axis(adc.astype(float) - bias, idx, axis=-1).reshape(1, 4, 7, 100)
    before = seg.var(axis=-1) - np.asarray(feats["noise_rms"], float)[..., None] ** 2
    assert np.array_equal(damping.block_power(adc, cfg, bias, blocks), before)
    short = _modal_ringing(fs, 550, 50, 300.0, np.random.default_rng(3), bias)   # 5 ms after the hit
    assert damping.record_blocks(short, cfg) in (damping.Blocks(1.0, 3), damping.Blocks(1.0, 4))
