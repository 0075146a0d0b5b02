"""The core's baseline (impactcore.h "baseline", features.cpp): mains hum, DC offsets and glitches do not
move the picks or the energies of measured drops; clean drops keep the plain level."""

import numpy as np
import pytest

from impactsense import _core
from impactsense.data import load_session
from impactsense.signal import core_config

FS = 100000.0


@pytest.fixture(scope="module")
def drops():
    s = load_session()
    rows = np.arange(0, len(s), 19)        # 41 drops over the plate and the heights
    return s, s.adc[rows].astype(np.int16), core_config(s.rig)


def features(adc, cfg):
    return _core.extract_batch(np.ascontiguousarray(adc), cfg)


def with_hum(adc, amp, hz, phase, offset=0.0):
    t = np.arange(adc.shape[-1]) / FS
    return np.clip(np.rint(adc + offset + amp * np.sin(2 * np.pi * hz * t + phase)), 0, 4095).astype(np.int16)


def test_clean_drops_keep_the_plain_level():
    for name in (None, "bundled:session-2"):
        s = load_session(name)
        out = features(s.adc.astype(np.int16), core_config(s.rig))
        assert not np.any(out["flags"] & (_core.FLAG_HUM | _core.FLAG_GLITCH)), s.name


@pytest.mark.parametrize("hz", [50.0, 60.0])
def test_hum_of_150_counts_at_any_phase_leaves_picks_and_energies(drops, hz):
    """Picks within 2 samples (20 us) of the clean picks on every channel, 95 % within 1.5 samples, the median within 0.2 (the
    model's residual of a count or two moves a 10-count threshold crossing on a slow first lobe); the
    arrival energy (the twin's feature) within 1 % on 95 % of channels; the hum's amplitude recovered."""
    _, adc, cfg = drops
    clean = features(adc, cfg)
    for phase in np.linspace(0, 2 * np.pi, 4, endpoint=False):
        out = features(with_hum(adc, 150, hz, phase, offset=37), cfg)
        assert np.all(out["flags"] & _core.FLAG_HUM)
        assert np.all(np.abs(out["hum_counts"] - 150) < 15)
        d = np.abs(out["toa_us"] - clean["toa_us"])
        assert d.max() <= 20.0 and np.percentile(d, 95) <= 15.0 and np.median(d) <= 2.0, (phase, d.max())
        arrival = np.log10(out["window_energy"].sum(-1) / clean["window_energy"].sum(-1))
        assert np.percentile(np.abs(arrival), 95) < np.log10(1.01)


def test_each_event_finds_its_own_mains_frequency(drops):
    """Once a channel's fit tells 50 from 60 Hz, the event's later channels fit that frequency alone; the next
    event starts afresh: events alternating 50 and 60 Hz hum in one batch recover each hum's amplitude on every
    channel (an event fitted at the other frequency misses a 150-count hum by far more than 15 counts)."""
    _, adc, cfg = drops
    hummed = np.stack([with_hum(a, 150, 50.0 if i % 2 == 0 else 60.0, 0.7 * i) for i, a in enumerate(adc)])
    out = features(hummed, cfg)
    assert np.all(out["flags"] & _core.FLAG_HUM)
    assert np.all(np.abs(out["hum_counts"] - 150) < 15)


@pytest.mark.parametrize("amp", [6.0, 40.0, 400.0])
def test_a_hum_channels_peak_is_the_whole_captures(drops, amp):
    """A hum channel's peak (largest |x - baseline|) is taken partly from the onset scan's block extremes and
    partly by the pruned scan after the crossing: bit for bit the full scan's, with a hum weaker than the
    arrival, near it and stronger (the largest sample then before the crossing), and a glitch before it."""
    _, adc, cfg = drops
    for phase in (0.3, 2.0):
        x = with_hum(adc, amp, 50.0, phase, offset=11)
        x[::3, 1, 300] = 4000                              # a glitch before most onsets
        out = features(x, cfg)
        hum = (out["flags"] & _core.FLAG_HUM) != 0
        assert hum.mean() > 0.5, (amp, hum.mean())
        want = np.max(np.abs(x.astype(np.float32) - out["baseline"][..., None].astype(np.float32)), axis=-1)
        assert np.array_equal(out["peak"], want), (amp, phase)


