"""One source for the core's configuration: impactcore.h's field lists reach the binding, SignalConfig, every
host builder, the C the exporter writes and the board's copy of it with the same names, values and defaults;
every builder takes the rig's sample rate (a 50 kHz session's timings are in microseconds, not halved)."""

from __future__ import annotations

import re
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import resample_poly

from impactsense import _core
from impactsense import residuals as R
from impactsense.data import load_session, rig_from_dict
from impactsense.effects import EFFECTS, context
from impactsense.export import exported_fields, signal_c, signal_struct_c
from impactsense.signal import (CORE_FIELDS, FIELDS, LOCALISER_FIELDS, SignalConfig, card_values, config_dict,
                                core_config, localiser_config, settings)

MODELS = Path(__file__).resolve().parents[1] / "models"


def _public(cls) -> set[str]:
    return {k for k in dir(cls) if not k.startswith("_")}


@pytest.fixture(scope="module")
def s1():
    s = load_session("bundled:session-1")
    return s.subset(np.arange(0, len(s), 3))   # 257 drops, every case


def _at_50khz(session):
    """The session resampled to 50 kHz (anti-aliased), its rig.json saying so."""
    adc = session.adc.astype(float)
    mean = adc.mean(axis=2, keepdims=True)
    half = np.clip(np.rint(resample_poly(adc - mean, 1, 2, axis=2) + mean), 0, session.rig.adc_max)
    rig = rig_from_dict({**session.rig.raw, "fs_hz": 50000, "samples": half.shape[2]})
    return replace(session, rig=rig, adc=half.astype(np.uint16))


def test_binding_tables_are_the_structs():
    """Every attribute of the bound structs is a field of the table, with the struct's own default."""
    for cls, fields in ((_core.CoreConfig, CORE_FIELDS), (_core.LocaliserConfig, LOCALISER_FIELDS)):
        assert _public(cls) == {f.name for f in fields}
        obj = cls()
        for f in fields:
            np.testing.assert_array_equal(np.float32(getattr(obj, f.name)), np.float32(f.default), err_msg=f.name)
            assert f.role in {"RATE", "ACQUISITION", "SAMPLES", "COPY"}
    assert FIELDS["aic_blend"].default == 0.35   # the literal of impactcore.h, not its float32 neighbour


def test_signal_config_is_the_field_list(s1):
    sig = SignalConfig.for_rig(s1.rig, aic_blend=0.8)
    assert list(asdict(sig)) == list(FIELDS)
    core, loc = sig.core(), sig.localiser()
    for f in CORE_FIELDS:
        np.testing.assert_allclose(getattr(core, f.name), getattr(sig, f.name), rtol=1e-7, err_msg=f.name)
    for f in LOCALISER_FIELDS:
        np.testing.assert_allclose(getattr(loc, f.name), getattr(sig, f.name), rtol=1e-7, err_msg=f.name)
    assert SignalConfig.from_dict({**sig.to_dict(), "not_a_field": 1}) == sig
    assert core_config(**config_dict(core)).aic_blend == core.aic_blend
    with pytest.raises(TypeError, match="aic_blnd"):
        core_config(s1.rig, aic_blnd=1.0)
    with pytest.raises(ValueError, match="channel_gain"):
        core_config(channel_gain=[1.0, 1.0])


def test_every_builder_takes_the_rigs_rate(s1):
    from impactsense.calibration.pipeline import CalibrateOptions, measured_core_config, sim_core_config
    from impactsense.effects.apply import core_config_with_effects

    rig = _at_50khz(s1.subset(np.arange(2))).rig
    built = [core_config(rig), SignalConfig.for_rig(rig).core(), measured_core_config(rig, CalibrateOptions()),
             sim_core_config(rig, CalibrateOptions()), core_config_with_effects(rig, []),
             core_config(rig, **R.TIMING_PICKER)]
    assert [c.fs_hz for c in built] == [50000.0] * len(built)
    assert localiser_config(rig).sensor_x_mm == [float(v) for v in rig.sensor_x_mm]


def test_diagnosed_delay_does_not_halve_at_50khz_circular(s1):
    """(Circular: the effect's own apply_signal puts the delay in, its fit reads it; what it proves is the rate.)
    A 20 us delay put on channel 2 of a 50 kHz session is diagnosed as 20 us (not 10: the timing residuals
    read the session's rate), and the reference's wave speed is near the 100 kHz one (within 15 %: the picker
    sees half the samples; a rate taken as 100 kHz would double it)."""
    s50 = _at_50khz(s1)
    F100, F50 = R.extract(s1), R.extract(s50)
    ref100, ref50 = R.fit_reference(F100, "calibrated"), R.fit_reference(F50, "calibrated")
    assert ref50.velocity_m_s == pytest.approx(ref100.velocity_m_s, rel=0.15)
    eff = EFFECTS["channel_delay"]
    delayed = replace(s50, adc=eff.apply_signal(s50.adc, 2, {"delay_us": 20.0}, context(s50)))
    got = eff.fit(ref50, R.extract(delayed), 2)
    assert got["delay_us"] == pytest.approx(20.0, abs=2.0)   # 2 us: a tenth of a 50 kHz sample


def _c_struct(text: str) -> list[tuple[str, int]]:
    body = re.search(r"typedef struct \{\n((?:(?!typedef).)*?)\n\} impactsense_signal_config;", text, re.S).group(1)
    return [(m.group(2), int(m.group(3) or 1)) for m in re.finditer(r"(float|int32_t) (\w+)(?:\[(\d+)\])?;", body)]


def _c_values(text: str) -> list[list[float]]:
    body = re.search(r"impactsense_signal = \{\n(.*?)\n\};", text, re.S).group(1)
    items = re.findall(r"\{[^}]*\}|[^,{}\s]+", body)
    return [[float(v.rstrip("f")) for v in re.findall(r"[-+0-9.eE]+f?", item)] for item in items]


@pytest.mark.parametrize("where", ["generated", "shipped"])
def test_exported_c_config_is_the_host_config(where, s1):
    """The C the exporter writes (struct and initializer) holds every field but the ADC rails, each equal to
    the model card's value (to float32)."""
    if where == "shipped":
        from impactsense.export import firmware_models
        header, tables = (MODELS / "impactsense_models.h").read_text(), (MODELS / "impactsense_forest_tables.c").read_text()
        card = firmware_models(MODELS)[1]
    else:
        card = SignalConfig.for_rig(s1.rig, aic_blend=0.7, rig_delay_us=[0, -0.5, -6.5, -6.25],
                                    velocity_mm_per_us=0.95, aic_before=48).to_dict()
        header, tables = signal_struct_c(), signal_c(card)
    want = settings(**card_values(card))
    members = _c_struct(header)
    assert members == [(f.name, f.count) for f in exported_fields()]
    assert {f.name for f in FIELDS.values()} - {n for n, _ in members} == {"adc_min", "adc_max", "sample_offset", "record_start",
                                                                             "capture_delay_us"}
    values = _c_values(tables)
    assert len(values) == len(members)
    for (name, count), got in zip(members, values):
        np.testing.assert_array_equal(np.float32(got), np.float32(np.reshape(want[name], count)), err_msg=name)
