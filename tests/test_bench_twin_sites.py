"""bench_twin_sites' what-if twins: --stiffness scales the moduli and nothing else, --set replaces a SimParams field,
and a field or value the simulator would not take is refused with its name before any drop is simulated."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_twin_sites  # noqa: E402
from impactsense.errors import ConfigError  # noqa: E402
from impactsense.sim import SimParams  # noqa: E402


def laminate():
    return SimParams(e_pa=57e9, e2_pa=16e9, g12_pa=11e9, nu=0.28, rho_kg_m3=1550.0, thickness_mm=2.5)


def test_set_parses_numbers_and_names():
    sets = bench_twin_sites.what_if(["support=elastic_rim", "rim_stiffness_n_m2=1e9", "element_mm=1.5"])
    assert sets == {"support": "elastic_rim", "rim_stiffness_n_m2": 1e9, "element_mm": 1.5}


def test_stiffness_scales_the_moduli_and_set_replaces_fields():
    base = laminate()
    p = bench_twin_sites.what_if_params(base, 1.4, {"support": "clamped", "element_mm": 1.15})
    assert p.e_pa == pytest.approx(1.4 * base.e_pa) and p.e2_pa == pytest.approx(1.4 * base.e2_pa)
    assert p.g12_pa == pytest.approx(1.4 * base.g12_pa)
    assert p.support == "clamped" and p.element_mm == 1.15
    assert p.nu == base.nu and p.rho_kg_m3 == base.rho_kg_m3 and p.damping_per_s == base.damping_per_s
    iso = bench_twin_sites.what_if_params(SimParams(e_pa=70e9), 0.5, {})
    assert iso.e_pa == pytest.approx(35e9) and iso.e2_pa is None and iso.g12_pa is None


def test_unknown_field_or_refused_value_is_an_error_naming_it():
    with pytest.raises(ConfigError, match="rim_stifness"):
        bench_twin_sites.what_if_params(laminate(), 1.0, {"rim_stifness": 1e9})
    with pytest.raises(ConfigError, match="support"):
        bench_twin_sites.what_if_params(laminate(), 1.0, {"support": "glued"})
    with pytest.raises(ConfigError, match="rim_stiffness_n_m2"):  # a rim's stiffness on a simply supported plate
        bench_twin_sites.what_if_params(laminate(), 1.0, {"rim_stiffness_n_m2": 1e9})
