"""The travel-time model of an anisotropic plate: the core's localiser with a travel metric, and its fit."""

import numpy as np
import pytest

from impactsense import _core
from impactsense.travel import fit_travel, metric_of, travel_distances

SENSORS = np.array([[50.0, 45.0], [400.0, 55.0], [395.0, 300.0], [60.0, 290.0]])
PLATE = (450.0, 350.0)


def synthetic_toa(xy, v, metric, delays=(0.0, 0.0, 0.0, 0.0), t0=100.0):
    return (t0 + travel_distances(xy, SENSORS, metric) / v + np.asarray(delays)[None]).astype(np.float32)


def localise(toa, v, metric=None):
    kw = {} if metric is None else {"travel_metric": list(metric)}
    return _core.localise_batch(np.ascontiguousarray(toa), np.ones(toa.shape, np.uint8), SENSORS[:, 0].tolist(),
                                SENSORS[:, 1].tolist(), v, 1.0, *PLATE, 4.0, **kw)


def test_localiser_with_the_plates_metric_finds_exact_positions():
    """ToAs made with elliptical wavefronts (speed along x 1.5x that along y): the metric's localiser
    recovers the position inside the sensors' hull to 0.05 mm; the Euclidean one misses by millimetres."""
    rng = np.random.default_rng(1)
    xy = np.c_[rng.uniform(80, 370, 30), rng.uniform(80, 270, 30)]
    q = metric_of(-0.385, 0.0)   # (1 - a) / (1 + a) = 2.25 = 1.5^2
    toa = synthetic_toa(xy, 1.6, q)
    got = localise(toa, 1.6, q)
    err = np.hypot(got["x_mm"] - xy[:, 0], got["y_mm"] - xy[:, 1])
    assert np.all(got["status"] == 0) and err.max() < 0.05
    iso = localise(toa, 1.6)
    assert np.median(np.hypot(iso["x_mm"] - xy[:, 0], iso["y_mm"] - xy[:, 1])) > 2.0


def test_identity_metric_is_the_isotropic_localiser_bit_for_bit():
    rng = np.random.default_rng(2)
    xy = np.c_[rng.uniform(20, 430, 20), rng.uniform(20, 330, 20)]
    toa = synthetic_toa(xy, 1.9, (1.0, 0.0, 1.0)) + rng.normal(0, 2.0, (20, 4)).astype(np.float32)
    a, b = localise(toa, 1.9), localise(toa, 1.9, (1.0, 0.0, 1.0))
    for key in ("x_mm", "y_mm", "t0_us", "cov"):
        assert np.array_equal(a[key], b[key])


def test_a_metric_that_is_not_positive_definite_is_a_config_error():
    toa = synthetic_toa(np.array([[200.0, 150.0]]), 1.5, (1.0, 0.0, 1.0))
    r = localise(toa, 1.5, (1.0, 2.0, 1.0))
    assert r["status"][0] != 0 and np.isnan(r["x_mm"][0])


@pytest.mark.parametrize("a, b", [(0.0, 0.0), (-0.3, 0.1), (0.25, -0.15)])
def test_fit_travel_recovers_velocity_delays_and_metric(a, b):
    """Known DToA (the model's own form, 1 us pick noise, 5 % cycle-skipped picks 15 us late). The soft-L1
    loss still feels a late pick (~3 us of pull each), so a channel's delay moves with its share of them:
    0.5 us allowed (the draw's shares differ by a few percent between channels)."""
    rng = np.random.default_rng(3)
    xy = np.c_[rng.uniform(10, 440, 300), rng.uniform(10, 340, 300)]
    delays = (0.0, -2.0, 4.0, 1.5)
    toa = synthetic_toa(xy, 1.7, metric_of(a, b), delays, t0=rng.uniform(900, 1100, (300, 1)))
    toa = toa + rng.normal(0, 1.0, toa.shape)
    toa[rng.random(toa.shape) < 0.05] += 15.0
    fit = fit_travel(toa, xy, SENSORS, anisotropic=True)
    assert fit.velocity_mm_per_us == pytest.approx(1.7, rel=0.01)
    assert np.allclose(fit.delays_us, delays, atol=0.5)
    assert np.allclose(fit.metric, metric_of(a, b), atol=0.01)
    assert 0.7 < fit.spread_us < 2.0


