"""benchmarks/synthetic_rig.py's KINDS: every kind's rig.json reads as a user's would (data.rig_from_dict), its
truth's keys are the simulator's, and its logger keeps the far arrivals (record_window)."""

import dataclasses
import importlib.util
from pathlib import Path

import pytest

from impactsense.data import rig_from_dict
from impactsense.record_window import window_check
from impactsense.sim import SimParams

_SPEC = importlib.util.spec_from_file_location("synthetic_rig",
                                               Path(__file__).resolve().parents[1] / "benchmarks" / "synthetic_rig.py")
synthetic_rig = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(synthetic_rig)


@pytest.mark.parametrize("kind", sorted(synthetic_rig.KINDS))
def test_kind_is_a_valid_rig(kind):
    spec = synthetic_rig.KINDS[kind]
    raw = dict(spec["rig"])
    raw.setdefault("density_kg_m3", spec["sim"].get("density_kg_m3"))
    rig = rig_from_dict({k: v for k, v in raw.items() if v is not None})
    fields = {f.name for f in dataclasses.fields(SimParams)}
    assert set(spec["sim"]) <= fields | {"density_kg_m3"}
    pre = spec["sim"].get("pretrigger_samples")
    assert pre is not None and not window_check(rig, rig.samples, pre)["short"]


@pytest.mark.parametrize("kind", sorted(synthetic_rig.KINDS))
def test_truth_covers_the_decay_window(kind):
    """A synthetic session's simulated span covers calibrate's envelope-decay window where its record keeps it
    (before: 6 ms, faded out over its last 1 ms, inside the 1..8 ms window: alu-large-thin's decay read 285 1/s
    against 93 with 10 ms simulated, and calibrate's D_s 734 1/s against the truth's 250)."""
    from impactsense.calibration.damping import DECAY_DURATION_MS, MAX_MS

    spec = synthetic_rig.KINDS[kind]
    raw = dict(spec["rig"])
    raw.setdefault("density_kg_m3", spec["sim"].get("density_kg_m3"))
    rig = rig_from_dict(raw)
    pre = spec["sim"]["pretrigger_samples"]
    duration = synthetic_rig.sim_duration_ms(rig, pre, SimParams().duration_ms)
    after_ms = (rig.samples - pre) / rig.fs_hz * 1e3
    assert duration >= SimParams().duration_ms
    if after_ms >= DECAY_DURATION_MS:
        assert duration - SimParams().taper_ms >= MAX_MS   # the fade starts after the window's end
    else:
        assert duration >= after_ms                         # the whole record is simulated


def test_audio_front_end_sags_and_rings_before_the_arrival():
    """glass-audio's logger (`_filtered_adc`): the 10 Hz AC coupling lets a held level sag as exp(-2 pi f_c t) and
    the centred linear-phase FIR puts a little ringing before a sharp arrival, symmetric about it."""
    import numpy as np

    spec = synthetic_rig.KINDS["glass-audio"]
    rig = rig_from_dict(spec["rig"])
    front = dict(spec["front_end"], noise_counts=0.0)
    params = SimParams.from_rig(rig).replace(pretrigger_samples=512, circuit_gain=1.0, noise_counts_rms=0.0)
    volts = np.zeros((1, 4, rig.samples - 512))
    volts[0, 0, :] = 1000 * rig.vref / 2 ** rig.adc_bits        # a held level of 1000 counts from the touch
    volts[0, 1, 300] = 20000 * rig.vref / 2 ** rig.adc_bits       # one sharp arrival
    adc = synthetic_rig._filtered_adc(volts, params, rig, front, seed=0).astype(float) - rig.bias_counts
    t_ms = 30.0
    k = 512 + int(t_ms * 1e-3 * rig.fs_hz)
    assert adc[0, 0, k] == pytest.approx(1000 * np.exp(-2 * np.pi * front["highpass_hz"] * t_ms * 1e-3), abs=25)
    arrival = 512 + 300
    before, after = adc[0, 1, arrival - 63:arrival], adc[0, 1, arrival + 1:arrival + 64][::-1]
    assert np.abs(before).max() > 10                              # pre-ringing ahead of the arrival
    assert np.allclose(before, after, atol=20)    # linear phase: the same ringing after it (less the ~13-count sag)


def _truth_params(kind: str, element_mm: float):
    spec = synthetic_rig.KINDS[kind]
    sim, raw = dict(spec["sim"]), dict(spec["rig"])
    rig = rig_from_dict(dict(raw, density_kg_m3=sim.pop("density_kg_m3", raw.get("density_kg_m3"))))
    return SimParams.from_rig(rig).replace(element_mm=element_mm, max_height_mm=float(max(spec["heights"])),
                                           **sim), rig


