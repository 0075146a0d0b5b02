"""What a batch of drops costs on each solver, in CPU seconds of one core: the rule `--solver auto` follows.

- direct (the fast path, `simulate.py`): four reciprocal runs over the whole record, then per drop the ball on
  the plate for its contact window (about twice the rigid Hertz contact time, the plate's give lengthens it,
  plus the quiet tail of `simulate.contact_window`), each step costing the mesh's elements x
  `DIRECT_S_PER_ELEMENT_STEP`. The site map prices the windows better (`measured_contact_windows`): a few
  windows stepped on the plate (a thin plate's ball chatters: windows 2-5 x the rigid rule) and the elements each
  step really touches (`cone_element_steps`: the explicit step starts from rest);
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


def contact_steps(model, height_mm) -> float:
    """Mean steps of the fast path's contact windows for drops from height_mm: 2 x the rigid Hertz contact
    time (the plate's compliance lengthens it) + the quiet tail, at most contact_window_ms."""
    from .model import impact_velocity
    from .simulate import QUIET_AFTER_CONTACT_FRACTION, QUIET_AFTER_CONTACT_S

    v = np.maximum(np.asarray(impact_velocity(model.params, np.atleast_1d(height_mm)), float), 1e-3)
    depth = (5 * model.ball_mass_kg * v ** 2 / (4 * model.k_hertz)) ** 0.4
    contact = 2 * 2.9432 * depth / v
    quiet = np.maximum(QUIET_AFTER_CONTACT_S, QUIET_AFTER_CONTACT_FRACTION * contact)
    t = np.minimum(contact + quiet, model.params.contact_window_ms * 1e-3)
    return float(np.mean(t)) / model.dt_s


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


def measured_contact_windows(model, x_mm, y_mm, height_mm: float) -> dict:
    """The fast path's contact windows of drops from height_mm at (x_mm, y_mm), stepped on the model
    (`simulate.contact_window`; cached on the model per set of points): their mean steps ("steps") and mean
    elements stepped (`cone_element_steps`, "element_steps"). Counts, not times, so the machine's load does not
    enter them. On a thin plate the ball chatters (several contacts, the window 3-5 x `contact_steps`'
    rigid-Hertz estimate: docs/findings.md, Session 25 mapcost)."""
    from .model import impact_velocity
    from .simulate import contact_window

    x = np.asarray(x_mm, float).ravel()
    y = np.asarray(y_mm, float).ravel()
    key = (float(height_mm), x.tobytes(), y.tobytes())
    cache = model.__dict__.setdefault("_windows", {})
    if key not in cache:
        v0 = float(impact_velocity(model.params, float(height_mm)))
        steps = [np.asarray(contact_window(model, a * 1e-3, b * 1e-3, v0)["force_n"]).size for a, b in zip(x, y)]
        cache[key] = {"steps": float(np.mean(steps)),
                      "element_steps": float(np.mean([cone_element_steps(model, a * 1e-3, b * 1e-3, k)
                                                      for a, b, k in zip(x, y, steps)]))}
    return cache[key]


def direct_parts(model, n_drops: int, height_mm, window: dict | None = None) -> dict:
    """The direct solver's fast path, part by part: the four reciprocal runs ("runs_cpu_s", the whole plate every
    step) and one drop's contact window ("drop_cpu_s"; window: its measured mean elements stepped,
    `measured_contact_windows`, else the `contact_steps` estimate over the whole plate)."""
    record_steps = model.n_record * model.record_every
    runs = len(model.sensors) * record_steps * model.elements * DIRECT_S_PER_ELEMENT_STEP
    if window is None:
        element_steps = contact_steps(model, height_mm) * model.elements
    else:
        element_steps = float(window["element_steps"])
    drop = element_steps * DIRECT_S_PER_ELEMENT_STEP
    return {"runs_cpu_s": runs, "drop_cpu_s": drop, "cpu_s": runs + n_drops * drop}


def direct_cpu_s(model, n_drops: int, height_mm, window: dict | None = None) -> float:
    """The direct solver's fast path for n_drops drops (four reciprocal runs, then the contact windows)."""
    return direct_parts(model, n_drops, height_mm, window)["cpu_s"]


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


def choose(model, n_drops: int, height_mm, *, cached: bool, window: dict | None = None) -> tuple[str, dict]:
    """("modal" | "direct", the two estimates in CPU s): the cheaper solver for this batch (window: the direct
    path's measured contact windows, `direct_parts`)."""
    direct = direct_cpu_s(model, n_drops, height_mm, window)
    modal = modal_cpu_s(model, n_drops, cached=cached) if cached or basis_fits(model) else math.inf
    return ("modal" if modal < direct else "direct"), {"direct_cpu_s": direct, "modal_cpu_s": modal,
                                                       "basis_cached": cached}
