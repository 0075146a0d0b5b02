"""Where the core's window starts in a record longer than the core reads (signal.record_start): near the first
arrival, not at the record's start. A bench oscilloscope keeping 4 ms before the hit and 16 ms after let a 50 Hz
hum of 1.5-3 counts (8 bits) drift from the baseline segment's level (the capture's first samples) past the onset
threshold before the arrival: the hum channel's picks came early (docs/findings.md "Session 25: humscope")."""

import dataclasses

import numpy as np

from impactsense import _core
from impactsense.signal import (CORE_MAX_SAMPLES, QUIET_KEPT_S, SignalConfig, core_samples, core_window,
                                record_start, rig_settings)

from test_scope_logger import BIAS, FS, PRE, _records, _rig

N_SHORT = 4000


def _hummed(rng, n_rec, n, amps):
    clean = _records(rng, n_rec, n, 0.0)
    t = np.arange(n) / FS
    hummed = clean.copy()
    for r in range(n_rec):
        hummed[r, 1] = np.clip(hummed[r, 1] + np.rint(amps[r] * np.sin(2 * np.pi * 50 * t + rng.uniform(0, 6.3))),
                               0, 255)
    return clean, hummed


def test_a_long_records_window_starts_near_the_first_arrival_and_the_hum_picks_are_not_early():
    """20,000 samples at 1 MHz, 4,000 before the hit, 1.5-3 counts of 50 Hz hum on channel 1 that the core does not
    model and an onset threshold of 3.3 counts (what train fits on such a logger): read from the record's start, the hum channel's
    picks come > 20 us early on many records; from 1 ms before the quiet start's end, on none or nearly none,
    and the other channels' picks do not move against the same window without hum."""
    n = 20000
    rig = dataclasses.replace(_rig(n), pretrigger_samples=PRE)
    start = record_start(n, PRE, FS)
    assert start == PRE - round(QUIET_KEPT_S * FS) and rig_settings(rig)["record_start"] == start
    rng = np.random.default_rng(11)
    clean, hummed = _hummed(rng, 40, n, rng.uniform(1.5, 3.0, 40))

    def early(cfg):
        ref = _core.extract_batch(core_samples(clean, cfg.core()), cfg.core())["toa_us"]
        now = _core.extract_batch(core_samples(hummed, cfg.core()), cfg.core())["toa_us"]
        assert np.allclose(now[:, [0, 2, 3]], ref[:, [0, 2, 3]], equal_nan=True)
        return np.mean(~np.isfinite(now[:, 1]) | (now[:, 1] < ref[:, 1] - 20.0))

    # the hum not modelled, as on most of the scope session's drops (its fit over the core's 8 ms rarely four
    # standard errors above zero there): the floor raised here so the test reads the window alone
    now = SignalConfig.for_rig(rig, onset_threshold_counts=3.3, hum_min_counts=100.0)
    assert now.record_start == start
    old = dataclasses.replace(now, record_start=0, baseline_samples=64)   # the window at the record's start
    before, after = early(old), early(now)
    assert after <= 0.05 < before, (before, after)


def test_records_the_core_reads_whole_are_read_as_before():
    """A record of at most CORE_MAX_SAMPLES is read whole whatever record_start says (a model card trained on a
    long-record logger, run on a short record), so every rig with such records reads bit for bit as before; a
    long record's window is CORE_MAX_SAMPLES and never runs past its end; no quiet start known: from 0."""
    x = np.arange(3 * 4 * 5000, dtype=np.uint16).reshape(3, 4, 5000)
    assert core_window(x, 3000) is x
    assert record_start(5000, 4000, FS) == 0 and record_start(20000, None, FS) == 0
    assert record_start(CORE_MAX_SAMPLES + 100, 4000, FS) == 100        # the window ends at the record's end
    assert record_start(20000, 300, FS) == 0                           # little quiet start: from the start
    long = np.zeros((1, 4, 20000), np.uint16)
    long[..., 15000:] = 1
    w = core_window(long, 15000)
    assert w.shape[-1] == CORE_MAX_SAMPLES and w[..., -1].all() and not w[..., 0].any()
    cfg = SignalConfig.for_rig(_rig(5000))
    assert cfg.record_start == 0
    short = SignalConfig.from_dict({**cfg.to_dict(), "record_start": 3000})
    assert np.array_equal(core_samples(x, short.core()), core_samples(x, cfg.core()))
    assert BIAS == 128


def test_a_coarse_loggers_onset_threshold_is_not_under_its_quantisation():
    """An 8-bit, 5 V logger: the reference logger's onset threshold in volts is 0.41 of its steps; with ~0.4 step
    of noise the 5 x noise-rms floor sets ~2 steps, and a lone sample 2 steps from the level (quantised noise past
    1.5 steps) crosses it before the arrival. The host's threshold is at least ONSET_MIN_STEPS of the logger's
    steps; finer loggers keep the scaled default."""
    from impactsense.signal import ONSET_MIN_STEPS, counts_per_core_count

    rig = _rig(N_SHORT)
    assert 10.0 * counts_per_core_count(rig) < 1.0
    assert rig_settings(rig)["onset_threshold_counts"] == ONSET_MIN_STEPS
    ten = dataclasses.replace(rig, adc_bits=10, vref=3.3, bias_counts=512)   # 2.5 steps scaled: kept
    assert rig_settings(ten)["onset_threshold_counts"] == 10.0 * counts_per_core_count(ten)
    assert "onset_threshold_counts" not in rig_settings(dataclasses.replace(rig, adc_bits=12, vref=3.3))
    rng = np.random.default_rng(3)
    x = _records(rng, 150, N_SHORT, 0.0, ring_start=N_SHORT - 400)   # 3.6 ms of quiet start, then the ring
    cfg = SignalConfig.for_rig(rig)
    scaled = dataclasses.replace(cfg, onset_threshold_counts=10.0 * counts_per_core_count(rig))

    def in_quiet(c):
        toa = _core.extract_batch(core_samples(x, c.core()), c.core())["toa_threshold"]
        return np.mean(toa < N_SHORT - 400 - 20)

    assert in_quiet(cfg) == 0.0 and in_quiet(scaled) >= 0.01     # 14 of 600 channel records here
