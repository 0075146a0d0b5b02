"""Plate materials: what rig.json's `plate_material` says about the plate's elastic constants, as priors.

A rig declares its plate in words ("PMMA", "aluminium 6061-T6", "carbon-fibre laminate, fibres mostly along
x (orthotropic)"). `material_for_rig` turns that into a `Material`: isotropic (E, nu) or orthotropic (E1, E2,
G12, nu12 in the material axes, axis 1 along the fibres at `axis_deg` from the plate's x axis), each constant a
`Prior` (a typical value and the range a calibration may search). The density always comes from rig.json
(`density_kg_m3`); the table's density range only checks it. An unrecognised material gets wide priors.

Optional rig.json fields read here:
- `material_axes`: {"fibre_angle_deg": A} (or `material_axes_deg`: A), the angle of material axis 1 (the
  fibres) from the plate's x axis, counter-clockwise, in degrees. Absent: taken from the words ("fibres ...
  along x" -> 0, "along y" -> 90), else 0.
- `material_properties`: known constants that replace the table's typical values (and pin their range), in
  SI units: {"e_pa": ..., "nu": ...} or {"e1_pa", "e2_pa", "g12_pa", "nu12"}.

Tabled values are handbook figures (each entry's source in a comment beside it) for the dynamic
(ultrasonic-rate) moduli where they differ: PMMA ~5 GPa (its quasi-static 3 GPa rises with rate), aluminium
alloys 69-72 GPa, steels 190-210 GPa, soda-lime/borosilicate glass 62-74 GPa, titanium alloys 105-120 GPa,
brasses and bronzes 90-125 GPa, copper 110-130 GPa; unidirectional-leaning CFRP and GFRP laminates over the
range from cross-ply to mostly unidirectional lay-ups, woven ones (FR-4, G-10, twill or plain-weave carbon)
with warp and fill nearly alike; wood and plywood orthotropic along the (face) grain.
"""

from __future__ import annotations

import math
import re
from functools import lru_cache
from itertools import product
from dataclasses import dataclass, replace

import numpy as np

from .errors import DataError

ISOTROPIC = "isotropic"
ORTHOTROPIC = "orthotropic"


@dataclass(frozen=True)
class Prior:
    """A typical value and the closed range [lo, hi] a fit may search (SI units)."""

    value: float
    lo: float
    hi: float

    def __post_init__(self):
        if not (self.lo <= self.value <= self.hi):
            raise ValueError(f"prior value {self.value} outside [{self.lo}, {self.hi}]")

    def pinned(self, value: float) -> "Prior":
        return Prior(float(value), float(value), float(value))

    def to_dict(self) -> dict:
        return {"value": self.value, "lo": self.lo, "hi": self.hi}


@dataclass(frozen=True)
class Material:
    """A plate material's priors. Isotropic: e_pa, nu. Orthotropic: e1_pa, e2_pa, g12_pa, nu12 (axis 1 at
    axis_deg from the plate's x axis)."""

    name: str
    kind: str
    density_kg_m3: Prior
    e_pa: Prior | None = None
    nu: Prior | None = None
    e1_pa: Prior | None = None
    e2_pa: Prior | None = None
    g12_pa: Prior | None = None
    nu12: Prior | None = None
    axis_deg: float = 0.0
    known: bool = True            # False: not in the table, wide priors
    notes: str = ""

    @property
    def orthotropic(self) -> bool:
        return self.kind == ORTHOTROPIC

    def constants(self) -> dict[str, Prior]:
        names = ("e1_pa", "e2_pa", "g12_pa", "nu12") if self.orthotropic else ("e_pa", "nu")
        return {n: getattr(self, n) for n in names}

    def typical(self) -> dict[str, float]:
        return {n: p.value for n, p in self.constants().items()}

    def bending_stiffness_ratio(self) -> float:
        """D_11 / D_22 of the typical values (1 for isotropic): how much faster flexural waves run along the
        fibres, (D11/D22)^(1/4) in phase velocity."""
        if not self.orthotropic:
            return 1.0
        return self.e1_pa.value / self.e2_pa.value

    def to_dict(self) -> dict:
        out = {"name": self.name, "kind": self.kind, "known": self.known, "axis_deg": self.axis_deg,
               "density_kg_m3": self.density_kg_m3.to_dict()}
        out.update({n: p.to_dict() for n, p in self.constants().items()})
        if self.notes:
            out["notes"] = self.notes
        return out


