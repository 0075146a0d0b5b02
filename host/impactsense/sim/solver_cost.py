"""What a batch of drops costs on each solver, in CPU seconds of one core: the rule `--solver auto` follows.

- direct (the fast path, `simulate.py`): four reciprocal runs over the whole record, then per drop the ball on
  the plate for its contact window, each step costing the elements it really steps x `DIRECT_S_PER_ELEMENT_STEP`.
  The windows are measured, not predicted (`measured_contact_windows`: PILOT_DROPS of the batch's drops, or of
  the site map's grid, stepped; a thin plate's ball chatters, windows 2-5 x a rigid Hertz contact), and a step
  is priced over the elements the wave has reached (`cone_element_steps`: the explicit step starts from rest).
  `batch_choice` steps the pilot only when the choice depends on it (`direct_bounds`);
- modal: the basis when it is not cached (free dofs x modes x `BASIS_S_PER_DOF_MODE`: the inertia-planned
  Lanczos slices and the residual probes, `modal_basis.py`), else its load; per drop its modal sum (modes x
  record samples x `MODAL_S_PER_DROP_MODE_SAMPLE`).

The constants are this machine's measurements on the bundled twin (docs/findings.md, "A reduced-order twin",
"The cold chain"); the rule only compares the two sums, so a machine that is uniformly faster keeps its choice.
The mode count of a basis not yet computed is Weyl's count along the softest direction x `MODE_COUNT_FACTOR`
(the finite-element plate holds more modes than Kirchhoff's below a frequency: 1.6 x on the bundled twin's
2 mm mesh, 2.8 x on a 5 mm mesh).
"""

from __future__ import annotations

import math

import numpy as np

DIRECT_S_PER_ELEMENT_STEP = 1.6e-9
BASIS_S_PER_DOF_MODE = 2.0e-6
MODAL_S_PER_DROP_MODE_SAMPLE = 2.2e-9
MODAL_LOAD_S = 1.5
MODE_COUNT_FACTOR = 2.0


PILOT_DROPS = 24   # contact windows stepped to measure a plate's mean window (`measured_contact_windows`)
COLUMN_BLOCK = 16  # the fused pass steps columns in blocks of this many (sim/src/step.cpp)


