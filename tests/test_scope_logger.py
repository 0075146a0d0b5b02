"""A bench oscilloscope as the logger: 1 MHz, 8 bits, a long pre-trigger, 50 Hz hum on one channel. The hum is a
few counts of an 8-bit ADC (tens of the reference logger's, in volts); the core must model it, and `info` must
read it on that channel alone, not the plate's ring-down on every channel (docs/findings.md "Session 24:
newuser5")."""

from types import SimpleNamespace

import numpy as np

from impactsense import _core
from impactsense.data import rig_from_dict
from impactsense.signal import core_config, counts_per_core_count

FS, N, PRE, BIAS = 1_000_000, 8192, 4000, 128


def _rig(samples=N):
    sensors = [{"name": f"S{k + 1}", "channel": k, "x_mm": x, "y_mm": y}
               for k, (x, y) in enumerate([(335, 42), (205, 262), (62, 36), (198, 28)])]
    return rig_from_dict({"plate_material": "FR-4 glass-epoxy laminate", "plate_x_mm": 400.0, "plate_y_mm": 300.0,
                          "thickness_mm": 1.6, "density_kg_m3": 1850.0, "plate_support": "four nylon standoffs",
                          "sensors": sensors, "channels": 4, "sensor_type": "PZT disc", "sensor_diameter_mm": 12.0,
                          "ball_material": "steel", "ball_diameter_mm": 6.0,
                          "fs_hz": FS, "samples": samples, "adc_bits": 8, "vref": 5.0, "bias_counts": BIAS,
                          "ball_mass_g": 0.88})


def _burst(n, rng, start=PRE, peak=40.0):
    """A hit's ring: a 15-30 kHz decaying tone from `start` (its onset ramps over ~20 us), counts less the bias."""
    t = (np.arange(n) - start) / FS
    f = rng.uniform(15e3, 30e3)
    env = np.where(t >= 0, (1 - np.exp(-t / 20e-6)) * np.exp(-t / 1.5e-3), 0.0)
    return peak * env * np.sin(2 * np.pi * f * np.clip(t, 0, None))


def _records(rng, n_rec, n, hum_amp, hum_channel=1, ring_start=PRE):
    x = np.stack([np.stack([_burst(n, rng, ring_start + 30 * c) for c in range(4)]) for _ in range(n_rec)])
    x += rng.normal(0.0, 0.45, x.shape)
    t = np.arange(n) / FS
    for r in range(n_rec):
        x[r, hum_channel] += hum_amp * np.sin(2 * np.pi * 50.0 * t + rng.uniform(0, 2 * np.pi))
    return np.clip(np.rint(x + BIAS), 0, 255)


def test_an_8_bit_loggers_hum_is_modelled_and_does_not_pick_the_arrival_early():
    """3 counts of 50 Hz hum on an 8-bit, 5 V logger is ~18 of the reference logger's counts: the core's 4-count
    floor for a modelled hum, not scaled, left it out, and over a 4 ms pre-trigger the hum's drift met the
    (scaled) onset threshold before the arrival: the hum channel's picks came up to 2.7 ms early (train fitted a
    -40 us channel delay). The floor is now a count field the host scales like the threshold."""
    rig = _rig()
    assert counts_per_core_count(rig) < 0.1
    cfg = core_config(rig)
    assert np.isclose(cfg.hum_min_counts, 4.0 * counts_per_core_count(rig), rtol=1e-6)
    rng = np.random.default_rng(5)
    clean = _records(rng, 40, N, 0.0)
    hummed = clean.copy()
    t = np.arange(N) / FS
    for r in range(hummed.shape[0]):
        hummed[r, 1] = np.clip(hummed[r, 1] + np.rint(3.0 * np.sin(2 * np.pi * 50 * t + rng.uniform(0, 2 * np.pi))),
                               0, 255)
    as16 = lambda a: np.ascontiguousarray(a.astype(np.int16))  # noqa: E731
    ref = _core.extract_batch(as16(clean), cfg)["toa_us"][:, 1]
    now = _core.extract_batch(as16(hummed), cfg)
    early = lambda toa: np.mean(~np.isfinite(toa) | (toa < ref - 20.0))  # noqa: E731
    assert early(now["toa_us"][:, 1]) <= 0.1        # 3 of 40 here: the 8-bit steps of the hum past 5 x noise
    assert np.mean((now["flags"][:, 1] & _core.FLAG_HUM) != 0) > 0.8
    old = core_config(rig, hum_min_counts=4.0)      # the unscaled floor: the failure this test guards
    assert early(_core.extract_batch(as16(hummed), old)["toa_us"][:, 1]) > 0.5   # 29 of 40