def _p(value, lo, hi) -> Prior:
    return Prior(float(value), float(lo), float(hi))


GPA = 1e9

# Words that say a laminate's fibres run both ways in-plane (a woven fabric: warp and fill alike, axis 1 = warp).
WEAVE = ("woven", "weave", "plain-weave", "twill", "satin", "fabric", "cloth")
GLASS_FIBRE = ("gfrp", "glass", "e-glass", "s-glass", "fibreglass", "fiberglass")
CARBON_FIBRE = ("cfrp", "carbon", "graphite")

# (keywords matched at the start of a word of the lower-cased plate_material, so "polycarbonate" is not "carbon";
# a keyword that is a tuple of words needs all of them (each at a word start, in any order); the first entry that
# matches wins: steels first ("carbon steel" is a steel), the woven laminates before the unidirectional-leaning
# ones, alumina before aluminium). Values: typical figure, then the range a fit may search.
TABLE: list[tuple[tuple, Material]] = [
    # ASM Handbook vol. 1 / AK Steel 304 & 316 data: 193 GPa, nu 0.29, 8000 kg/m3 (ferritic 430: 200 GPa, 7750)
    (("stainless", "inox", "18/8"), Material(
        "stainless steel", ISOTROPIC, _p(7950, 7700, 8100),
        e_pa=_p(193 * GPA, 185 * GPA, 205 * GPA), nu=_p(0.29, 0.26, 0.31))),
    (("steel",), Material(
        "steel", ISOTROPIC, _p(7850, 7700, 8050),
        e_pa=_p(200 * GPA, 185 * GPA, 215 * GPA), nu=_p(0.29, 0.26, 0.32))),
    # ASTM A48 grey iron classes 20-60: 66-157 GPa; ductile (ASTM A536) 165-170 GPa; 6900-7400 kg/m3
    (("cast iron", "grey iron", "gray iron", "ductile iron", "nodular iron", "iron"), Material(
        "cast iron", ISOTROPIC, _p(7150, 6900, 7400),
        e_pa=_p(120 * GPA, 65 * GPA, 175 * GPA), nu=_p(0.26, 0.20, 0.31))),
    # FR-4 / G-10 / woven E-glass-epoxy: IPC-4101 laminate data sheets (e.g. Isola 370HR: 24 / 21 GPa warp / fill,
    # Poisson 0.13-0.18), MIL-HDBK-17-2F woven E-glass/epoxy G12 4-6 GPa, 1800-1950 kg/m3: quasi-isotropic in-plane
    (("fr4", "fr-4", "fr 4", "g10", "g-10", "g11", "g-11", "epoxy glass cloth")
     + tuple(product(WEAVE, GLASS_FIBRE)), Material(
        "woven GFRP (FR-4 / G-10)", ORTHOTROPIC, _p(1850, 1700, 2000),
        e1_pa=_p(24 * GPA, 17 * GPA, 30 * GPA), e2_pa=_p(21 * GPA, 15 * GPA, 28 * GPA),
        g12_pa=_p(4.5 * GPA, 3 * GPA, 7 * GPA), nu12=_p(0.13, 0.08, 0.20),
        notes="woven: warp (axis 1) and fill nearly alike")),
    # woven carbon/epoxy (T300 3K plain weave / twill, Vf ~0.55): MIL-HDBK-17-2F, Hexcel fabric prepreg data:
    # E1 ~ E2 55-70 GPa, G12 4-5 GPa, nu12 0.04-0.08, 1500-1600 kg/m3
    (tuple(product(WEAVE, CARBON_FIBRE)), Material(
        "woven CFRP", ORTHOTROPIC, _p(1550, 1400, 1650),
        e1_pa=_p(62 * GPA, 40 * GPA, 80 * GPA), e2_pa=_p(58 * GPA, 38 * GPA, 78 * GPA),
        g12_pa=_p(4.5 * GPA, 3 * GPA, 9 * GPA), nu12=_p(0.06, 0.02, 0.15),
        notes="woven: warp (axis 1) and fill nearly alike")),
    (CARBON_FIBRE, Material(
        "CFRP laminate", ORTHOTROPIC, _p(1550, 1400, 1700),
        e1_pa=_p(70 * GPA, 30 * GPA, 150 * GPA), e2_pa=_p(20 * GPA, 6 * GPA, 70 * GPA),
        g12_pa=_p(5 * GPA, 2.5 * GPA, 20 * GPA), nu12=_p(0.30, 0.05, 0.45))),
    (("gfrp", "glass-fibre", "glass fibre", "glass-fiber", "glass fiber", "fibreglass", "fiberglass", "e-glass",
      "s-glass", "glass/epoxy", "glass-epoxy", "glass epoxy"), Material(
        "GFRP laminate", ORTHOTROPIC, _p(1900, 1700, 2100),
        e1_pa=_p(30 * GPA, 15 * GPA, 50 * GPA), e2_pa=_p(12 * GPA, 6 * GPA, 30 * GPA),
        g12_pa=_p(4 * GPA, 2 * GPA, 8 * GPA), nu12=_p(0.25, 0.10, 0.40))),
    (("pmma", "acrylic", "plexiglas", "perspex"), Material(
        "PMMA", ISOTROPIC, _p(1180, 1150, 1200),
        e_pa=_p(5.0 * GPA, 2.5 * GPA, 7.0 * GPA), nu=_p(0.35, 0.30, 0.40))),
    (("polycarbonate", "lexan", "makrolon"), Material(
        "polycarbonate", ISOTROPIC, _p(1200, 1180, 1220),
        e_pa=_p(2.35 * GPA, 2.0 * GPA, 2.7 * GPA), nu=_p(0.37, 0.34, 0.40))),
    # CP titanium grade 1-4: 103-105 GPa, 4510 kg/m3; Ti-6Al-4V: 114 GPa, 4430 kg/m3 (ASM Handbook vol. 2)
    (("titan", "ti-6al", "ti6al"), Material(
        "titanium", ISOTROPIC, _p(4500, 4400, 4650),
        e_pa=_p(112 * GPA, 100 * GPA, 120 * GPA), nu=_p(0.33, 0.30, 0.36))),
    (("brass", "cuzn", "bronze"), Material(
        "brass / bronze", ISOTROPIC, _p(8500, 7500, 8900),
        e_pa=_p(105 * GPA, 90 * GPA, 125 * GPA), nu=_p(0.34, 0.31, 0.37))),
    (("copper",), Material(
        "copper", ISOTROPIC, _p(8930, 8850, 8960),
        e_pa=_p(120 * GPA, 110 * GPA, 135 * GPA), nu=_p(0.34, 0.32, 0.36))),
    # alumina ceramic (Al2O3 92-99.5 %): 300-390 GPa, nu 0.21-0.23, 3600-3950 kg/m3 (CoorsTek data): not aluminium
    (("alumina", "al2o3", "aluminium oxide", "aluminum oxide"), Material(
        "alumina ceramic", ISOTROPIC, _p(3850, 3550, 3990),
        e_pa=_p(360 * GPA, 290 * GPA, 400 * GPA), nu=_p(0.22, 0.20, 0.25))),
    (("alumin",), Material(
        "aluminium", ISOTROPIC, _p(2700, 2600, 2850),
        e_pa=_p(70 * GPA, 65 * GPA, 75 * GPA), nu=_p(0.33, 0.30, 0.36))),
    # AZ31B / AZ91 / ZE41: 44-45 GPa, nu 0.35, 1770-1840 kg/m3 (ASM Handbook vol. 2)
    (("magnes", "az31", "az61", "az91", "ze41", "we43"), Material(
        "magnesium", ISOTROPIC, _p(1780, 1730, 1850),
        e_pa=_p(45 * GPA, 40 * GPA, 47 * GPA), nu=_p(0.35, 0.33, 0.37))),
    (("glass",), Material(
        "glass", ISOTROPIC, _p(2500, 2200, 2700),
        e_pa=_p(70 * GPA, 60 * GPA, 90 * GPA), nu=_p(0.22, 0.18, 0.26))),
    # HDPE 0.8-1.2 GPa quasi-static, higher at acoustic rates; LDPE 0.2-0.3 GPa; nu 0.42-0.46; 920-970 kg/m3
    (("hdpe", "pe-hd", "uhmw", "ldpe", "polyethylene", "polythene"), Material(
        "polyethylene", ISOTROPIC, _p(950, 910, 975),
        e_pa=_p(1.2 * GPA, 0.2 * GPA, 2.5 * GPA), nu=_p(0.43, 0.38, 0.47))),
    # polypropylene homopolymer 1.3-1.8 GPa, nu 0.42, 900-910 kg/m3
    (("polypropylen",), Material(
        "polypropylene", ISOTROPIC, _p(905, 890, 920),
        e_pa=_p(1.6 * GPA, 1.0 * GPA, 2.4 * GPA), nu=_p(0.42, 0.38, 0.45))),
    # rigid (unplasticised) PVC: 2.9-3.4 GPa, nu 0.38-0.40, 1380-1450 kg/m3
    (("pvc", "upvc", "polyvinyl chloride"), Material(
        "rigid PVC", ISOTROPIC, _p(1400, 1350, 1460),
        e_pa=_p(3.2 * GPA, 2.4 * GPA, 4.2 * GPA), nu=_p(0.39, 0.35, 0.42))),
    # PA6 / PA66 (dry to conditioned) 1.5-3.3 GPa, nu 0.39, 1130-1150 kg/m3
    (("nylon", "polyamide", "pa6", "pa66", "pa 6"), Material(
        "nylon (polyamide)", ISOTROPIC, _p(1140, 1120, 1160),
        e_pa=_p(2.8 * GPA, 1.5 * GPA, 3.8 * GPA), nu=_p(0.39, 0.35, 0.42))),
    # POM (acetal, Delrin): 2.8-3.3 GPa, nu 0.35-0.38, 1410 kg/m3
    (("pom", "acetal", "delrin", "polyoxymethylene"), Material(
        "POM (acetal)", ISOTROPIC, _p(1410, 1390, 1430),
        e_pa=_p(3.1 * GPA, 2.5 * GPA, 3.8 * GPA), nu=_p(0.36, 0.33, 0.40))),
    # plywood: USDA Wood Handbook (FPL-GTR-190) ch. 11-12 and birch plywood (EN 636) data: bending along the face
    # grain (axis 1) 6-13 GPa, across 2-8 GPa (more plies: more alike), panel shear 0.4-1.0 GPa, 400-750 kg/m3
    (("plywood", "ply wood", "multiplex"), Material(
        "plywood", ORTHOTROPIC, _p(600, 400, 750),
        e1_pa=_p(9 * GPA, 5 * GPA, 14 * GPA), e2_pa=_p(5 * GPA, 2 * GPA, 9 * GPA),
        g12_pa=_p(0.6 * GPA, 0.3 * GPA, 1.2 * GPA), nu12=_p(0.07, 0.02, 0.20),
        notes="face grain along axis 1")),
    # MDF / HDF / hardboard (EN 622-5): 2.5-4.5 GPa in-plane alike, nu ~0.25, 600-1050 kg/m3
    (("mdf", "hdf", "hardboard", "fibreboard", "fiberboard", "medium-density", "medium density"), Material(
        "fibreboard (MDF)", ISOTROPIC, _p(750, 550, 1050),
        e_pa=_p(3.5 * GPA, 2.0 * GPA, 5.5 * GPA), nu=_p(0.25, 0.15, 0.35))),
    # solid wood: Wood Handbook table 5-1/5-2 (E_L 8-16 GPa, E_T / E_L ~0.05, G_LT / E_L ~0.06, nu_LT ~0.4),
    # 350-900 kg/m3; grain along axis 1
    (("wood", "timber", "oak", "pine", "spruce", "beech", "birch", "maple", "hardwood", "softwood"), Material(
        "solid wood", ORTHOTROPIC, _p(550, 350, 900),
        e1_pa=_p(11 * GPA, 6 * GPA, 17 * GPA), e2_pa=_p(0.7 * GPA, 0.3 * GPA, 1.5 * GPA),
        g12_pa=_p(0.7 * GPA, 0.3 * GPA, 1.3 * GPA), nu12=_p(0.40, 0.25, 0.50),
        notes="grain along axis 1")),
    # granite, marble, slate: 30-70 GPa (granite ~50-60), nu 0.2-0.3, 2600-2850 kg/m3 (Goodman, Introduction to
    # Rock Mechanics, table A1.2; wide: stone varies by quarry)
    (("granite", "marble", "slate", "stone", "quartzite", "limestone"), Material(
        "natural stone", ISOTROPIC, _p(2680, 2300, 2900),
        e_pa=_p(55 * GPA, 20 * GPA, 90 * GPA), nu=_p(0.25, 0.12, 0.33))),
    # normal-weight concrete: 25-40 GPa (EN 1992-1-1 E_cm), nu 0.2, 2300-2450 kg/m3
    (("concrete",), Material(
        "concrete", ISOTROPIC, _p(2400, 2200, 2500),
        e_pa=_p(33 * GPA, 20 * GPA, 45 * GPA), nu=_p(0.20, 0.15, 0.25))),
]

