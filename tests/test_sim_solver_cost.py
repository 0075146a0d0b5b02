"""`--solver auto`'s cost rule (sim/solver_cost.py), one for every batch command: its estimates against the
model it prices, and the choice.

- the direct path's contact windows are measured (a few of the batch's drops stepped), and on a thin sheet they
  are longer than on a thick plate of the same metal (the ball chatters);
- the mode count of a basis not yet computed (Weyl x 2) against the count the solve finds, within 2x;
- the choice: cold and few drops -> direct; the basis cached -> modal; a batch large enough to pay for the basis
  -> modal, and batch_solver("auto", x, y, h) follows it; its shortcut (no pilot where the choice cannot depend on
  the windows) never changes the choice.
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


def drops(rig, n, seed=0):
    """n drops spread over the plate's middle (mm), heights 100-200 mm."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.3, 0.7, n) * rig.plate_x_mm
    y = rng.uniform(0.3, 0.7, n) * rig.plate_y_mm
    return x, y, rng.uniform(100.0, 200.0, n)


def pilot_window(model, x, y, h):
    rows = solver_cost.pilot_rows(x.size)
    return solver_cost.measured_contact_windows(model, x[rows], y[rows], h[rows])


def test_batch_pilot_is_a_fixed_draw_of_the_batch_and_its_windows_are_the_drops_own():
    rig = small_rig(160.0, 140.0)
    model = build_model(params(), rig)
    assert solver_cost.pilot_rows(10).tolist() == list(range(10))           # a small batch: every drop
    rows = solver_cost.pilot_rows(500)
    assert rows.size == solver_cost.PILOT_DROPS and np.all(np.diff(rows) > 0) and rows.max() < 500
    assert np.array_equal(rows, solver_cost.pilot_rows(500))               # the same batch, the same drops
    x, y, h = drops(rig, 3)
    win = solver_cost.measured_contact_windows(model, x, y, h)
    v0 = impact_velocity(model.params, h)
    steps = [np.asarray(contact_window(model, a * 1e-3, b * 1e-3, float(v))["force_n"]).size
             for a, b, v in zip(x, y, v0)]
    assert win["steps"] == pytest.approx(np.mean(steps))
    lo, hi = solver_cost.direct_bounds(model, 3)
    assert lo < solver_cost.direct_cpu_s(model, 3, win) < hi


