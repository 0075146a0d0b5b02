"""bench_bond_inverse.spectral_one_pole: a bonded channel's one-pole read from its spectrum against the reference's
(different drops; the other channels' ratio taken out). Synthetic records only: nothing simulated."""

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_bond_inverse import spectral_one_pole  # noqa: E402

FS, N, START = 100_000.0, 2048, 128


def drops(seed: int, level: float, channel: int = -1, fc: float = 0.0, g: float = 1.0, noise: float = 2.0):
    """120 records of 4 channels: quiet until START, then a decaying broadband arrival of `level` (each drop
    its own), the amplifier's white noise (`noise` counts) after the channel's bond (g / (1 + j f / fc))."""
    rng = np.random.default_rng(seed)
    t = np.arange(N - START)
    burst = rng.normal(size=(120, 4, N - START)) * np.exp(-t / 300.0) * level * rng.uniform(0.8, 1.2, (120, 1, 1))
    if channel >= 0:
        f = np.fft.rfftfreq(2 * burst.shape[-1], 1.0 / FS)
        h = g / (1.0 + 1j * f / fc) if fc > 0 else g
        burst[:, channel] = np.fft.irfft(np.fft.rfft(burst[:, channel], 2 * burst.shape[-1]) * h)[..., :N - START]
    x = np.zeros((120, 4, N))
    x[..., START:] = burst
    return SimpleNamespace(adc=2048.0 + x + noise * rng.normal(size=x.shape), rig=SimpleNamespace(fs_hz=FS))


def test_a_bonds_one_pole_is_read_from_the_spectra_of_other_drops():
    ref = drops(0, 200.0)
    fc, g = spectral_one_pole(ref, drops(1, 300.0, channel=2, fc=3000.0, g=0.7), 2)   # stronger drops: taken out
    # above the corner |H| = g fc / f: the product is what the spectra fix best (few bins lie below fc)
    assert abs(fc * g / (3000.0 * 0.7) - 1.0) < 0.05
    assert abs(fc / 3000.0 - 1.0) < 0.15 and abs(g / 0.7 - 1.0) < 0.10


def test_a_plain_gain_or_no_change_is_no_low_pass():
    ref = drops(0, 200.0)
    fc, g = spectral_one_pole(ref, drops(2, 200.0, channel=1, g=0.6), 1)
    assert abs(g / 0.6 - 1.0) < 0.07 and fc > 100_000.0
    fc, g = spectral_one_pole(ref, drops(3, 200.0), 0)
    assert abs(g - 1.0) < 0.07 and fc > 100_000.0


def test_the_prefilter_is_the_cores_inverse_and_its_roll_off_cuts_the_lifted_noise():
    """bench_bond_inverse.prefiltered (the roll-off prototype): with no roll-off, channel 1 is the core's bond
    inverse of the whole record to within one count (double against single precision); with a roll-off at
    f3 the white noise it passes is the inverse's less the band above f3: the rms ratio is the analytic one of
    |H_inv R| against |H_inv| over 0..fs/2 (bilinear, so R is 0 at fs/2) within 5 %, and the other channels are
    untouched."""
    import dataclasses

    from scipy import signal as ss

    from bench_bond_inverse import prefiltered
    from impactsense import _core
    from impactsense.signal import SignalConfig

    fs, fc, g, f2, f3, n = 100_000.0, 3000.0, 0.65, 9000.0, 30_000.0, 2048
    rng = np.random.default_rng(7)
    adc = np.clip(np.rint(2048.0 + 20.0 * rng.normal(size=(20, 4, n))), 0, 4095).astype(np.uint16)

    @dataclasses.dataclass
    class Session:   # what prefiltered reads (dataclasses.replace needs a dataclass)
        adc: np.ndarray
        rig: object

    sess = Session(adc, SimpleNamespace(fs_hz=fs, adc_max=4095))
    plain = prefiltered(sess, 1, fc, g, f2, 0.0).adc
    cfg = SignalConfig(fs_hz=fs, adc_min=0, adc_max=4095, bond_corner_hz=[0.0, fc, 0.0, 0.0],
                       bond_gain=[1.0, g, 1.0, 1.0], bond_limit_hz=[0.0, f2, 0.0, 0.0])
    core = np.stack([_core.bond_inverse(adc[k, 1].astype(np.int16), cfg.core(), 1) for k in range(len(adc))])
    assert np.abs(plain[:, 1].astype(int) - core.astype(int)).max() <= 1
    np.testing.assert_array_equal(plain[:, [0, 2, 3]], adc[:, [0, 2, 3]])
    rolled = prefiltered(sess, 1, fc, g, f2, f3).adc
    b, a = ss.bilinear([1.0 / (2 * np.pi * fc), 1.0], [g / (2 * np.pi * f2), g], fs)
    b3, a3 = ss.bilinear([1.0], [1.0 / (2 * np.pi * f3), 1.0], fs)
    w, h = ss.freqz(b, a, 4096, fs=fs)
    _, r = ss.freqz(b3, a3, w, fs=fs)
    want = np.sqrt(np.sum(np.abs(h * r) ** 2) / np.sum(np.abs(h) ** 2))
    got = rolled[:, 1, 200:].astype(float).std() / plain[:, 1, 200:].astype(float).std()
    assert abs(got / want - 1.0) < 0.05, (got, want)
    assert want < 0.8   # the band above f3 carries a real share of the lifted noise (the test can fail)


