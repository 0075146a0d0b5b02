"""The impactor: what rig.json's `ball_material` says about the ball's elastic constants (the Hertz contact).

The contact's stiffness, and so its duration and the band it excites, follows the reduced modulus
E* = 1 / ((1 - nu_plate^2) / E_plate + (1 - nu_ball^2) / E_ball) (`sim.model.hertz_k`,
`calibration.arrival.hertz_duration_s`). A steel ball on glass and a nylon ball of the same size differ ~20x
in E*: ~3x in contact time. `ball_for_rig` reads `ball_material` in words (a keyword at the start of a word,
as `materials.lookup`); optional rig.json `ball_properties` {"e_pa": ..., "nu": ...} (SI) gives the constants
and wins over the words. A ball the table does not know is taken as steel (the twin as built so far) with
`known` False, and `impactsense info` says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .errors import DataError
from .materials import first_keyword_entry

GPA = 1e9


@dataclass(frozen=True)
class Ball:
    name: str
    e_pa: float
    nu: float
    known: bool = True
    source: str = "table"          # "table", "rig.json ball_properties", "default (steel)"


# (keywords at the start of a word of the lower-cased ball_material; the first entry that matches wins:
# handbook figures at impact rates, polymers' dynamic moduli)
TABLE: list[tuple[tuple[str, ...], str, float, float]] = [
    (("tungsten carbide", "carbide"), "tungsten carbide", 600 * GPA, 0.24),
    (("silicon nitride", "si3n4"), "silicon nitride", 310 * GPA, 0.27),
    (("alumina", "al2o3", "ceramic"), "alumina", 370 * GPA, 0.22),
    (("steel", "chrome", "100cr6", "52100", "bearing"), "steel", 210 * GPA, 0.30),
    (("brass", "bronze"), "brass / bronze", 105 * GPA, 0.34),
    (("titan",), "titanium", 112 * GPA, 0.33),
    (("alumin",), "aluminium", 70 * GPA, 0.33),
    (("glass",), "glass", 70 * GPA, 0.22),
    (("nylon", "polyamide", "pa6", "pa66", "pa 6"), "nylon", 3.0 * GPA, 0.40),
    (("acetal", "delrin", "pom", "polyoxymethylene"), "acetal (POM)", 3.1 * GPA, 0.35),
    (("pmma", "acrylic"), "PMMA", 5.0 * GPA, 0.35),
    (("polycarbonate",), "polycarbonate", 2.35 * GPA, 0.37),
    (("ptfe", "teflon"), "PTFE", 0.5 * GPA, 0.46),
    (("polypropylene",), "polypropylene", 1.5 * GPA, 0.42),
    (("hdpe", "polyethylene"), "polyethylene", 1.0 * GPA, 0.42),
]
STEEL = Ball("steel", 210 * GPA, 0.30)


def lookup(text: str) -> Ball:
    """The table's ball with a keyword at the start of a word of `text`, else steel with known False."""
    row = first_keyword_entry(text, TABLE)
    if row is not None:
        return Ball(*row)
    return Ball(STEEL.name, STEEL.e_pa, STEEL.nu, known=False, source="default (steel)")


def ball_for_rig(rig, path="rig.json") -> Ball:
    """The rig's ball: rig.json `ball_properties` when given, else `ball_material` in words."""
    raw = getattr(rig, "raw", None) or {}
    props = raw.get("ball_properties")
    ball = lookup(raw.get("ball_material", getattr(rig, "ball_material", "")))
    if props is None:
        return ball
    if not isinstance(props, dict) or set(props) - {"e_pa", "nu"} or "e_pa" not in props:
        raise DataError(path, "ball_properties", 'must be an object {"e_pa": Pa, "nu": Poisson ratio} ("nu" optional)')
    vals = {}
    for key, lo, hi in (("e_pa", 0.0, math.inf), ("nu", -1.0, 0.5)):
        if key not in props:
            continue
        v = props[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo < v < hi:
            raise DataError(path, f"ball_properties.{key}", f"must be a number in ({lo:g}, {hi:g}), got {v!r}")
        vals[key] = float(v)
    return Ball(ball.name if ball.known else "declared", vals["e_pa"], vals.get("nu", ball.nu), known=True,
                source="rig.json ball_properties")


def check_ball_properties(raw: dict, path) -> None:
    """rig.json's optional `ball_properties` checked when the rig is read (a DataError naming the file and field)."""
    if "ball_properties" in raw:
        ball_for_rig(type("RigWords", (), {"raw": raw})(), path)


__all__ = ["Ball", "TABLE", "STEEL", "lookup", "ball_for_rig", "check_ball_properties"]