def cone_element_steps(model, x_m: float, y_m: float, steps: int) -> float:
    """The elements a contact window of `steps` steps at (x_m, y_m) really steps (sim/src/step.cpp): from rest,
    only the rows and columns the disturbance can have reached, one more per step around the contact nodes
    (the forward cone), and once the window's end is known only those still able to reach the contact point
    before it (the backward cone); the columns in blocks of COLUMN_BLOCK. A sub-cycled mesh steps the whole
    plate."""
    steps = int(steps)
    if steps <= 0:
        return 0.0
    if model.subcycles > 1:
        return float(steps * model.elements)
    i0 = min(int(x_m / model.hx_m), model.nx - 1)
    j0 = min(int(y_m / model.hy_m), model.ny - 1)
    n = np.arange(steps)
    r = np.minimum(n + 2, steps - n)
    rows = np.minimum(model.ny, j0 + 1 + r) - np.maximum(0, j0 - r)
    c_lo, c_hi = np.maximum(0, i0 - r), np.minimum(model.nx, i0 + 1 + r)
    cols = np.minimum(model.nx, (c_hi // COLUMN_BLOCK - c_lo // COLUMN_BLOCK + 1) * COLUMN_BLOCK)
    return float(np.sum(rows.astype(float) * cols))


def measured_contact_windows(model, x_mm, y_mm, height_mm) -> dict:
    """The fast path's contact windows of drops at (x_mm, y_mm) from height_mm (one height, or one a drop),
    stepped on the model (`simulate.contact_window`; cached on the model per set of drops): their mean steps
    ("steps") and mean elements stepped (`cone_element_steps`, "element_steps"). Counts, not times, so the
    machine's load does not enter them. On a thin plate the ball chatters (several contacts, the window 3-5 x a
    rigid Hertz contact: docs/findings.md, Session 25 mapcost)."""
    from .model import impact_velocity
    from .simulate import contact_window

    x = np.asarray(x_mm, float).ravel()
    y = np.asarray(y_mm, float).ravel()
    h = np.broadcast_to(np.asarray(height_mm, float), x.shape).ravel()
    key = (x.tobytes(), y.tobytes(), h.tobytes())
    cache = model.__dict__.setdefault("_windows", {})
    if key not in cache:
        v0 = np.asarray(impact_velocity(model.params, h), float)
        steps = [np.asarray(contact_window(model, a * 1e-3, b * 1e-3, float(v))["force_n"]).size
                 for a, b, v in zip(x, y, v0)]
        cache[key] = {"steps": float(np.mean(steps)),
                      "element_steps": float(np.mean([cone_element_steps(model, a * 1e-3, b * 1e-3, k)
                                                      for a, b, k in zip(x, y, steps)]))}
    return cache[key]


def pilot_rows(n_drops: int, n: int = PILOT_DROPS) -> np.ndarray:
    """Which of a batch's n_drops drops price it (`measured_contact_windows`): n of them, drawn with a fixed
    seed (the same drops for the same batch), in order."""
    n = min(int(n), int(n_drops))
    return np.sort(np.random.default_rng(0).choice(int(n_drops), n, replace=False))


def direct_parts(model, n_drops: int, window: dict) -> dict:
    """The direct solver's fast path, part by part: the four reciprocal runs ("runs_cpu_s", the whole plate every
    step) and one drop's contact window ("drop_cpu_s"; window: its mean elements stepped,
    `measured_contact_windows`)."""
    record_steps = model.n_record * model.record_every
    runs = len(model.sensors) * record_steps * model.elements * DIRECT_S_PER_ELEMENT_STEP
    drop = float(window["element_steps"]) * DIRECT_S_PER_ELEMENT_STEP
    return {"runs_cpu_s": runs, "drop_cpu_s": drop, "cpu_s": runs + n_drops * drop}


def direct_cpu_s(model, n_drops: int, window: dict) -> float:
    """The direct solver's fast path for n_drops drops (four reciprocal runs, then the contact windows)."""
    return direct_parts(model, n_drops, window)["cpu_s"]


def direct_bounds(model, n_drops: int) -> tuple[float, float]:
    """(lowest, highest) `direct_cpu_s` any window can give: no step at all, or every step of the longest
    window `simulate.contact_window` takes (contact_window_ms) over the whole plate."""
    longest = math.ceil(model.params.contact_window_ms * 1e-3 / model.dt_s)
    return (direct_cpu_s(model, n_drops, {"element_steps": 0.0}),
            direct_cpu_s(model, n_drops, {"element_steps": float(longest * model.elements)}))


def basis_modes(model) -> int:
    """The modes a cold basis of `model` will hold (an estimate: Weyl x MODE_COUNT_FACTOR)."""
    from .modal_basis import default_cutoff, estimated_modes

    return int(math.ceil(estimated_modes(model, default_cutoff(model)) / 3 * MODE_COUNT_FACTOR))


def basis_fits(model) -> bool:
    """Whether a cold basis of `model` is within the modal solver's size limit (`modal_basis.check_size`: a
    large thin plate's would be refused, so `auto` must not choose it)."""
    from ..errors import ConfigError
    from .modal_basis import check_size, default_cutoff

    try:
        check_size(model, default_cutoff(model))
    except ConfigError:
        return False
    return True


def modal_cpu_s(model, n_drops: int, *, cached: bool, modes: int | None = None) -> float:
    """The modal solver for n_drops drops: the basis (or its load when cached) and the modal sums."""
    modes = basis_modes(model) if modes is None else modes
    free_dofs = 3 * model.nodes
    basis = MODAL_LOAD_S if cached else free_dofs * modes * BASIS_S_PER_DOF_MODE
    return basis + n_drops * modes * model.n_record * MODAL_S_PER_DROP_MODE_SAMPLE


def choose(model, n_drops: int, window: dict, *, cached: bool) -> tuple[str, dict]:
    """("modal" | "direct", the two estimates in CPU s): the cheaper solver for this batch (window: the direct
    path's measured contact windows, `measured_contact_windows`). A cold basis over the modal solver's size
    limit is never chosen (`basis_fits`)."""
    direct = direct_cpu_s(model, n_drops, window)
    modal = modal_cpu_s(model, n_drops, cached=cached) if cached or basis_fits(model) else math.inf
    return ("modal" if modal < direct else "direct"), {"direct_cpu_s": direct, "modal_cpu_s": modal,
                                                       "basis_cached": cached}


def batch_choice(model, x_mm, y_mm, height_mm, *, cached: bool) -> str:
    """`choose` for a batch of drops at (x_mm, y_mm) from height_mm (one a drop): its windows measured on
    `pilot_rows` of the drops, stepped only when the choice depends on them (the modal estimate between
    `direct_bounds`)."""
    x = np.asarray(x_mm, float).ravel()
    n = x.size
    modal = modal_cpu_s(model, n, cached=cached) if cached or basis_fits(model) else math.inf
    lo, hi = direct_bounds(model, n)
    if modal >= hi:
        return "direct"
    if modal < lo:
        return "modal"
    rows = pilot_rows(n)
    h = np.broadcast_to(np.asarray(height_mm, float), x.shape)
    window = measured_contact_windows(model, x[rows], np.asarray(y_mm, float).ravel()[rows], h[rows])
    return choose(model, n, window, cached=cached)[0]
