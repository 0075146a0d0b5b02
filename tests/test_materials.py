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
    ("stainless steel 304", "stainless steel", "isotropic"), ("float glass", "glass", "isotropic"),
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


# A new user's words for the plate, and the handbook figures its priors must hold (E or E1 / E2 in GPa, nu or
# nu12, density kg/m3; sources beside the table's entries): the typical value need not be the figure, the range must.
GPA = 1e9
HANDBOOK = [
    ("FR4 board", "woven GFRP (FR-4 / G-10)", dict(e1_pa=24, e2_pa=21, nu12=0.13, rho=1850)),
    ("G-10", "woven GFRP (FR-4 / G-10)", dict(e1_pa=24, e2_pa=21, rho=1800)),
    ("FR-4 glass-epoxy laminate", "woven GFRP (FR-4 / G-10)", dict(e1_pa=24, e2_pa=21, rho=1850)),
    ("woven glass fabric / epoxy", "woven GFRP (FR-4 / G-10)", dict(e1_pa=22, e2_pa=20)),
    ("woven carbon fibre", "woven CFRP", dict(e1_pa=62, e2_pa=60, g12_pa=4.5, rho=1550)),
    ("twill CFRP", "woven CFRP", dict(e1_pa=62, e2_pa=60, nu12=0.05)),
    ("stainless steel 304", "stainless steel", dict(e_pa=193, nu=0.29, rho=8000)),
    ("mild steel", "steel", dict(e_pa=205, nu=0.29, rho=7850)),
    ("brass", "brass / bronze", dict(e_pa=100, nu=0.34, rho=8500)),
    ("copper", "copper", dict(e_pa=117, nu=0.34, rho=8940)),
    ("titanium grade 2", "titanium", dict(e_pa=105, nu=0.34, rho=4510)),
    ("magnesium AZ31", "magnesium", dict(e_pa=45, nu=0.35, rho=1770)),
    ("polycarbonate", "polycarbonate", dict(e_pa=2.4, nu=0.37, rho=1200)),
    ("HDPE", "polyethylene", dict(e_pa=1.0, nu=0.44, rho=955)),
    ("float glass", "glass", dict(e_pa=72, nu=0.22, rho=2500)),
    ("granite", "natural stone", dict(e_pa=55, nu=0.25, rho=2650)),
    ("plywood", "plywood", dict(e1_pa=9, e2_pa=5, rho=600)),
    ("MDF", "fibreboard (MDF)", dict(e_pa=3.5, rho=750)),
    ("acrylic", "PMMA", dict(e_pa=5.0, nu=0.35, rho=1180)),
    ("perspex", "PMMA", dict(e_pa=5.0, rho=1190)),
    ("aluminium 5083", "aluminium", dict(e_pa=71, nu=0.33, rho=2660)),
    ("alumina 99.5 %", "alumina ceramic", dict(e_pa=370, nu=0.22, rho=3890)),
    ("grey cast iron", "cast iron", dict(e_pa=110, nu=0.26, rho=7150)),
    ("rigid PVC sheet", "rigid PVC", dict(e_pa=3.0, nu=0.39, rho=1400)),
]


@pytest.mark.parametrize("text, name, figures", HANDBOOK)
def test_a_new_users_words_get_priors_holding_the_handbook_values(text, name, figures):
    m = lookup(text)
    assert m.known and m.name == name
    for key, want in figures.items():
        p = m.density_kg_m3 if key == "rho" else getattr(m, key)
        want = want * GPA if key.endswith("_pa") else want
        assert p is not None and p.lo <= want <= p.hi, (key, want, p)


def test_woven_laminates_are_nearly_alike_both_ways_and_unidirectional_ones_are_not():
    # a woven fabric's warp and fill: flexural speeds within a few percent; the unidirectional-leaning entries keep
    # their stiff axis; the ellipse a woven plate may take is narrower than a unidirectional one's
    from impactsense.materials import travel_metric_sd
    for text in ("FR4 board", "twill CFRP"):
        woven = lookup(text)
        assert woven.orthotropic and woven.bending_stiffness_ratio() ** 0.25 < 1.05
        assert travel_metric_sd(woven) < 0.5 * travel_metric_sd(lookup("glass-fibre epoxy laminate"))
    assert lookup("unidirectional carbon/epoxy prepreg").bending_stiffness_ratio() ** 0.25 > 1.3
    assert lookup("GFRP laminate (E-glass/epoxy), fibres at 35 deg").name == "GFRP laminate"
    # a keyword of two words needs both: "woven" alone names no fibre, "glass" alone is a glass plate
    assert not lookup("woven mat").known and lookup("glass").name == "glass"


