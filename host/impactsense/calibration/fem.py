"""The calibration's view of the simulator: the fitted `SimParams` fields and `simulate(params, rig, x, y, h)`.

The calibration carries the fields it fits (e_pa, nu, damping_per_s, pzt_*, the model choices) by their
`impactsense.sim.SimParams` names and nothing else: `SimParams.from_rig(rig, **params)` is the simulator's
parameter set (the simulator's one parameter form), and CAL.json's "sim_params" its `to_dict()` (what
`SimParams.from_json(CAL.json)` / `simulate-dataset --calibration` loads).
"""

from __future__ import annotations

import threading
from typing import Callable

import numpy as np

from ..sim import SimParams, simulate_drops

# The design stage's factors (docs/method.md): SimParams name, low, high, step, unit
FACTORS = (
    ("pzt_rho_kg_m3", 7500.0, 7800.0, 150.0, "kg/m3"),
    ("pzt_e11_mpa", 55000.0, 85000.0, 5000.0, "MPa"),
    ("pzt_e33_mpa", 45000.0, 75000.0, 5000.0, "MPa"),
    ("pzt_nu12", 0.30, 0.40, 0.02, "-"),
    ("pzt_nu13", 0.30, 0.40, 0.02, "-"),
    ("pzt_g12_mpa", 20000.0, 25000.0, 2500.0, "MPa"),
    ("pzt_g13_mpa", 20000.0, 25000.0, 2500.0, "MPa"),
    ("pzt_d15_pc_n", 50.0, 800.0, 50.0, "pC/N"),
    ("pzt_d31_pc_n", -800.0, -50.0, 50.0, "pC/N"),
    ("pzt_d33_pc_n", 50.0, 800.0, 50.0, "pC/N"),
    ("pzt_eps11_rel", 500.0, 10000.0, 250.0, "-"),
    ("pzt_eps33_rel", 500.0, 10000.0, 250.0, "-"),
    ("damping_per_s", 200.0, 1200.0, 100.0, "1/s"),
)
FACTOR_NAMES = tuple(f[0] for f in FACTORS)


# The SimParams field `calibrate --disc-bond fit` fits (`disc_bond`).
DISC_BOND_FIELD = "disc_stiffness_scale"
# The twin's model choices a stage's result depends on beyond E, nu and D_s: set by --support, the `support`
# stage or the `disc_bond` stage. Absent (the rig's support, the bonded disc) they leave the cache keys as they
# were.
MODEL_FIELDS = ("laminate_e2_over_e1", "laminate_g12_over_e1", "element_mm", "support", "rim_stiffness_n_m2",
                "rim_damping_n_s_m2", "rim_inset_mm", DISC_BOND_FIELD, "disc_mass_scale", "disc_patch_diameter_mm")


def factor_range(name: str) -> tuple:
    """The design's (low, high) of factor `name`."""
    return FACTORS[FACTOR_NAMES.index(name)][1:3]

# Starting point before the design stage: the seed's fitted PZT and damping (docs/method.md).
SEED_PZT = {
    "pzt_rho_kg_m3": 7531.4, "pzt_e11_mpa": 75200.0, "pzt_e33_mpa": 55200.0, "pzt_nu12": 0.30,
    "pzt_nu13": 0.34, "pzt_g12_mpa": 24800.0, "pzt_g13_mpa": 24900.0, "pzt_d15_pc_n": 50.0,
    "pzt_d31_pc_n": -737.8, "pzt_d33_pc_n": 793.0, "pzt_eps11_rel": 3875.5, "pzt_eps33_rel": 6320.2,
    "damping_per_s": 1086.0,
}


def base_params(rig, e_mpa: float = 5000.0, nu: float = 0.32) -> dict:
    """Flat parameters: plate E (Pa) and nu, the seed's PZT block and damping. Plate rho, t and support
    come from the rig (`SimParams.from_rig`)."""
    return {"e_pa": float(e_mpa) * 1e6, "nu": float(nu), **SEED_PZT}


def available() -> bool:
    """Whether the FEM runs here (the simulator is built with the package; tests ask before FEM runs)."""
    return callable(simulate_drops)


def rig_support(rig) -> str:
    """The support `SimParams.from_rig` reads from rig.json's plate_support text."""
    return SimParams.from_rig(rig).support


# A laminate's fitted shape (stage `plate_laminate`): with these in the flat dict, its e_pa is the
# isotropic-equivalent modulus the other stages scale, and E1, E2, G12 follow from it (`_fields`).
LAMINATE_FIELDS = ("laminate_e2_over_e1", "laminate_g12_over_e1")