def _growing_bursts(f_hz, fs_hz, rise, rng, n=1024, start=300):
    """Six captures [6, 4, n] (uint16 about 2048, 1.5-count noise) of an oscillation at f_hz sampled at fs_hz,
    its amplitude rising to 300 counts as a logistic of `rise` samples from `start`, each at a random phase."""
    rows = []
    for phase in rng.uniform(0, 2 * np.pi, 6):
        t = np.arange(n) - start
        burst = 300.0 / (1.0 + np.exp(-t / rise)) * np.sin(2 * np.pi * f_hz / fs_hz * t + phase)
        rows.append(2048 + burst[None] + rng.normal(0, 1.5, (4, n)))
    return np.rint(np.array(rows)).astype(np.uint16)


def test_pick_period_is_the_caught_cycles_period():
    """A 20 kHz (then 31.25 kHz) oscillation growing over a few cycles, sampled at 100 kHz with 1.5-count
    noise: the core's pick_period is fs / f whatever its phase against the samples, within 3 % at 5 samples
    a period and 8 % at 3.2 (linear interpolation of the zero crossings; the median within 3 %)."""
    from impactsense.pipeline import as_int16
    from impactsense.signal import SignalConfig

    cfg = SignalConfig.from_dict({"fs_hz": 100000.0})
    rng = np.random.default_rng(4)
    for f_hz, tol in ((20000.0, 0.03), (31250.0, 0.08)):   # 5 and 3.2 samples a period
        raw = _core.extract_batch(as_int16(_growing_bursts(f_hz, 1e5, 4.0, rng)), cfg.core())
        assert np.all(np.isfinite(raw["pick_period"]))
        assert np.allclose(raw["pick_period"], 1e5 / f_hz, rtol=tol)
        assert np.median(raw["pick_period"]) == pytest.approx(1e5 / f_hz, rel=0.03)


def test_pick_period_reads_a_low_band_on_a_slow_logger():
    """A 1.6 kHz oscillation at 48 kHz (30 samples a period: a thick wooden plate's picks on a 48 kHz logger read
    2.7 kHz, 18 samples, with the zero crossing before the threshold up to a period back): its crossings lie beyond
    the short search (PERIOD_SEARCH) and its half periods agree, so the core reads fs / f within 5 % (the first
    cycles' crossings on a rising envelope with 1.5-count noise; the median within 2 %), where a 32-sample search
    read none."""
    from impactsense.pipeline import as_int16
    from impactsense.signal import SignalConfig

    cfg = SignalConfig.from_dict({"fs_hz": 48000.0})
    rng = np.random.default_rng(6)
    f_hz = 1600.0
    assert 1.5 * 48000.0 / f_hz + 1 > _core.PERIOD_SEARCH   # 1.5 periods and the lead: beyond the short search
    raw = _core.extract_batch(as_int16(_growing_bursts(f_hz, 48000.0, 8.0, rng)), cfg.core())
    assert np.all(np.isfinite(raw["pick_period"]))
    assert np.allclose(raw["pick_period"], 48000.0 / f_hz, rtol=0.05)
    assert np.median(raw["pick_period"]) == pytest.approx(48000.0 / f_hz, rel=0.02)


def _half_lobes(lengths, amps, rows=3, n=1024, start=300, seed=0):
    """Captures [rows, 4] (uint16 about 2048, 0.5-count noise) whose signal from `start` is a small negative lead
    (4 samples, 5 counts: under the onset threshold, so the zero crossing before the threshold crossing is its
    end) and then half sines of alternating sign (+ first) of these lengths (samples) and amplitudes (counts),
    held within the 12-bit rails."""
    x = np.zeros(n)
    t = start
    signed = [(4, -5.0)] + [(length, amp * (-1) ** k) for k, (length, amp) in enumerate(zip(lengths, amps))]
    for length, amp in signed:
        x[t:t + length] = amp * np.sin(np.pi * (np.arange(length) + 0.5) / length)
        t += length
    rng = np.random.default_rng(seed)
    return np.clip(np.rint(2048 + x + rng.normal(0, 0.5, (rows, 4, n))), 0, 4095).astype(np.uint16)


@pytest.mark.parametrize("lengths, period", [((20, 20, 20, 40), 40.0),   # one slow cycle, beyond the short search
                                             ((2, 8, 14, 40), 16.0),     # unequal halves within it: read as before
                                             ((3, 9, 30, 40), None)])    # a fast half cycle, then one side long