UNKNOWN = Material("unknown", ISOTROPIC, _p(2000, 500, 20000), e_pa=_p(20 * GPA, 1 * GPA, 250 * GPA),
                   nu=_p(0.30, 0.15, 0.45), known=False,
                   notes="not in the materials table: wide priors; declare `material_properties` to narrow them")


def first_keyword_entry(text: str, table):
    """The first row (keywords, *rest) of `table` with a keyword at the start of a word of `text`
    (case-insensitive; a keyword given as a tuple of words needs each of them), as `rest`; None when no row
    matches. The materials and the balls tables' one rule."""
    low = str(text).lower()

    def at_word_start(k: str) -> bool:
        return re.search(r"(?<![a-z0-9])" + re.escape(k), low) is not None

    for keys, *rest in table:
        if any(at_word_start(k) if isinstance(k, str) else all(map(at_word_start, k)) for k in keys):
            return rest
    return None


def lookup(text: str) -> Material:
    """The table's entry with a keyword at the start of a word of `text` (case-insensitive), else UNKNOWN."""
    row = first_keyword_entry(text, TABLE)
    return UNKNOWN if row is None else row[0]


def _fibre_angle_from_words(text: str) -> float:
    low = text.lower()
    if re.search(r"along\s+(the\s+)?y\b", low):
        return 90.0
    return 0.0


