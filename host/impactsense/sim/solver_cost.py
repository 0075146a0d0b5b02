"""What a batch of drops costs on each solver, in CPU seconds of one core: the rule `--solver auto` follows.

- direct (the fast path, `simulate.py`): four reciprocal runs over the whole record, then per drop the ball on
  the plate for its contact window (about twice the rigid Hertz contact time, the plate's give lengthens it,
  plus the quiet tail of `simulate.contact_window`), each step costing the mesh's elements x
  `DIRECT_S_PER_ELEMENT_STEP`;
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


def direct_cpu_s(model, n_drops: int, height_mm) -> float:
    """The direct solver's fast path for n_drops drops (four reciprocal runs, then the contact windows)."""
    record_steps = model.n_record * model.record_every
    steps = len(model.sensors) * record_steps + n_drops * contact_steps(model, height_mm)
    return steps * model.elements * DIRECT_S_PER_ELEMENT_STEP


def basis_modes(model) -> int:
    """The modes a cold basis of `model` will hold (an estimate: Weyl x MODE_COUNT_FACTOR)."""
    from .modal_basis import default_cutoff, estimated_modes

    return int(math.ceil(estimated_modes(model, default_cutoff(model)) / 3 * MODE_COUNT_FACTOR))


def modal_cpu_s(model, n_drops: int, *, cached: bool, modes: int | None = None) -> float:
    """The modal solver for n_drops drops: the basis (or its load when cached) and the modal sums."""
    modes = basis_modes(model) if modes is None else modes
    free_dofs = 3 * model.nodes
    basis = MODAL_LOAD_S if cached else free_dofs * modes * BASIS_S_PER_DOF_MODE
    return basis + n_drops * modes * model.n_record * MODAL_S_PER_DROP_MODE_SAMPLE


def choose(model, n_drops: int, height_mm, *, cached: bool) -> tuple[str, dict]:
    """("modal" | "direct", the two estimates in CPU s): the cheaper solver for this batch."""
    direct = direct_cpu_s(model, n_drops, height_mm)
    modal = modal_cpu_s(model, n_drops, cached=cached)
    return ("modal" if modal < direct else "direct"), {"direct_cpu_s": direct, "modal_cpu_s": modal,
                                                       "basis_cached": cached}
