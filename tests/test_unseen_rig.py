"""A new user's rig.json as written (issue 15): fields left out, the material in other words. Cheap: rig.json only."""

import json

import pytest

from impactsense.data import rig_from_dict
from impactsense.errors import DataError
from impactsense.materials import material_for_rig


@pytest.mark.parametrize("text, name, orthotropic", [
    ("Graphite/epoxy cross-ply [0/90]2s", "CFRP laminate", True),
    ("titanium grade 5 (Ti-6Al-4V)", "titanium", False),
    ("brass CuZn37", "brass / bronze", False),
    ("copper sheet, Cu-ETP", "copper", False),
])
def test_other_words_for_a_material_find_its_priors(session1, text, name, orthotropic):
    mat = material_for_rig(rig_from_dict({**session1.rig.to_dict(), "plate_material": text}))
    assert (mat.name, mat.orthotropic, mat.known) == (name, orthotropic, True)


def test_a_rig_json_without_density_takes_the_materials_typical_one(session1):
    raw = {k: v for k, v in session1.rig.to_dict().items() if k != "density_kg_m3"}
    rig = rig_from_dict({**raw, "plate_material": "Graphite/epoxy cross-ply"})
    mat = material_for_rig(rig)
    assert rig.density_kg_m3 == mat.density_kg_m3.value
    assert mat.density_kg_m3.lo <= rig.density_kg_m3 <= mat.density_kg_m3.hi
    # the declared one wins when given
    assert rig_from_dict({**raw, "density_kg_m3": 1600.0}).density_kg_m3 == 1600.0


def test_a_rig_json_without_density_of_an_unknown_material_is_a_clear_error(session1):
    raw = {k: v for k, v in session1.rig.to_dict().items() if k != "density_kg_m3"}
    with pytest.raises(DataError, match="density_kg_m3.*not in the materials table"):
        rig_from_dict({**raw, "plate_material": "unobtainium foam"})


def test_calibrate_says_when_an_isotropic_constant_stops_at_the_materials_bound(tmp_path, session1):
    """A brass plate's four drops put nu on the table's upper bound (0.37; truth 0.34), printed as a fitted
    value before; the summary now names it, as it names a laminate's constants."""
    from impactsense.commands.calibrate import _at_bounds

    (tmp_path / "rig.json").write_text(json.dumps(dict(session1.rig.to_dict(), plate_material="brass CuZn37")))
    cal = {"data": str(tmp_path)}
    text = _at_bounds(cal, {"E_mpa": 100250.0, "nu": 0.37})
    assert "nu 0.370 (upper)" in text and "MPa" not in text
    assert _at_bounds(cal, {"E_mpa": 100250.0, "nu": 0.34}) == ""
    assert "E 90000 MPa (lower)" in _at_bounds(cal, {"E_mpa": 90000.0, "nu": 0.34})


def test_info_says_which_material_and_density_the_project_assumed(session1):
    from impactsense.commands.info import plate_summary

    raw = {k: v for k, v in session1.rig.to_dict().items() if k != "density_kg_m3"}
    pl = plate_summary(rig_from_dict({**raw, "plate_material": "Graphite/epoxy", "material_axes": {"fibre_angle_deg": 90}}))
    assert (pl["material"], pl["kind"], pl["axis_deg"], pl["density_kg_m3"]) == ("CFRP laminate", "orthotropic", 90.0, 1550.0)
    assert "materials table" in pl["density_from"]
    assert plate_summary(session1.rig)["density_from"] == "rig.json"


def test_a_calibration_without_the_pzt_design_matches_the_twins_peaks_to_the_loggers(session1):
    """calibrate --no-fem / --plate-only kept the seed's circuit gain (the bundled logger's): on a 16-bit
    logger and a thin laminate the twin's drops went past the int16 range and simulate-dataset stopped. The
    gain is now scaled so that the four calibration drops peak as measured; a probe that clips is repeated at
    a smaller gain. Here the 'twin' is the measured drops themselves, linear in the gain (truth 0.004)."""
    from types import SimpleNamespace

    import numpy as np

    from impactsense.calibration.logger_gain import fit_logger_gain, record_peaks

    rig, rows = session1.rig, np.arange(4) * 37
    adc = session1.adc[rows].astype(float)
    truth = 0.004

    def twin(flat, rig_, x, y, h):
        counts = rig.bias_counts + (adc - rig.bias_counts) * flat["circuit_gain"] / truth
        return np.clip(np.rint(counts), 0, rig.adc_max).astype(np.uint16)

    targets = SimpleNamespace(x_mm=session1.x_mm[rows], y_mm=session1.y_mm[rows], height_mm=session1.height_mm[rows],
                              peak=record_peaks(session1.adc[rows], 100))
    problem = SimpleNamespace(rig=rig, targets=targets, params={"circuit_gain": 0.04}, simulate=None,
                              opts=SimpleNamespace(workers=1))
    probes = []
    out = fit_logger_gain(problem, lambda *a: probes.append(a[0]["circuit_gain"]) or twin(*a))
    assert len(probes) == 2 and probes[1] == probes[0] / 16       # x10 the measured clips; 1/16 of it does not
    assert abs(problem.params["circuit_gain"] / truth - 1) < 0.02
    assert abs(out["over_seed"] - truth / 0.04) < 0.002