def test_mesh_note_names_a_mesh_too_coarse_for_the_band():
    """A mesh whose elements cut an A0 wavelength at the contact's band into fewer than 6 is named, with the
    frequency it resolves; one that resolves the band is not (a 4 mm mesh on a 1.5 mm steel strip read at
    500 kHz resolves A0 to ~24 kHz: its picks at 50-100 kHz read a dispersion exponent of ~1, the plate's ~0.4)."""
    from impactsense.sim.dispersion import a0_wavelength

    params, rig = _truth_params("ss-strip-edge", 4.0)
    note = synthetic_rig.mesh_note(params, rig)
    assert note is not None and "resolved" in note
    f_ok = float(note.split("up to ")[1].split(" kHz")[0]) * 1e3
    # at that frequency the wavelength spans the stated number of elements
    lam_mm = a0_wavelength(f_ok, params.e_pa, params.nu, params.rho_kg_m3, params.thickness_mm * 1e-3) * 1e3
    assert lam_mm / 4.0 == pytest.approx(synthetic_rig.RESOLVED_ELEMENTS_PER_WAVELENGTH, rel=0.05)
    fine, rig = _truth_params("ss-strip-edge", 1.0)
    assert synthetic_rig.mesh_note(fine, rig) is None


def test_thick_soft_plate_record_window_reads_the_mindlin_speed():
    """hdpe-kite (12 mm HDPE, no density in rig.json): the density is the table's polyethylene (within 1 % of the
    truth's), and the record check takes the far arrivals at the thick plate's Mindlin group speed: 466 mm of path
    difference needs ~0.7 ms at the truth's A0 group velocity (10 kHz, sim.dispersion); a record kept 0.55 ms
    after the first arrival is SHORT (Kirchhoff's sqrt(omega) law read 1.04 mm/us, 0.45 ms: not short)."""
    from impactsense.sim.dispersion import a0_group_velocity

    spec = synthetic_rig.KINDS["hdpe-kite"]
    rig = rig_from_dict(spec["rig"])
    truth = spec["sim"]
    assert rig.density_kg_m3 == pytest.approx(truth["density_kg_m3"], rel=0.01)
    v_truth = float(a0_group_velocity(10e3, truth["e_pa"], truth["nu"], truth["density_kg_m3"],
                                      rig.thickness_mm * 1e-3)) * 1e-3
    pre = truth["pretrigger_samples"]
    check = window_check(rig, pre + int(0.55e-3 * rig.fs_hz), pre)
    assert check["velocity_mm_per_us"] == pytest.approx(v_truth, rel=0.15)
    assert check["short"]
    assert check["far_arrival_ms"] == pytest.approx(check["path_difference_mm"] / v_truth * 1e-3, rel=0.15)


def test_low_rate_logger_record_window_reads_the_velocity_it_can_record():
    """pvc-slowlog (a 20 kHz logger: nothing above 10 kHz in its records): the record check reads the plate's
    velocity at a quarter of the rate, 5 kHz (within 10 % of the truth's A0 group velocity there; the picks'
    travel fit on the session reads 0.52 mm/us at their 5.7 kHz), not at 10 kHz, where the waves run ~25 % faster
    and the far arrivals would be said to come ~0.2 ms sooner; a record kept 0.9 ms after the first arrival is
    SHORT (before: not). A 50 kHz logger keeps 10 kHz."""
    from impactsense.record_window import REFERENCE_HZ, reference_hz
    from impactsense.sim.dispersion import a0_group_velocity

    spec = synthetic_rig.KINDS["pvc-slowlog"]
    rig = rig_from_dict(spec["rig"])
    truth = spec["sim"]
    h_m = rig.thickness_mm * 1e-3
    v5, v10 = (float(a0_group_velocity(f, truth["e_pa"], truth["nu"], rig.density_kg_m3, h_m)) * 1e-3
               for f in (5e3, 10e3))
    assert v10 > 1.2 * v5
    pre = truth["pretrigger_samples"]
    check = window_check(rig, pre + int(0.9e-3 * rig.fs_hz), pre)
    assert check["reference_hz"] == pytest.approx(5e3)
    assert check["velocity_mm_per_us"] == pytest.approx(v5, rel=0.10)
    assert check["short"]
    assert reference_hz(50e3) == REFERENCE_HZ