def _number(raw: dict, where: str, key: str, path) -> float:
    v = raw.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise DataError(path, f"{where}.{key}", f"must be a finite number, got {v!r}")
    return float(v)


def material_for_rig(rig, path="rig.json") -> Material:
    """The rig's plate material with its priors (optional `material_axes`, `material_properties`)."""
    raw = getattr(rig, "raw", None) or {}
    text = str(raw.get("plate_material", getattr(rig, "plate_material", "")))
    mat = lookup(text)
    axes = raw.get("material_axes")
    if axes is None and "material_axes_deg" in raw:     # the simulator's name for the same angle
        axes = {"fibre_angle_deg": raw["material_axes_deg"]}
    if axes is not None:
        if not isinstance(axes, dict) or "fibre_angle_deg" not in axes:
            raise DataError(path, "material_axes", 'must be an object {"fibre_angle_deg": degrees}')
        angle = _number(axes, "material_axes", "fibre_angle_deg", path)
    else:
        angle = _fibre_angle_from_words(text) if mat.orthotropic else 0.0
    mat = replace(mat, axis_deg=angle)
    props = raw.get("material_properties")
    if props is not None:
        if not isinstance(props, dict):
            raise DataError(path, "material_properties", "must be an object of constants (SI units)")
        if {"e1_pa", "e2_pa"} & set(props) and not mat.orthotropic:
            iso_nu = mat.nu if mat.nu is not None else UNKNOWN.nu
            mat = replace(mat, kind=ORTHOTROPIC, e_pa=None, nu=None, e1_pa=mat.e_pa or UNKNOWN.e_pa,
                          e2_pa=mat.e_pa or UNKNOWN.e_pa, g12_pa=_p(5 * GPA, 0.5 * GPA, 100 * GPA), nu12=iso_nu)
        allowed = set(mat.constants())
        for key in props:
            if key not in allowed:
                raise DataError(path, f"material_properties.{key}",
                                f"not a constant of a {mat.kind} plate ({', '.join(sorted(allowed))})")
            value = _number(props, "material_properties", key, path)
            if value <= 0:
                raise DataError(path, f"material_properties.{key}", "must be positive")
            mat = replace(mat, **{key: getattr(mat, key).pinned(value)})
    return mat