def laminate_moduli(e_equivalent_pa: float, nu12: float, e2_over_e1: float, g12_over_e1: float) -> dict:
    """SimParams' e_pa (E1), e2_pa, g12_pa of the laminate of that shape whose isotropic-equivalent modulus
    (`materials.equivalent_isotropic_ratio`) is e_equivalent_pa."""
    from .laminate import Laminate
    ratio = Laminate(1.0, e2_over_e1, g12_over_e1, nu12, 0.0).equivalent_ratio()
    e1 = e_equivalent_pa / ratio
    return {"e_pa": e1, "e2_pa": e1 * e2_over_e1, "g12_pa": e1 * g12_over_e1}


def _fields(flat: dict) -> dict:
    """The flat dict as SimParams fields: numbers as floats, the support (a name) as it is; a laminate's shape
    (LAMINATE_FIELDS) turns e_pa into E1, E2 and G12."""
    out = {k: (v if isinstance(v, str) else float(v)) for k, v in flat.items() if k not in LAMINATE_FIELDS}
    if all(k in flat for k in LAMINATE_FIELDS):
        out.update(laminate_moduli(out["e_pa"], out["nu"], *(float(flat[k]) for k in LAMINATE_FIELDS)))
    return out


def sim_params(flat: dict, rig) -> SimParams:
    """The simulator's parameters of the flat dict: `SimParams.from_rig(rig, **flat)` (the support: flat's,
    else the rig's text through `SimParams.from_rig`)."""
    return SimParams.from_rig(rig, **_fields(flat))


def sim_params_json(flat: dict, rig) -> dict:
    """CAL.json's "sim_params": `sim_params(flat, rig).to_dict()`."""
    return sim_params(flat, rig).to_dict()


def capped_mesh(flat: dict, rig, max_elements: int | None) -> dict:
    """The twin's mesh rule for the chain: Eq. 1's element size (`sim.model.mesh_size`), but no finer than the
    square element that puts `max_elements` on the rig's plate, sqrt(plate area / max_elements) (the
    calibration, the virtual drops, the site map and the calibration drops' twins then run on that mesh).
    Returns {"element_mm": size} when the cap binds, else {} (the twin keeps Eq. 1's mesh). An element_mm
    already in `flat` is kept."""
    from ..sim.model import mesh_size

    if not max_elements or "element_mm" in flat:
        return {}
    _, nx, ny, _, _ = mesh_size(SimParams.from_rig(rig, **_fields(flat)), rig)
    if nx * ny <= max_elements:
        return {}
    return {"element_mm": float(np.ceil(100 * np.sqrt(rig.plate_x_mm * rig.plate_y_mm / max_elements)) / 100)}


Simulator = Callable[[dict, object, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


_point = threading.local()      # inside points_concurrently: each point's drops in one thread


def fem_simulator(workers: int = 2, **overrides) -> Simulator:
    """`simulate(flat, rig, x_mm, y_mm, height_mm) -> uint16 [n, 4, samples]` with the project's FEM, its drops
    `workers` at a time (one at a time inside `points_concurrently`, which runs the points side by side).
    `overrides` are extra SimParams fields (e.g. element_mm for a coarse mesh)."""
    def simulate(flat, rig, x_mm, y_mm, height_mm):
        p = SimParams.from_rig(rig, **{**_fields(flat), **overrides})
        return np.asarray(simulate_drops(p, rig, np.asarray(x_mm, float), np.asarray(y_mm, float),
                                         np.asarray(height_mm, float), noise=False, seed=None,
                                         workers=getattr(_point, "workers", workers), progress=False))
    return simulate


def points_concurrently(fn, items, workers: int = 2):
    """fn(item) for every item (each one FEM point: a batch of the calibration drops), `workers` items side by
    side in threads, each item's drops one after the other in its thread; results in order. A calibration
    point is only a few drops, so spreading each point's drops over the cores leaves them idle at every
    point's end (drops of unequal cost, the model's build, the features); side by side they are not. The
    items that do not fill a round of `workers` (the last len % workers) run one at a time with their drops
    spread as before: alone in a thread, a point would leave the other cores idle. The FEM runs are the same
    either way (each drop is one run in one thread)."""
    from ..sim.executor import Executor

    def one(item):
        _point.workers = 1
        try:
            return fn(item)
        finally:
            del _point.workers
    items = list(items)
    n_side = len(items) - len(items) % workers if workers > 1 else 0
    side = list(Executor("", workers=workers).map(one, items[:n_side])) if n_side else []
    return side + [fn(item) for item in items[n_side:]]