@pytest.mark.parametrize("text", ["Hardox 450 wear plate", "unobtainium", "basalt-fibre panel"])
def test_words_the_table_does_not_know_get_the_wide_prior_and_info_says_so(text):
    from impactsense.commands.info import plate_summary, priors_text
    m = material_for_rig(rig_from_dict(rig_dict(plate_material=text)))
    assert m is not None and not m.known and m.e_pa == UNKNOWN.e_pa
    pl = plate_summary(rig_from_dict(rig_dict(plate_material=text)))
    assert text in pl["material"] and "unknown to the materials table" in pl["material"]
    assert "material_properties" in pl["material"]
    assert priors_text(pl["priors"]).startswith("e GPa 20 (1..250)")


def test_unknown_material_gets_wide_priors():
    m = lookup("unobtainium")
    assert m is UNKNOWN and not m.known
    assert m.e_pa.hi / m.e_pa.lo >= 100      # spans polymers to steel


def test_fibre_direction_from_words_and_from_material_axes():
    along_x = material_for_rig(rig_from_dict(rig_dict(plate_material="CFRP, fibres along x")))
    along_y = material_for_rig(rig_from_dict(rig_dict(plate_material="CFRP, fibres along y")))
    given = material_for_rig(rig_from_dict(rig_dict(plate_material="CFRP", material_axes={"fibre_angle_deg": 30})))
    assert (along_x.axis_deg, along_y.axis_deg, given.axis_deg) == (0.0, 90.0, 30.0)
    # flexural waves run fastest along the fibres: (D11 / D22)^(1/4) between the two axes on a thin plate (Kirchhoff)
    v0 = flexural_group_velocity_mm_per_us(along_x, 2.5, 1550, 200.0, 0.0)
    v90 = flexural_group_velocity_mm_per_us(along_x, 2.5, 1550, 200.0, 90.0)
    assert v0 / v90 == pytest.approx(along_x.bending_stiffness_ratio() ** 0.25, rel=2e-3)
    with pytest.raises(DataError, match="material_axes"):
        material_for_rig(rig_from_dict(rig_dict(material_axes=[0])))


def test_isotropic_velocity_is_kirchhoff_on_a_thin_plate():
    """h / wavelength ~0.006 (3 mm aluminium at 1 kHz): Mindlin's shear and rotary inertia change the group
    velocity by well under 1 %."""
    m = lookup("aluminium")
    e, nu, h, rho, f = m.e_pa.value, m.nu.value, 3e-3, 2700.0, 1e3
    d = e * h ** 3 / (12 * (1 - nu ** 2))
    want = 2 * (d / (rho * h)) ** 0.25 * math.sqrt(2 * math.pi * f) * 1e-3
    assert flexural_group_velocity_mm_per_us(m, 3.0, rho, f) == pytest.approx(want, rel=5e-3)


def test_thick_soft_plate_velocity_levels_off_at_the_shear_wave_speed():
    """A 12 mm HDPE sheet at 10 kHz (h / wavelength ~0.2): the A0 group velocity is the simulator's Mindlin
    relation's (sim.dispersion), near the shear wave speed sqrt(kappa G / rho), where Kirchhoff's sqrt(omega)
    law reads it ~1.7 x too fast; it grows with frequency and stays under ~1.1 x the shear speed."""
    from impactsense.sim.dispersion import KAPPA_MINDLIN, a0_group_velocity

    m = lookup("HDPE sheet")
    e, nu, rho, h = m.e_pa.value, m.nu.value, 950.0, 12e-3
    v = flexural_group_velocity_mm_per_us(m, 12.0, rho, 10e3)
    assert v == pytest.approx(float(a0_group_velocity(10e3, e, nu, rho, h)) * 1e-3, rel=1e-4)
    shear = math.sqrt(KAPPA_MINDLIN * e / (2 * (1 + nu)) / rho) * 1e-3
    kirchhoff = 2 * (e * h ** 3 / (12 * (1 - nu ** 2)) / (rho * h)) ** 0.25 * math.sqrt(2 * math.pi * 10e3) * 1e-3
    assert 0.8 * shear < v < 1.1 * shear and kirchhoff > 1.5 * v
    assert flexural_group_velocity_mm_per_us(m, 12.0, rho, 3e3) < v < flexural_group_velocity_mm_per_us(m, 12.0, rho, 40e3) < 1.1 * shear


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