def spiked(adc, size: float, window):
    """adc with a one- or two-sample spike of +-size counts on one random channel of each drop, starting at a
    random sample in window(r, c) = [lo, hi) (None: that drop stays clean); returns (adc, [(r, c) spiked])."""
    rng = np.random.default_rng(int(size))
    bad = adc.copy()
    where = []
    for r in range(adc.shape[0]):
        c = int(rng.integers(4))
        span = window(r, c)
        if span is None:
            continue
        i = int(rng.integers(*span))
        width = 1 + (r % 2)
        bad[r, c, i:i + width] += np.int16(size * rng.choice([-1, 1]))
        where.append((r, c))
    return bad, where


@pytest.mark.parametrize("size", [25.0, 200.0, 2000.0])
def test_a_spike_before_the_arrival_is_never_the_pick(drops, size):
    """A one- or two-sample spike anywhere between the capture start and the arrival, of any size from
    2.5x the threshold up: the pick stays within a sample (10 us) of the clean pick (a spike in the baseline
    segment or the AIC window is left out of them, which moves them by less), the channel says GLITCH."""
    _, adc, cfg = drops
    clean = features(adc, cfg)
    bad, where = spiked(adc, size, lambda r, c: (1, int(clean["toa_threshold"][r, c]) - 8))
    out = features(bad, cfg)
    for r, c in where:
        assert out["toa_us"][r, c] == pytest.approx(clean["toa_us"][r, c], abs=10.0), (r, c)
        assert out["flags"][r, c] & _core.FLAG_GLITCH


def test_dc_offsets_move_nothing(drops):
    """+123 counts on every sample: the same picks and energies (channels that reach the rails after the
    shift left out: clipping does change them)."""
    _, adc, cfg = drops
    clean = features(adc, cfg)
    shifted = adc.astype(np.int32) + 123
    ok = (shifted.max(-1) < 4095) & ~(clean["flags"] & _core.FLAG_CLIPPED).astype(bool)
    out = features(np.clip(shifted, 0, 4095).astype(np.int16), cfg)
    assert ok.sum() > 100
    np.testing.assert_allclose(out["toa_us"][ok], clean["toa_us"][ok], atol=0.05)   # float rounding of the AIC
    np.testing.assert_allclose(out["energy"][ok], clean["energy"][ok], rtol=1e-5)
    # the arrival's energy (onset to n2; a pick rounding across a sample moves the five windows' edges)
    np.testing.assert_allclose(out["window_energy"].sum(-1)[ok], clean["window_energy"].sum(-1)[ok], rtol=1e-3)
    np.testing.assert_allclose(out["diff_energy"][ok], clean["diff_energy"][ok], rtol=1e-3)


@pytest.mark.parametrize("size", [1000.0, 2000.0])
def test_a_spike_after_the_arrival_leaves_the_energies(drops, size):
    """A one- or two-sample spike in the rung-down tail (after n2) holds more than 1 - n2_fraction of the
    capture's energy: without care n2 jumps to it and the arrival's windows take the ringing up to it. The
    core finds the spike where n2 landed and takes it out: n2 and the arrival energy (the twin's feature)
    stay the clean ones (n2 within 2 samples on 95 % of the hit channels, the arrival energy within 1 %),
    the channel says GLITCH. (A smaller spike that does not hold the tail's energy moves n2 later without
    landing on it: not found; docs/findings.md "A faulty lab".)"""
    _, adc, cfg = drops
    clean = features(adc, cfg)
    end = adc.shape[-1] - 4
    bad, where = spiked(adc, size, lambda r, c: (int(clean["n2"][r, c]) + 50, end)
                        if int(clean["n2"][r, c]) + 50 < end else None)
    out = features(bad, cfg)
    r, c = np.array(where).T
    assert np.mean(out["flags"][r, c] & _core.FLAG_GLITCH != 0) >= 0.9
    assert np.percentile(np.abs(out["n2"][r, c] - clean["n2"][r, c]), 95) <= 2
    arrival = np.log10(out["window_energy"][r, c].sum(-1) / clean["window_energy"][r, c].sum(-1))
    assert np.percentile(np.abs(arrival), 95) < np.log10(1.01)
    # the other channels are untouched
    other = np.ones(out["n2"].shape, bool)
    other[r, c] = False
    np.testing.assert_array_equal(out["n2"][other], clean["n2"][other])


