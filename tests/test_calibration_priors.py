"""The calibration's plate grid spans the rig material's priors (issue 15), and a laminate's calibrated plate
modulus scales the table's laminate."""

from __future__ import annotations

import numpy as np
import pytest

from impactsense.calibration.priors import plate_grid_range
from impactsense.data import bundled_session_path, read_json, rig_from_dict
from impactsense.materials import equivalent_isotropic_ratio, material_for_rig
from impactsense.sim import SimParams, material


def _rig(text: str):
    return rig_from_dict({**read_json(bundled_session_path() / "rig.json"), "plate_material": text})


@pytest.mark.parametrize("text", ["aluminium 6061-T6", "steel", "PMMA", "float glass", "unobtainium"])
def test_isotropic_grid_is_the_material_prior(text):
    mat = material_for_rig(_rig(text))
    g = plate_grid_range(_rig(text))
    assert g["e_min_mpa"] <= mat.e_pa.lo / 1e6 and g["e_max_mpa"] >= mat.e_pa.hi / 1e6
    assert g["e_max_mpa"] - g["e_min_mpa"] <= (mat.e_pa.hi - mat.e_pa.lo) / 1e6 + 2
    assert g["nu_min"] == pytest.approx(mat.nu.lo) and g["nu_max"] == pytest.approx(mat.nu.hi)


def test_laminate_equivalent_modulus_round_trip():
    """The equivalent isotropic plate has the laminate's direction-averaged flexural slowness; a bare e_pa
    for a laminate rig scales every modulus by e_pa / (E1 r) and keeps the anisotropy and the fibre angle."""
    rig = _rig("CFRP laminate, fibres along y")
    mat = material_for_rig(rig)
    r = equivalent_isotropic_ratio(mat)
    assert 0.3 < r < 1.0                                   # softer than along the fibres, stiffer than across
    g = plate_grid_range(rig)
    assert g["e_min_mpa"] == pytest.approx(mat.e1_pa.lo * r / 1e6, abs=1)
    typ = mat.typical()
    e_eq = 0.8 * typ["e1_pa"] * r
    p = SimParams.from_rig(rig, e_pa=e_eq, nu=0.31)
    assert p.e_pa == pytest.approx(0.8 * typ["e1_pa"]) and p.e2_pa == pytest.approx(0.8 * typ["e2_pa"])
    assert p.g12_pa == pytest.approx(0.8 * typ["g12_pa"]) and p.nu == 0.31 and p.material_axes_deg == 90.0
    slowness = np.mean(material.directional_bending(p, np.arange(0.0, 180.0)) ** -0.25)
    iso = SimParams(e_pa=e_eq, nu=0.31, thickness_mm=p.thickness_mm)
    assert slowness == pytest.approx(material.bending_matrix(iso)[0, 0] ** -0.25, rel=2e-3)
    assert SimParams.from_rig(rig, e_pa=50e9, e2_pa=10e9, g12_pa=4e9).e_pa == 50e9   # a full laminate as given
