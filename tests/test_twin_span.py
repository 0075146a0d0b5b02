"""The twin's simulated span read from the rig's calibration drops (`calibration.span`, docs/method.md "The twin's
span"): the core's n2 after the onset measured on ringing records, and the rule's bounds."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from impactsense import _core
from impactsense.calibration import span
from impactsense.data import load_session
from impactsense.signal import SignalConfig, core_samples
from impactsense.sim import SimParams

SESSION1 = Path(__file__).resolve().parents[1] / "host/impactsense/data/session-1"
ONSET = 300          # samples of quiet start before the ring


@pytest.fixture(scope="module")
def rig():
    return load_session(SESSION1).rig


def ringing_records(rig, amp_decay_per_s: float, n: int = 3) -> np.ndarray:
    """n drops whose four channels ring at 8 kHz from ONSET with the amplitude falling as exp(-a t)."""
    fs, s = float(rig.fs_hz), int(rig.samples)
    t = (np.arange(s) - ONSET) / fs
    ring = np.where(t >= 0, 600.0 * np.exp(-amp_decay_per_s * np.clip(t, 0, None)) * np.sin(2 * np.pi * 8e3 * t), 0.0)
    rng = np.random.default_rng(0)
    adc = rig.bias_counts + ring[None, None, :] + rng.normal(0, 1.0, (n, 4, s))
    return np.clip(np.rint(adc), 0, rig.adc_max).astype(np.uint16)


def n2_expected_ms(rig, a: float, fraction: float = 0.99) -> float:
    """Where exp(-2 a t)'s cumulative energy over the record after the onset reaches `fraction` of it."""
    T = (rig.samples - ONSET) / rig.fs_hz
    return -math.log(1 - fraction * (1 - math.exp(-2 * a * T))) / (2 * a) * 1e3


@pytest.mark.parametrize("a", [600.0, 60.0, 10.0])
def test_the_measured_span_is_where_the_rings_energy_is_in(rig, a):
    """A plate that stops ringing early (a = 600 1/s: n2 ~ 3.8 ms), one that rings past the twin's default span
    (60: ~38 ms) and one that rings through the record (10: n2 near its end): the core's n2 after the first
    crossing follows the energy law within 0.3 ms (a crossing is a few samples after the onset)."""
    cfg = SignalConfig.for_rig(rig).core()
    adc = ringing_records(rig, a)
    feats = _core.extract_batch(core_samples(adc, cfg), cfg)
    got = span.measured_span_ms(feats, range(adc.shape[0]), float(rig.fs_hz))
    assert got == pytest.approx(n2_expected_ms(rig, a), abs=0.3), (got, n2_expected_ms(rig, a))


def fake_feats(after_samples: float, rows: int = 4) -> dict:
    cross = np.full((rows, 4), 400.0)
    cross[:, 1:] += 30.0                                  # the first crossing is channel 0's
    return {"toa_threshold": cross, "n2": np.full((rows, 4), int(400 + after_samples), np.int32)}


def test_the_rule_keeps_a_short_ringing_twin_and_follows_a_long_one(rig, monkeypatch):
    params = SimParams.from_rig(rig, element_mm=8.0)          # a coarse mesh: only the rule is asserted
    fs = float(rig.fs_hz)
    short = span.twin_span(params, rig, fake_feats(0.004 * fs), range(4))        # 4 ms: inside the default 6 ms
    assert short["duration_ms"] == params.duration_ms and short["bound"] == "default"
    long = span.twin_span(params, rig, fake_feats(0.020 * fs), range(4))         # 20 ms past the first crossing
    assert long["bound"] == "measured"
    assert long["duration_ms"] == pytest.approx(20.0, abs=0.01)
    # the twin's record: what the core reads after the touch at the twin's pre-trigger (the cost's bounds lifted)
    monkeypatch.setattr(span, "FIELDS_MAX_BYTES", math.inf)
    monkeypatch.setattr(span, "RUNS_MAX_CPU_S", math.inf)
    past = span.twin_span(params, rig, fake_feats(rig.samples), range(4))
    assert past["bound"] == "record"
    assert past["duration_ms"] == pytest.approx((rig.samples - params.pretrigger_samples) / fs * 1e3)
    # no usable channel: the default
    none = span.twin_span(params, rig, {"toa_threshold": np.full((2, 4), np.nan), "n2": np.full((2, 4), -1)}, [0, 1])
    assert none["duration_ms"] == params.duration_ms and none["measured_n2_ms"] is None


def test_the_span_is_held_within_its_memory(rig, monkeypatch):
    """The four reciprocal fields ([samples, nodes] float32 each) at the chosen span fit FIELDS_MAX_BYTES."""
    from impactsense.sim.simulate import get_model

    params = SimParams.from_rig(rig, element_mm=8.0)
    model = get_model(params, rig)
    per_ms = 4 * model.n_record * model.nodes * 4 / params.duration_ms
    monkeypatch.setattr(span, "FIELDS_MAX_BYTES", per_ms * 15.0)        # room for 15 ms
    got = span.twin_span(params, rig, fake_feats(0.030 * float(rig.fs_hz)), range(4))
    assert got["bound"] == "cost" and got["duration_ms"] == pytest.approx(15.0, abs=0.01)
    longer = get_model(params.replace(duration_ms=got["duration_ms"]), rig)
    assert 4 * longer.n_record * longer.nodes * 4 <= per_ms * 15.0 * 1.01


def test_the_span_option_is_checked():
    """`calibrate --twin-span` takes measured (the rule) or default (the simulator's span), nothing else."""
    from impactsense.calibration.options import CalibrateOptions
    from impactsense.errors import ConfigError

    CalibrateOptions(twin_span="default").validate()
    with pytest.raises(ConfigError, match="--twin-span"):
        CalibrateOptions(twin_span="long").validate()