def equivalent_isotropic_ratio(mat) -> float:
    """E_eq / E1 of a `materials.Material`'s typical values: the isotropic plate (Poisson nu12) whose
    Kirchhoff flexural slowness equals the laminate's averaged over directions, D_eq^(-1/4) = mean_phi
    D(phi)^(-1/4); 1 for an isotropic material."""
    if not mat.orthotropic:
        return 1.0
    e1, e2, g12, nu12 = (mat.e1_pa.value, mat.e2_pa.value, mat.g12_pa.value, mat.nu12.value)
    q = 1.0 - nu12 * nu12 * e2 / e1
    d11, d22, d12, d66 = e1 / q, e2 / q, nu12 * e2 / q, g12
    phi = np.radians(np.arange(0.0, 180.0, 1.0))
    c, s = np.cos(phi), np.sin(phi)
    d_phi = d11 * c ** 4 + 2 * (d12 + 2 * d66) * c ** 2 * s ** 2 + d22 * s ** 4
    d_eq = float(np.mean(d_phi ** -0.25)) ** -4.0
    return d_eq * (1.0 - nu12 ** 2) / e1


def _ray_metrics(e1, e2, g12, nu12, axis_deg: float = 0.0) -> np.ndarray:
    """kirchhoff_ray_metric of arrays of constants: [N, 3]."""
    e1, e2, g12 = (np.atleast_1d(np.asarray(v, float))[:, None] for v in (e1, e2, g12))
    q = 1.0 - nu12 * nu12 * e2 / e1
    d11, d22, d12, d66 = e1 / q, e2 / q, nu12 * e2 / q, g12
    phi = np.radians(np.arange(0.0, 360.0, 1.0))
    c, s = np.cos(phi), np.sin(phi)
    k = (d11 * c ** 4 + 2 * (d12 + 2 * d66) * c * c * s * s + d22 * s ** 4) ** -0.25          # [N, P], material axes
    theta = np.radians(np.arange(0.0, 180.0, 2.0))
    k_ray = np.max(k[:, None, :] * np.cos(phi[None, None, :] - theta[None, :, None]), axis=2)   # [N, T]
    t = theta + math.radians(axis_deg)                                                      # the plate's axes
    ct, st = np.cos(t), np.sin(t)
    coef = np.linalg.lstsq(np.c_[ct * ct, 2 * ct * st, st * st], (k_ray ** 2).T, rcond=None)[0].T   # [N, 3]
    return coef * (2.0 / (coef[:, 0] + coef[:, 2]))[:, None]


