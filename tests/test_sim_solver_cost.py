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


def test_direct_estimate_scales_with_the_mesh_as_the_cost_law_says():
    """The site map's direct estimate on two meshes of one plate: the contact window measured in steps
    (`measured_contact_windows`) is a physical time, so it holds the same microseconds on both meshes; the elements
    a window steps follow the cone law (`cone_element_steps`: never more than the whole plate every step, all of
    it once the cone has crossed the plate), and the estimate per drop is that count x the constant, the
    reciprocal runs the whole plate x the record's steps."""
    from impactsense.sitemap import pilot_points

    rig = small_rig(300.0, 200.0)
    pts = pilot_points(rig, n=6)
    got = []
    for h in (5.0, 2.5):
        model = build_model(params(element_mm=h), rig)
        win = solver_cost.measured_contact_windows(model, pts[:, 0], pts[:, 1], 175.0)
        got.append((model, win, solver_cost.direct_parts(model, 1, 175.0, win)))
    (m1, w1, p1), (m2, w2, p2) = got
    assert m2.elements == pytest.approx(4 * m1.elements, rel=0.05)
    assert w2["steps"] * m2.dt_s == pytest.approx(w1["steps"] * m1.dt_s, rel=0.15)   # the same contact time
    for m, w in ((m1, w1), (m2, w2)):
        assert 0.2 * w["steps"] * m.elements < w["element_steps"] <= w["steps"] * m.elements
    assert p2["drop_cpu_s"] / p1["drop_cpu_s"] == pytest.approx(w2["element_steps"] / w1["element_steps"], rel=1e-9)
    assert p1["drop_cpu_s"] == pytest.approx(w1["element_steps"] * solver_cost.DIRECT_S_PER_ELEMENT_STEP)
    runs = (m2.elements * m2.n_record * m2.record_every) / (m1.elements * m1.n_record * m1.record_every)
    assert p2["runs_cpu_s"] / p1["runs_cpu_s"] == pytest.approx(runs, rel=1e-9)


def test_cone_law_counts_the_rows_and_column_blocks_reached():
    model = build_model(params(element_mm=5.0), small_rig(300.0, 200.0))   # 60 x 40 elements
    nx, ny = model.nx, model.ny
    centre = (150e-3, 100e-3)
    assert 0 < solver_cost.cone_element_steps(model, *centre, 1) <= 4 * 2 * 16    # step 0: a few rows, <= 2 blocks
    long = 10 * (nx + ny)
    whole = solver_cost.cone_element_steps(model, *centre, long)
    assert long * model.elements * 0.9 < whole < long * model.elements          # the cone soon covers the plate
    corner = solver_cost.cone_element_steps(model, 1e-3, 1e-3, 20)
    assert corner < solver_cost.cone_element_steps(model, *centre, 20)          # the edges clip the cone


def test_thin_plate_window_is_measured_not_the_rigid_hertz_estimate():
    """On a thin sheet the ball chatters (several contacts): the window the solver steps is well over
    `contact_steps`' rigid-Hertz estimate, and the site map's cost is priced with the measured one."""
    from impactsense.sitemap import pilot_points, site_map_cost

    rig = small_rig(300.0, 200.0)
    thin = params(thickness_mm=1.5, e_pa=70e9, nu=0.33, rho_kg_m3=2700.0)
    model = get_model(thin, rig)
    pts = pilot_points(rig)
    v0 = float(impact_velocity(model.params, 175.0))
    steps = [np.asarray(contact_window(model, x * 1e-3, y * 1e-3, v0)["force_n"]).size for x, y in pts]
    win = solver_cost.measured_contact_windows(model, pts[:, 0], pts[:, 1], 175.0)
    assert win["steps"] == pytest.approx(np.mean(steps))
    assert win["steps"] > 1.4 * solver_cost.contact_steps(model, 175.0)
    cost = site_map_cost(thin, rig, every=2)
    assert cost["window_steps"] == pytest.approx(win["steps"])
    if cost["solver"] == "direct":
        assert cost["cpu_s"] == pytest.approx(solver_cost.direct_cpu_s(model, cost["simulated"], 175.0, win))


def test_auto_never_chooses_a_basis_the_modal_solver_would_refuse(monkeypatch):
    model = get_model(params(element_mm=2.0), small_rig(160.0, 140.0))
    assert solver_cost.choose(model, 10 ** 7, 175.0, cached=False)[0] == "modal"      # a huge batch pays a basis
    monkeypatch.setenv("IMPACTSENSE_MODAL_MAX_MB", "0.01")                            # ... unless it is refused
    assert not solver_cost.basis_fits(model)
    assert solver_cost.choose(model, 10 ** 7, 175.0, cached=False)[0] == "direct"