@pytest.mark.parametrize("size", [400.0, 1500.0])
def test_a_spike_inside_the_arrival_leaves_the_energies(drops, size):
    """A one- or two-sample spike within the difference window (10..200 samples after the onset) adds ~20
    size^2 to the channel's Delta^3 energy: its Delta^3 / Delta^1 then stands out from the other channels'
    and the core hunts the spike there and takes it out of the windows, n2 and the difference energies
    (the channel says GLITCH); the other channels are untouched. The spike points toward the baseline so
    that it does not reach the rail; channels clipped without it are left alone (no twin features)."""
    _, adc, cfg = drops
    clean = features(adc, cfg)
    rng = np.random.default_rng(int(size))
    bad = adc.copy()
    where = []
    for r in range(adc.shape[0]):
        c = int(rng.integers(4))
        if clean["flags"][r, c] & _core.FLAG_CLIPPED:   # no twin features, no ratio test: another case
            continue
        i = int(clean["toa_threshold"][r, c]) + int(rng.integers(10, 200))
        width = 1 + (r % 2)
        sign = -1 if bad[r, c, i] > 2048 else 1
        bad[r, c, i:i + width] = np.clip(bad[r, c, i:i + width] + sign * size, 0, 4095).astype(np.int16)
        where.append((r, c))
    out = features(bad, cfg)
    r, c = np.array(where).T
    assert np.mean(out["flags"][r, c] & _core.FLAG_GLITCH != 0) >= 0.9
    delta3 = np.abs(np.log10(out["diff_energy"][r, c, 2] / clean["diff_energy"][r, c, 2]))
    arrival = np.abs(np.log10(out["window_energy"][r, c].sum(-1) / clean["window_energy"][r, c].sum(-1)))
    # raw, the spike would raise Delta^3 by log10(1 + 20 size^2 / E3) (~0.3..2 here)
    assert np.percentile(delta3, 90) < np.log10(1.05) and np.percentile(arrival, 90) < np.log10(1.02)
    assert np.percentile(np.abs(out["n2"][r, c] - clean["n2"][r, c]), 90) <= 2
    other = np.ones(out["n2"].shape, bool)
    other[r, c] = False
    for key in ("n2", "toa_us", "diff_energy", "window_energy", "flags"):
        np.testing.assert_array_equal(out[key][other], clean[key][other])


def test_the_hum_basis_kept_between_events_follows_the_rate(drops):
    """extract_features keeps the rate's hum basis (the mains frequencies' rotations) from event to event: events
    at another rate in between (the basis made again for it) leave a hum channel's outputs bit for bit what they
    were, and the hum at that other rate is modelled at its own frequency."""
    s, adc, cfg = drops
    hum100 = with_hum(adc[:8], 150, 50.0, 0.7, offset=20)
    first = features(hum100, cfg)
    assert np.all(first["flags"] & _core.FLAG_HUM)
    # the same drops at half the rate with a 60 Hz hum: the basis is set for 50 kHz
    t = np.arange(adc.shape[-1] // 2) / (FS / 2)
    hum50 = np.clip(np.rint(adc[:8, :, ::2] + 150 * np.sin(2 * np.pi * 60.0 * t + 0.7)), 0, 4095).astype(np.int16)
    other = features(np.ascontiguousarray(hum50), core_config(s.rig, fs_hz=FS / 2))
    assert np.all(other["flags"] & _core.FLAG_HUM) and np.all(np.abs(other["hum_counts"] - 150) < 15)
    again = features(hum100, cfg)
    for k, v in first.items():
        assert np.array_equal(np.asarray(v), np.asarray(again[k]), equal_nan=True), k


def test_a_hum_on_the_longest_capture_leaves_the_energies(drops):
    """The hum model is stepped block to block by the sinusoid's two-term recurrence (HumSteps, HumEnergy): on the
    longest capture the core takes (kMaxSamples, 512 blocks, four 50 Hz periods at 100 kHz) a 150-count hum leaves
    the capture's energy within 0.5 % of the same capture's without it on 95 % of channels (measured ~0.3 %; a 50 Hz
    residual of 3 counts left over the capture adds ~0.2 %, 5 counts ~0.5 %), the arrival's within 1 %."""
    _, adc, cfg = drops
    n = _core.MAX_SAMPLES
    rows = adc[:12]
    quiet = rows[..., :150]
    reps = -(-(n - rows.shape[-1]) // quiet.shape[-1])
    long = np.concatenate([rows, np.tile(quiet, reps)], -1)[..., :n]
    clean = features(long, cfg)
    out = features(with_hum(long, 150, 50.0, 1.1, offset=-25), cfg)
    assert np.all(out["flags"] & _core.FLAG_HUM)
    ratio = np.log10(out["energy"] / clean["energy"])
    assert np.percentile(np.abs(ratio), 95) < np.log10(1.005), np.abs(ratio).max()
    arrival = np.log10(out["window_energy"].sum(-1) / clean["window_energy"].sum(-1))
    assert np.percentile(np.abs(arrival), 95) < np.log10(1.01)