def kirchhoff_ray_metric(e1_pa: float, e2_pa: float, g12_pa: float, nu12: float, axis_deg: float = 0.0,
                         ) -> tuple[float, float, float]:
    """The elliptical travel metric (Q_xx, Q_xy, Q_yy; trace 2, travel.py) closest to a Kirchhoff orthotropic
    plate's flexural ray slowness: along a ray at theta the far field travels with the stationary phase of the
    plane waves, k_ray(theta) = max_phi k(phi) cos(phi - theta), k(phi) ~ D(phi)^(-1/4) (calibration.laminate);
    the ray's slowness squared, ~k_ray^2, is fitted by Q_xx c^2 + 2 Q_xy c s + Q_yy s^2 over the directions
    (least squares, then scaled to trace 2). The same at every frequency (Kirchhoff's k ~ sqrt(omega) factors
    out). An ellipse is what the localiser models; a laminate whose D66 is large departs from it (a cos 4 theta
    part the fit leaves)."""
    return tuple(float(v) for v in _ray_metrics(e1_pa, e2_pa, g12_pa, nu12, axis_deg)[0])


@lru_cache(maxsize=32)
def travel_metric_sd(mat: Material, draws: int = 400, seed: int = 0) -> float:
    """How far a plate's elliptical travel metric may lie from what one expects of its material (1 sd of the
    metric's a = (Q_xx - Q_yy) / 2, kirchhoff_ray_metric): an orthotropic material's E1, E2 and G12 drawn
    log-uniformly over their prior ranges (E2 <= E1: axis 1 is the stiff one), nu12 at its value; 0 for a
    known isotropic material (its wavefronts are circles); an unknown material gets the widest of the table's
    orthotropic materials (it might be any of them)."""
    if not mat.orthotropic:
        return 0.0 if mat.known else max(travel_metric_sd(m, draws, seed) for _, m in TABLE if m.orthotropic)
    rng = np.random.default_rng(seed)
    e1, e2, g12 = (np.exp(rng.uniform(math.log(p.lo), math.log(p.hi), 4 * draws))
                   for p in (mat.e1_pa, mat.e2_pa, mat.g12_pa))
    keep = np.flatnonzero((e2 <= e1) & (mat.nu12.value ** 2 * e2 < e1))[:draws]
    q = _ray_metrics(e1[keep], e2[keep], g12[keep], mat.nu12.value)
    return float(np.std((q[:, 0] - q[:, 2]) / 2))