def test_basis_mode_estimate_and_the_choice():
    rig = small_rig(160.0, 140.0)
    fine = params(element_mm=2.0)              # a drop costs the direct solver more than the modal sum here
    model = get_model(fine, rig)
    x, y, h = drops(rig, 4)
    assert batch_solver(fine, rig, "auto", x, y, h) == "direct"        # cold: a few drops never pay a basis
    win = pilot_window(model, *drops(rig, 400))
    per_drop = solver_cost.direct_parts(model, 1, win)["drop_cpu_s"] \
        - (solver_cost.modal_cpu_s(model, 1, cached=True) - solver_cost.modal_cpu_s(model, 0, cached=True))
    assert per_drop > 0
    big = int(2 * solver_cost.modal_cpu_s(model, 0, cached=False) / per_drop)
    assert solver_cost.choose(model, big // 4, win, cached=False)[0] == "direct"
    assert solver_cost.choose(model, big, win, cached=False)[0] == "modal"
    x, y, h = drops(rig, big)
    assert batch_solver(fine, rig, "auto", x, y, h) == "modal"
    assert batch_solver(fine, rig, "direct", x, y, h) == "direct"      # an explicit solver is kept
    p = params()
    model = get_model(p, rig)
    est = solver_cost.basis_modes(model)
    basis = modal_basis.load_or_compute(model)
    assert 0.5 <= est / basis.modes <= 2.0, (est, basis.modes)
    # cached, only its load is paid: modal from a batch that would not have paid the whole basis
    win = pilot_window(model, *drops(rig, 400))
    margin = solver_cost.direct_parts(model, 1, win)["drop_cpu_s"] - solver_cost.modal_cpu_s(model, 1, cached=True) \
        + solver_cost.modal_cpu_s(model, 0, cached=True)
    lo = solver_cost.MODAL_LOAD_S / margin
    hi = solver_cost.modal_cpu_s(model, 0, cached=False) / margin
    assert hi > 1.5 * lo
    n = int(np.sqrt(lo * hi))
    x, y, h = drops(rig, n)
    assert solver_cost.choose(model, n, pilot_window(model, x, y, h), cached=False)[0] == "direct"
    assert batch_solver(p, rig, "auto", x, y, h) == "modal"


def test_the_shortcut_never_changes_the_choice():
    """`batch_choice` steps no pilot when the modal estimate lies outside the direct estimate's bounds; over
    batch sizes from a few drops to far past the crossover it gives `choose`'s answer with the measured windows."""
    rig = small_rig(160.0, 140.0)
    fine = params(element_mm=2.0)
    ref, model = build_model(fine, rig), build_model(fine, rig)
    win = pilot_window(ref, *drops(rig, 400))
    per_drop = solver_cost.direct_parts(ref, 1, win)["drop_cpu_s"] \
        - (solver_cost.modal_cpu_s(ref, 1, cached=True) - solver_cost.modal_cpu_s(ref, 0, cached=True))
    crossover = solver_cost.modal_cpu_s(ref, 0, cached=False) / per_drop
    answers, stepped = [], []
    for n in (2, crossover / 3, crossover / 1.2, 1.2 * crossover, 3 * crossover, 10 * crossover):
        x, y, h = drops(rig, int(n))
        want = solver_cost.choose(ref, x.size, pilot_window(ref, x, y, h), cached=False)[0]
        before = len(model.__dict__.get("_windows", {}))
        assert solver_cost.batch_choice(model, x, y, h, cached=False) == want, n
        answers.append(want)
        stepped.append(len(model.__dict__.get("_windows", {})) > before)
    assert answers == ["direct"] * 3 + ["modal"] * 3
    assert not stepped[0]                              # a few drops: direct whatever the windows, none stepped
    assert stepped[2] and stepped[3]                   # near the crossover the measured windows decide


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
        got.append((model, win, solver_cost.direct_parts(model, 1, win)))
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


def test_thin_plate_window_is_measured_and_prices_every_batch_command():
    """On a thin sheet the ball chatters (several contacts): the window the solver steps is well over a thick
    plate's of the same metal (whose rigid Hertz contact is nearly the same), and both the site map and a batch
    of virtual drops are priced with the measured windows."""
    from impactsense.sitemap import pilot_points, site_map_cost

    rig = small_rig(300.0, 200.0)
    alu = dict(e_pa=70e9, nu=0.33, rho_kg_m3=2700.0)
    thin = params(thickness_mm=1.5, **alu)
    model = get_model(thin, rig)
    pts = pilot_points(rig)
    win = solver_cost.measured_contact_windows(model, pts[:, 0], pts[:, 1], 175.0)
    thick = build_model(params(thickness_mm=10.0, **alu), rig)
    win_thick = solver_cost.measured_contact_windows(thick, pts[:, 0], pts[:, 1], 175.0)
    assert win["steps"] * model.dt_s > 1.4 * win_thick["steps"] * thick.dt_s
    cost = site_map_cost(thin, rig, every=2)
    assert cost["window_steps"] == pytest.approx(win["steps"])
    if cost["solver"] == "direct":
        assert cost["cpu_s"] == pytest.approx(solver_cost.direct_cpu_s(model, cost["simulated"], win))
    x, y, h = drops(rig, 3000)
    want = solver_cost.choose(model, x.size, pilot_window(model, x, y, h), cached=False)[0]
    assert batch_solver(thin, rig, "auto", x, y, h) == want


def test_auto_never_chooses_a_basis_the_modal_solver_would_refuse(monkeypatch):
    model = get_model(params(element_mm=2.0), small_rig(160.0, 140.0))
    win = pilot_window(model, *drops(small_rig(160.0, 140.0), 30))
    assert solver_cost.choose(model, 10 ** 7, win, cached=False)[0] == "modal"        # a huge batch pays a basis
    monkeypatch.setenv("IMPACTSENSE_MODAL_MAX_MB", "0.01")                            # ... unless it is refused
    assert not solver_cost.basis_fits(model)
    assert solver_cost.choose(model, 10 ** 7, win, cached=False)[0] == "direct"