def test_a_flagged_channel_with_a_diagnosed_low_pass_goes_to_the_bond_choice():
    """A debonded disc's late picks ask for a move beyond a re-glued disc's, so its channel was left out with
    its low-pass and gain dropped. On a layout with two sensors 48 mm apart the three others placed worse
    (18.9 mm) than the four with the bond put in (12.8 mm). Now a flagged channel with a diagnosed low-pass
    keeps it and the bond choice decides; a flagged channel without one is left out as before."""
    from types import SimpleNamespace as C

    from impactsense.commands.retrain import bond_decides

    result = {"unabsorbed_channels": [{"sensor": 2}]}
    bond = [C(effect="channel_lowpass", sensor=2), C(effect="sensor_gain", sensor=2)]
    assert bond_decides(result, bond) == []
    assert bond_decides(result, [C(effect="sensor_gain", sensor=2), C(effect="channel_delay", sensor=2)]) == [2]
    assert bond_decides(result, [C(effect="channel_lowpass", sensor=1)]) == [2]
    assert bond_decides({"unabsorbed_channels": []}, bond) == []


def test_a_16_bit_loggers_twin_clips_at_its_rails_instead_of_stopping(session1):
    """The site map's twin counts (to_adc clip=False) past the int16 range stopped simulate-dataset on a 16-bit
    logger, whose rails the int16 range is: a drop next to a sensor clips there as the measured ones do. A
    logger of fewer bits keeps its drops whole up to the int16 range and still stops beyond, saying why."""
    import numpy as np

    from impactsense.errors import ConfigError
    from impactsense.sim import SimParams, to_adc

    volts = np.zeros((1, 4, 50))
    volts[0, :, 5] = [1e3, -1e3, 1.0, 0.0]
    params = SimParams(pretrigger_samples=10)
    rig16 = rig_from_dict({**session1.rig.to_dict(), "adc_bits": 16, "bias_counts": 32768, "samples": 100})
    out = to_adc(volts, params, rig16, clip=False)
    assert out.dtype == np.int16 and out[0, :, 15].tolist()[:2] == [32767, -32768]
    assert abs(int(out[0, 2, 15]) - round(params.circuit_gain * 65536 / rig16.vref)) <= 1
    rig12 = rig_from_dict({**session1.rig.to_dict(), "samples": 100})
    to_adc(volts, params, rig12, clip=False)     # its typical drop (median channel peak) within int16: kept
    with pytest.raises(ConfigError, match="calibrate again"):
        to_adc(volts * 2.0, params, rig12, clip=False)   # the typical drop past int16 itself


def test_a_drop_next_to_a_sensor_past_int16_clips_when_the_twins_gain_fits_the_logger(session1):
    """cfrp-ud-strip (a thin strip, a 12.7 mm ball, a 14-bit logger): the calibrated twin's virtual drops peaked as
    measured, yet one site-map drop next to a sensor reached 37,078 counts and simulate-dataset stopped with
    "the twin's gain does not fit this logger (calibrate again)". Only a typical drop past the rails says that; a
    few such drops clip at the int16 range, as a measured one clips at the rails."""
    import numpy as np

    from impactsense.errors import ConfigError
    from impactsense.sim import SimParams, to_adc

    params = SimParams(pretrigger_samples=10)
    rig14 = rig_from_dict({**session1.rig.to_dict(), "adc_bits": 14, "bias_counts": 8192, "samples": 100})
    per_volt = params.circuit_gain * 2 ** 14 / rig14.vref
    volts = np.zeros((20, 4, 50))
    volts[:, :, 5] = 2000.0 / per_volt                  # typical drops: 2000 counts, a quarter of the rails
    volts[3, 1, 5] = 40000.0 / per_volt                 # one next to a sensor: past int16 with the bias
    out = to_adc(volts, params, rig14, clip=False)
    assert out[3, 1, 15] == 32767 and abs(int(out[0, 0, 15]) - (8192 + 2000)) <= 1
    with pytest.raises(ConfigError, match="typical simulated drop.*calibrate again"):
        to_adc(volts * 20.0, params, rig14, clip=False)   # every drop past int16 itself: the gain is wrong


def test_a_hot_front_ends_typical_drop_past_the_rails_is_kept_whole(session1):
    """mg-clip (a 14-bit logger whose gain the lab set on its low drops: most drops clip): the calibrated twin's
    typical site-map drop peaked at 9,072 counts, past the 8,191 of the rails, as the measured drops do, and
    simulate-dataset stopped after its virtual drops ("the twin's gain does not fit this logger"). The map keeps
    such drops whole up to the int16 range; a drop past int16 still clips there."""
    import numpy as np

    from impactsense.sim import SimParams, to_adc

    params = SimParams(pretrigger_samples=10)
    rig14 = rig_from_dict({**session1.rig.to_dict(), "adc_bits": 14, "bias_counts": 8192, "samples": 100})
    per_volt = params.circuit_gain * 2 ** 14 / rig14.vref
    volts = np.zeros((20, 4, 50))
    volts[:, :, 5] = 9072.0 / per_volt                  # typical drops past the 14-bit rails
    volts[3, 1, 5] = 40000.0 / per_volt                 # one next to a sensor: past int16 with the bias
    out = to_adc(volts, params, rig14, clip=False)
    assert out[3, 1, 15] == 32767 and abs(int(out[0, 0, 15]) - (8192 + 9072)) <= 1