def test_info_reads_hum_on_the_hum_channel_over_quiet_start_and_tail():
    """A 20 ms record keeping 4 ms before the hit: neither the quiet start nor the tail (the record's second half,
    where the plate still rings) is long enough to tell 50 Hz from 60 Hz, offset and a slow ring apart; the tail
    alone read 18-52 counts of 'hum' on every channel of a session with 1.5-3 counts on one. The quiet start and the
    rung-down tail read together on the record's time axis give the hum channel's amplitude and the others none."""
    from impactsense.commands.info import hum_counts
    from impactsense.hum import hum_lock_in
    from impactsense.residuals import tail_start

    rng = np.random.default_rng(7)
    n = 20000
    adc = _records(rng, 30, n, 0.0)
    t = np.arange(n) / FS
    slow = np.where(t > PRE / FS, np.exp(-(t - PRE / FS) / 2e-3), 0) * 6.0 * np.sin(2 * np.pi * 44.0 * (t - PRE / FS))
    adc = np.clip(adc + np.rint(slow), 0, 255)             # the plate's own low mode, ringing down
    amps = rng.uniform(1.5, 3.0, adc.shape[0])
    for r in range(adc.shape[0]):
        adc[r, 1] = np.clip(adc[r, 1] + np.rint(amps[r] * np.sin(2 * np.pi * 50 * t + rng.uniform(0, 6.3))), 0, 255)
    t0 = tail_start(n, FS)
    tail_only = np.median(hum_lock_in(adc[:, :, t0:] - BIAS, FS)[0].max(axis=2), axis=0)
    assert np.all(tail_only[[0, 2, 3]] > 2.0)                # what the column printed before (no hum there)
    rig = SimpleNamespace(fs_hz=FS, pretrigger_samples=PRE, bias_counts=BIAS)
    amp, where, floor, _, _ = hum_counts(SimpleNamespace(adc=adc, rig=rig))
    assert "quiet start and the record's tail" in where
    assert 1.2 < amp[1] < 3.5 and amp[1] > floor[1]
    assert np.all(amp[[0, 2, 3]] < 0.6)


def test_info_says_the_core_reads_part_of_a_long_record():
    """20,000 samples at 1 MHz: `info`'s line on the record after the first arrival (what the core reads: its
    window from signal.record_start, 1 ms before the quiet start's end, 7.19 ms after it) says it is
    CORE_MAX_SAMPLES of the record and where they start, not the 16 ms the scope kept."""
    from impactsense.record_window import window_check, window_text
    from impactsense.signal import CORE_MAX_SAMPLES, record_start

    check = window_check(_rig(20000), 20000, PRE)
    start = record_start(20000, PRE, FS)
    assert 0 < start < PRE and check["core_start"] == start
    assert np.isclose(check["after_first_arrival_ms"], (start + CORE_MAX_SAMPLES - PRE) / FS * 1e3)
    assert f"{CORE_MAX_SAMPLES} of a record's 20000 samples, from sample {start}" in window_text(check)
    assert "of a record's" not in window_text(window_check(_rig(), N, PRE))


def test_calibrates_fast_model_spans_the_arrivals_at_1_mhz():
    """calibrate's fast first-arrival model took 1024 samples (the option is a sample count): at 1 MHz that ends
    before its impact at 1.5 ms, no synthetic drop had a pick, and every point of the plate grid read the misfit's
    cap (rms DToA 1000 us: E and G12 fell on the prior's bounds). The span now reaches the arrivals at any rate;
    at 100 kHz the default is kept."""
    import dataclasses

    from impactsense.calibration import arrival, plate
    from impactsense.signal import CORE_MAX_SAMPLES

    rig = _rig(20000)
    x, y, h = np.array([100.0, 300.0, 120.0, 280.0]), np.array([80.0, 90.0, 220.0, 200.0]), np.full(4, 160.0)
    setup = arrival.setup_from_rig(rig, x, y, h, n_fft=1024)
    assert 1.5e-3 * FS < setup.n_fft <= CORE_MAX_SAMPLES
    slow = dataclasses.replace(rig, fs_hz=100000.0)
    assert arrival.setup_from_rig(slow, x, y, h, n_fft=1024).n_fft == 1024
    state = plate.cfg_state(core_config(rig), BIAS)
    peak = np.full((4, 4), 40.0)
    args = (state, peak, np.zeros((4, 6)), np.array([22000.0]), np.array([0.13]))
    _, dtoa = plate.fast_loss(setup, *args)
    assert np.isfinite(dtoa).all()
    _, before = plate.fast_loss(dataclasses.replace(setup, n_fft=1024), *args)
    assert not np.isfinite(before).any()
