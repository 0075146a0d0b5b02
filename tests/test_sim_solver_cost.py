"""`--solver auto`'s cost rule (sim/solver_cost.py): its estimates against the model it prices, and the choice.

- the fast path's contact window: the estimate (2 x the rigid Hertz time + the quiet tail) against the steps the
  direct solver really takes for drops on a small plate, within a factor 1.6 either way (the plate's give and a
  drop near an edge or a disc move it; the rule compares costs that differ by 3-30x on the rigs measured);
- the mode count of a basis not yet computed (Weyl x 2) against the count the solve finds, within 2x;
- the choice: cold and few drops -> direct; the basis cached -> modal; a batch large enough to pay for the basis
  -> modal, and batch_solver("auto", n) follows it.
"""

from __future__ import annotations

import numpy as np
import pytest

from impactsense.sim import SimParams, modal_basis, solver_cost
from impactsense.sim.model import build_model, impact_velocity
from impactsense.sim.simulate import batch_solver, contact_window, get_model

from test_sim_modal import small_rig


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("IMPACTSENSE_MODAL_CACHE", str(tmp_path / "modal-cache"))


def params(**kw):
    return SimParams(**{"element_mm": 5.0, "duration_ms": 2.0, "taper_ms": 0.2, **kw})


def test_contact_window_estimate_is_within_a_factor_of_the_direct_solver():
    rig = small_rig(160.0, 140.0)
    model = build_model(params(), rig)
    for h in (60.0, 250.0):
        v0 = float(impact_velocity(model.params, h))
        steps = [np.asarray(contact_window(model, x, y, v0)["force_n"]).size
                 for x, y in ((0.08, 0.07), (0.05, 0.09), (0.11, 0.05))]
        est = solver_cost.contact_steps(model, h)
        assert 1 / 1.6 <= est / np.mean(steps) <= 1.6, (h, est, steps)


def test_basis_mode_estimate_and_the_choice():
    rig = small_rig(160.0, 140.0)
    fine = params(element_mm=2.0)              # a drop costs the direct solver more than the modal sum here
    model = get_model(fine, rig)
    assert batch_solver(fine, rig, "auto", n_drops=4) == "direct"        # cold: a few drops never pay a basis
    per_drop = solver_cost.direct_cpu_s(model, 1, 175.0) - solver_cost.direct_cpu_s(model, 0, 175.0) \
        - (solver_cost.modal_cpu_s(model, 1, cached=True) - solver_cost.modal_cpu_s(model, 0, cached=True))
    assert per_drop > 0
    big = int(2 * solver_cost.modal_cpu_s(model, 0, cached=False) / per_drop)
    assert solver_cost.choose(model, big // 4, 175.0, cached=False)[0] == "direct"
    assert solver_cost.choose(model, big, 175.0, cached=False)[0] == "modal"
    assert batch_solver(fine, rig, "auto", n_drops=big) == "modal"
    assert batch_solver(fine, rig, "direct", n_drops=10 ** 6) == "direct"  # an explicit solver is kept
    p = params()
    model = get_model(p, rig)
    est = solver_cost.basis_modes(model)
    basis = modal_basis.load_or_compute(model)
    assert 0.5 <= est / basis.modes <= 2.0, (est, basis.modes)
    # cached, only its load is paid: modal from a batch that would not have paid the whole basis
    margin = solver_cost.direct_cpu_s(model, 1, 175.0) - solver_cost.modal_cpu_s(model, 1, cached=True) \
        - solver_cost.direct_cpu_s(model, 0, 175.0) + solver_cost.modal_cpu_s(model, 0, cached=True)
    lo = solver_cost.MODAL_LOAD_S / margin
    hi = solver_cost.modal_cpu_s(model, 0, cached=False) / margin
    assert hi > 1.5 * lo
    n = int(np.sqrt(lo * hi))
    assert solver_cost.choose(model, n, 175.0, cached=False)[0] == "direct"
    assert batch_solver(p, rig, "auto", n_drops=n) == "modal"
    assert batch_solver(p, rig, "auto") == "modal"                       # no count given: the cache decides