def test_pick_period_beyond_the_short_search_keeps_one_cycle_only(lengths, period):
    """The core's period search: crossings within PERIOD_SEARCH samples of the threshold crossing give the read
    a short search gives, whatever its half periods (2, 8, 14 samples: 16); beyond it, up to PERIOD_SEARCH_WIDE,
    the read is kept when its three half periods agree within PERIOD_HALF_RATIO (20, 20, 20: a 40-sample period)
    and not when they do not (3, 9, 30: the caught half cycle, then the signal stays on one side of the baseline
    for 30 samples; 10 x, the kind a wider search reads on a fast plate). Periods within 5 % (the half sines'
    linear sub-sample crossings)."""
    from impactsense.pipeline import as_int16
    from impactsense.signal import SignalConfig

    span = sum(lengths[:3])
    assert (span > _core.PERIOD_SEARCH) == (period != 16.0) and span < _core.PERIOD_SEARCH_WIDE
    assert (max(lengths[:3]) / min(lengths[:3]) > _core.PERIOD_HALF_RATIO) == (period != 40.0)
    cfg = SignalConfig.from_dict({"fs_hz": 100000.0})
    raw = _core.extract_batch(as_int16(_half_lobes(lengths, (300.0, 200.0, 150.0, 100.0))), cfg.core())
    assert np.all(np.isfinite(raw["toa_threshold"]) & (raw["toa_threshold"] >= 0))
    if period is None:
        assert np.all(np.isnan(raw["pick_period"]))
    else:
        assert np.allclose(raw["pick_period"], period, rtol=0.05)


def test_pick_period_searches_a_clipped_channel_only_near_its_crossing():
    """The slow cycle above (20/20/20 samples) driven to the 12-bit rails: past the rail the waveform is the front
    end's, so the core reads the period only within PERIOD_SEARCH samples: NaN here; the same shape at a fourth of
    the width (5/5/5 samples, within the short search) is still read, 10 samples within 10 % (the first crossing
    lies next to the 5-count lead against a railed lobe, not midway: +0.9 sample on the 15-sample span)."""
    from impactsense.pipeline import as_int16
    from impactsense.signal import SignalConfig

    cfg = SignalConfig.from_dict({"fs_hz": 100000.0})
    for lengths, period in (((20, 20, 20, 40), None), ((5, 5, 5, 40), 10.0)):
        raw = _core.extract_batch(as_int16(_half_lobes(lengths, (3000.0,) * 4)), cfg.core())
        assert np.all(raw["flags"] & _core.FLAG_CLIPPED)
        if period is None:
            assert np.all(np.isnan(raw["pick_period"]))
        else:
            assert np.allclose(raw["pick_period"], period, rtol=0.1)


def test_dispersion_scaled_localiser_finds_exact_positions_and_scale_one_is_bit_for_bit():
    """ToAs whose channels travel at their own speeds (a dispersive plate's picked cycles): with the
    slowness scales the localiser recovers the position inside the hull to 0.05 mm, without them it misses;
    scales of 1 and starts = 1 are the plain localiser bit for bit."""
    rng = np.random.default_rng(5)
    xy = np.c_[rng.uniform(80, 370, 30), rng.uniform(80, 270, 30)]
    scale = rng.uniform(0.85, 1.15, (30, 4)).astype(np.float32)
    toa = (100.0 + travel_distances(xy, SENSORS) * scale / 1.6).astype(np.float32)
    got = _core.localise_batch(
        toa, np.ones(toa.shape, np.uint8), SENSORS[:, 0].tolist(), SENSORS[:, 1].tolist(), 1.6, 1.0, *PLATE, 4.0,
        slowness_scale=scale.ravel().tolist())
    assert np.hypot(got["x_mm"] - xy[:, 0], got["y_mm"] - xy[:, 1]).max() < 0.05
    plain = localise(toa, 1.6)
    assert np.median(np.hypot(plain["x_mm"] - xy[:, 0], plain["y_mm"] - xy[:, 1])) > 2.0
    ones = _core.localise_batch(toa, np.ones(toa.shape, np.uint8), SENSORS[:, 0].tolist(), SENSORS[:, 1].tolist(),
                                1.6, 1.0, *PLATE, 4.0, slowness_scale=[1.0] * toa.size, starts=1)
    for key in ("x_mm", "y_mm", "t0_us", "cov"):
        assert np.array_equal(plain[key], ones[key])