def density_warning(rig, mat: Material) -> str | None:
    """A line when rig.json's density lies outside the material's range (a typo or another material)."""
    rho = float(getattr(rig, "density_kg_m3", float("nan")))
    p = mat.density_kg_m3
    if mat.known and not (p.lo <= rho <= p.hi):
        return (f"rig.json density_kg_m3 {rho:g} lies outside {p.lo:g}..{p.hi:g} for {mat.name}; "
                "the declared density is used")
    return None


def flexural_group_velocity_mm_per_us(mat: Material, thickness_mm: float, density_kg_m3: float,
                                      freq_hz: float, angle_deg: float = 0.0) -> float:
    """Mindlin flexural (A0) group velocity of the typical values in the direction angle_deg from the plate's x
    axis (sim.dispersion, the simulator's relation): bending stiffness D(theta) = (D11 cos^4 + (2 D12 + 4 D66)
    cos^2 sin^2 + D22 sin^4) h^3 / 12 in the material axes, transverse shear kappa G h (G = E / 2(1 + nu); a
    laminate's G13 = G23 taken as G12, as the simulator's default). On a thin plate (h well under the
    wavelength) it is the Kirchhoff value 2 (D / rho h)^(1/4) sqrt(omega); on a thick or soft one it levels off
    at the shear wave speed, where Kirchhoff's grows as sqrt(omega) (12 mm HDPE at 10 kHz: 0.70 against
    1.11 mm/us). A starting value for fits, not a measurement."""
    from .sim.dispersion import KAPPA_MINDLIN, a0_wavenumber_ds

    h = thickness_mm * 1e-3
    if mat.orthotropic:
        e1, e2, g12, nu12 = (mat.e1_pa.value, mat.e2_pa.value, mat.g12_pa.value, mat.nu12.value)
        nu21 = nu12 * e2 / e1
        q = 1.0 - nu12 * nu21
        d11, d22, d12, d66 = e1 / q, e2 / q, nu12 * e2 / q, g12
        t = math.radians(angle_deg - mat.axis_deg)
        c, s = math.cos(t), math.sin(t)
        modulus = d11 * c ** 4 + (2 * d12 + 4 * d66) * c * c * s * s + d22 * s ** 4
        shear = g12
    else:
        modulus = mat.e_pa.value / (1.0 - mat.nu.value ** 2)
        shear = mat.e_pa.value / (2.0 * (1.0 + mat.nu.value))
    consts = (modulus * h ** 3 / 12.0, KAPPA_MINDLIN * shear * h, density_kg_m3 * h ** 3 / 12.0, density_kg_m3 * h)
    step = 1e-5 * freq_hz
    dk = float(a0_wavenumber_ds(freq_hz + step, *consts) - a0_wavenumber_ds(freq_hz - step, *consts))
    return 2.0 * math.pi * 2.0 * step / dk * 1e-3


__all__ = ["Prior", "Material", "TABLE", "UNKNOWN", "lookup", "material_for_rig", "density_warning",
           "equivalent_isotropic_ratio", "kirchhoff_ray_metric", "travel_metric_sd",
           "flexural_group_velocity_mm_per_us", "ISOTROPIC", "ORTHOTROPIC"]