def test_the_weighted_physics_position_leans_on_the_channels_weighted_up():
    """bench_bond_inverse.weighted_phys (the Session 28 prototype of a per-channel pick weight in the localiser):
    exact travel times from a known hit on the bundled rig with one channel's pick 15 us late. Equal weights: the
    position is the core's, unmoved. That channel weighted 1e4 x as scattered: the position moves onto the other
    three's exact solution (within 0.5 mm), nearer the hit than the equal-weight fit."""
    import dataclasses
    from bench_bond_inverse import weighted_phys
    from impactsense.data import load_session
    from impactsense.pipeline import FEATURE_NAMES, featurize
    from impactsense.signal import SignalConfig

    s = load_session("bundled:session-1").subset(np.arange(1))
    cfg = SignalConfig.for_rig(s.rig)
    f = featurize(s.adc, cfg)
    hit = np.array([120.0, 200.0])
    sensors = np.asarray(cfg.sensor_xy_mm, float)
    toa = 500.0 + np.linalg.norm(sensors - hit, axis=1) / float(cfg.velocity_mm_per_us)
    toa[2] += 15.0
    start = hit + [6.0, -4.0]   # the core's position of such picks: near, not on, the hit
    vec = np.array(f.vector, copy=True)
    vec[0, FEATURE_NAMES.index("phys_x_mm")], vec[0, FEATURE_NAMES.index("phys_y_mm")] = start
    f = dataclasses.replace(f, toa_us=toa[None].astype(np.float32), phys_xy_mm=start[None].astype(np.float32), vector=vec)
    same = weighted_phys(f, cfg, [1.0] * 4)
    assert np.allclose(same.phys_xy_mm, f.phys_xy_mm) and np.allclose(same.vector, f.vector)
    loc = cfg.localiser()
    assert float(loc.band_velocity_mm_per_us) == 0.0   # the rig's default: no band picks, the threshold picks' fit alone
    from bench_bond_inverse import _weighted_fit
    plate = (float(loc.plate_x_mm), float(loc.plate_y_mm))
    q = (loc.travel_metric_xx, loc.travel_metric_xy, loc.travel_metric_yy)
    equal = _weighted_fit(toa, sensors[:, 0], sensors[:, 1], float(loc.velocity_mm_per_us), q, float(loc.huber_us),
                          np.ones(4), start, plate)
    moved = weighted_phys(f, cfg, [1.0, 1.0, 1e4, 1.0])
    shift = moved.phys_xy_mm[0] - start
    got = equal + shift   # the equal-weight fit moved by the weighted fit's difference
    assert np.linalg.norm(got - hit) < 0.5 < np.linalg.norm(equal - hit)
    assert moved.vector[0, FEATURE_NAMES.index("phys_x_mm")] == pytest.approx(moved.phys_xy_mm[0, 0], abs=1e-3)