def test_more_starts_find_the_answer_outside_the_sensors_hull():
    """Noise-free ToAs of drops outside the sensors' quadrilateral: refining the two best-screened starts
    and keeping the lower Huber cost never ends farther from the truth than one start, and is exact."""
    rng = np.random.default_rng(6)
    xy = np.c_[np.r_[rng.uniform(5, 45, 20), rng.uniform(405, 445, 20)], rng.uniform(5, 345, 40)]
    toa = synthetic_toa(xy, 1.7, (1.0, 0.0, 1.0)) + rng.normal(0, 1.5, (40, 4)).astype(np.float32)
    args = (np.ascontiguousarray(toa, np.float32), np.ones(toa.shape, np.uint8), SENSORS[:, 0].tolist(),
            SENSORS[:, 1].tolist(), 1.7, 1.0, *PLATE, 4.0)
    one, two = _core.localise_batch(*args, starts=1), _core.localise_batch(*args, starts=2)
    e1 = np.hypot(one["x_mm"] - xy[:, 0], one["y_mm"] - xy[:, 1])
    e2 = np.hypot(two["x_mm"] - xy[:, 0], two["y_mm"] - xy[:, 1])
    assert e2.mean() <= e1.mean() + 1e-3


def test_fit_travel_recovers_the_dispersion_exponent_and_keeps_none_without_dispersion():
    """Picks whose slowness goes as (f / 25 kHz)^-0.3 with 1 us noise: the fit finds 0.3 within 0.03; the same
    picks made without dispersion keep exponent 0 (the plain fit)."""
    rng = np.random.default_rng(7)
    xy = np.c_[rng.uniform(10, 440, 300), rng.uniform(10, 340, 300)]
    period = rng.uniform(2.8, 5.0, (300, 4))        # samples at 100 kHz: 20 .. 36 kHz
    d = travel_distances(xy, SENSORS)
    t0 = rng.uniform(900, 1100, (300, 1))
    scale = (1e5 / period / 25000.0) ** -0.3
    toa = t0 + d * scale / 1.7 + rng.normal(0, 1.0, d.shape)
    fit = fit_travel(toa, xy, SENSORS, False, period, 1e5)
    ref_scale = (fit.dispersion_ref_hz / 25000.0) ** -0.3    # v is the speed at the fit's reference frequency
    assert fit.dispersion_exponent == pytest.approx(0.3, abs=0.03)
    assert fit.velocity_mm_per_us == pytest.approx(1.7 / ref_scale, rel=0.02)
    flat = fit_travel(t0 + d / 1.7 + rng.normal(0, 1.0, d.shape), xy, SENSORS, False, period, 1e5)
    assert flat.dispersion_exponent == 0.0 and flat.velocity_mm_per_us == pytest.approx(1.7, rel=0.01)


def _noisy_drops(metric, seed):
    rng = np.random.default_rng(seed)
    xy = np.c_[rng.uniform(10, 440, 60), rng.uniform(10, 340, 60)]
    toa = synthetic_toa(xy, 2.6, metric, (0.0, 1.0, -1.0, 0.5), t0=rng.uniform(900, 1100, (60, 1)))
    return toa + rng.normal(0, 1.4, toa.shape), xy


def test_an_unknown_materials_metric_is_kept_only_when_it_explains_the_picks_clearly_better():
    """anisotropic None (an unknown material, travel.metric_choice): on an isotropic plate with 1.4 us pick noise the
    fitted metric's two parameters buy a spread gain of a few percent at most, so the Euclidean distance (the
    identity) is kept; with elliptical wavefronts (speed along x 1.3x that along y) the metric is kept, as the
    metric's fit on its own gives it."""
    toa, xy = _noisy_drops((1.0, 0.0, 1.0), 7)
    assert fit_travel(toa, xy, SENSORS, anisotropic=None).metric == (1.0, 0.0, 1.0)
    assert fit_travel(toa, xy, SENSORS, anisotropic=True).metric != (1.0, 0.0, 1.0)
    q = metric_of(-0.26, 0.05)   # (1 - a) / (1 + a) ~ 1.7 ~ 1.3^2
    toa, xy = _noisy_drops(q, 8)
    fit = fit_travel(toa, xy, SENSORS, anisotropic=None)
    assert fit.metric == fit_travel(toa, xy, SENSORS, anisotropic=True).metric
    assert np.allclose(fit.metric, q, atol=0.02)


def test_metric_choice_follows_the_material():
    """A laminate always fits the metric, a known isotropic material never, an unknown one lets the picks decide."""
    from impactsense.data import bundled_session_path, load_rig, rig_from_dict
    from impactsense.travel import metric_choice

    def rig(text):
        return rig_from_dict({**load_rig(bundled_session_path()).raw, "plate_material": text})

    assert metric_choice(rig("CFRP, fibres along x")) is True
    assert metric_choice(rig("aluminium 6061-T6")) is False
    assert metric_choice(rig("Hardox 450 wear plate")) is None
