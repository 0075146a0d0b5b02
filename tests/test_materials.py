"""The materials table and the rig-driven inner region: rig.json words -> priors; defaults from the layout."""

import math

import pytest

from impactsense.data import bundled_session_path, load_rig, rig_from_dict
from impactsense.errors import DataError
from impactsense.materials import (UNKNOWN, flexural_group_velocity_mm_per_us, lookup, material_for_rig)
from impactsense.metrics import inner_mask, region_metrics


def rig_dict(**extra):
    raw = dict(load_rig(bundled_session_path()).raw)
    raw.update(extra)
    return raw


@pytest.mark.parametrize("text, name, kind", [
    ("PMMA", "PMMA", "isotropic"), ("cast acrylic sheet", "PMMA", "isotropic"),
    ("aluminium 6061-T6", "aluminium", "isotropic"), ("Aluminum 5083", "aluminium", "isotropic"),
    ("stainless steel 304", "steel", "isotropic"), ("float glass", "glass", "isotropic"),
    ("carbon-fibre laminate, fibres mostly along x (orthotropic)", "CFRP laminate", "orthotropic"),
    ("glass-fibre epoxy laminate", "GFRP laminate", "orthotropic"),
    # a keyword counts at the start of a word: "polycarbonate" holds "carbon", "carbon steel" is a steel
    ("polycarbonate sheet", "polycarbonate", "isotropic"), ("carbon steel S355", "steel", "isotropic"),
    ("Graphite/epoxy cross-ply", "CFRP laminate", "orthotropic"), ("fibreglass panel", "GFRP laminate", "orthotropic"),
])
def test_lookup_names_the_material_and_its_kind(text, name, kind):
    m = lookup(text)
    assert (m.name, m.kind, m.known) == (name, kind, True)
    for p in m.constants().values():
        assert p.lo <= p.value <= p.hi


def test_unknown_material_gets_wide_priors():
    m = lookup("unobtainium")
    assert m is UNKNOWN and not m.known
    assert m.e_pa.hi / m.e_pa.lo >= 100      # spans polymers to steel


def test_fibre_direction_from_words_and_from_material_axes():
    along_x = material_for_rig(rig_from_dict(rig_dict(plate_material="CFRP, fibres along x")))
    along_y = material_for_rig(rig_from_dict(rig_dict(plate_material="CFRP, fibres along y")))
    given = material_for_rig(rig_from_dict(rig_dict(plate_material="CFRP", material_axes={"fibre_angle_deg": 30})))
    assert (along_x.axis_deg, along_y.axis_deg, given.axis_deg) == (0.0, 90.0, 30.0)
    # flexural waves run fastest along the fibres: (D11 / D22)^(1/4) between the two axes
    v0 = flexural_group_velocity_mm_per_us(along_x, 2.5, 1550, 20e3, 0.0)
    v90 = flexural_group_velocity_mm_per_us(along_x, 2.5, 1550, 20e3, 90.0)
    assert v0 / v90 == pytest.approx(along_x.bending_stiffness_ratio() ** 0.25, rel=1e-9)
    with pytest.raises(DataError, match="material_axes"):
        material_for_rig(rig_from_dict(rig_dict(material_axes=[0])))


def test_isotropic_velocity_is_the_kirchhoff_value():
    m = lookup("aluminium")
    e, nu, h, rho, f = m.e_pa.value, m.nu.value, 3e-3, 2700.0, 50e3
    d = e * h ** 3 / (12 * (1 - nu ** 2))
    want = 2 * (d / (rho * h)) ** 0.25 * math.sqrt(2 * math.pi * f) * 1e-3
    assert flexural_group_velocity_mm_per_us(m, 3.0, rho, f) == pytest.approx(want, rel=1e-12)


def test_material_properties_pin_the_priors_and_bad_keys_name_the_field():
    m = material_for_rig(rig_from_dict(rig_dict(material_properties={"e_pa": 4.4e9})))
    assert m.e_pa.value == m.e_pa.lo == m.e_pa.hi == 4.4e9
    with pytest.raises(DataError, match=r"material_properties\.g12_pa"):
        material_for_rig(rig_from_dict(rig_dict(material_properties={"g12_pa": 1e9})))


def test_inner_region_default_is_the_sensors_box_inset_and_can_be_declared():
    rig = rig_from_dict(rig_dict())
    xs, ys = rig.sensor_x_mm, rig.sensor_y_mm
    assert rig.inner_region_mm == pytest.approx((xs.min() + 30, xs.max() - 30, ys.min() + 30, ys.max() - 30))
    declared = rig_from_dict(rig_dict(inner_region_mm=[50, 250, 40, 200]))
    assert declared.inner_region_mm == (50.0, 250.0, 40.0, 200.0)
    with pytest.raises(DataError, match="inner_region_mm"):
        rig_from_dict(rig_dict(inner_region_mm=[50, 40, 0, 10]))
    xy = [[60, 70], [55, 70], [100, 300]]
    assert inner_mask(xy, (60, 200, 60, 200)).tolist() == [True, False, False]
    m = region_metrics(xy, [[61, 70], [55, 72], [100, 300]], (60, 200, 60, 200))
    assert m["inner"]["n"] == 1 and m["all"]["n"] == 3
