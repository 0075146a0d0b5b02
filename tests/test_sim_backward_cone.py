"""A contact window wants only the ball's force (`simulate.contact_window`, RunConfig force_only): once the ball
has left, the window's last step is known, and the nodes too far to reach the contact point by then are no
longer stepped (sim/src/step.cpp, backward_cone). The force history and the contact point's own motion must be
the whole run's bit for bit; a touch that makes the window longer after that runs the window again whole."""

from __future__ import annotations

import numpy as np
import pytest

from impactsense.data import bundled_session_path, load_rig
from impactsense.sim import SimParams, simulate
from impactsense.sim.model import build_model, impact_velocity

DROPS = ((14.0, 12.0, 40.0), (160.0, 150.0, 175.0), (305.0, 140.0, 250.0), (60.0, 290.0, 110.0))


def _window(model, x_mm, y_mm, h_mm, force_only, n_record=0, sensors=(), mass_factor=1.0):
    p = model.params
    ball = [x_mm * 1e-3, y_mm * 1e-3, model.ball_mass_kg * mass_factor, model.k_hertz,
            float(impact_velocity(p, h_mm)), p.g_m_s2]
    return model.plate.run(dt_s=model.dt_s, n_steps=int(np.ceil(p.contact_window_ms * 1e-3 / model.dt_s)),
                           record_every=model.record_every, n_record=n_record, sensors=list(sensors), ball=ball,
                           stop_after_contact=True, quiet_after_contact_s=simulate.QUIET_AFTER_CONTACT_S,
                           quiet_after_contact_fraction=simulate.QUIET_AFTER_CONTACT_FRACTION, force_only=force_only)


def _same_window(a: dict, b: dict) -> None:
    fa, fb = np.asarray(a["force_n"]), np.asarray(b["force_n"])
    assert fa.shape == fb.shape and np.array_equal(fa.view(np.uint8), fb.view(np.uint8))
    for key in ("steps_done", "contacts", "contact_start_s", "contact_end_s", "ball_z_m", "ball_v_m_s"):
        assert a[key] == b[key], key


# 5 mm: 64 elements a row; 6 mm with the elastic rim's springs and dashpots (loads on the edge nodes)
@pytest.mark.parametrize("element_mm, support", [(5.0, "simply_supported"), (6.0, "elastic_rim")])
def test_force_only_windows_give_the_whole_runs_force_and_contact_motion(element_mm, support):
    rig = load_rig(bundled_session_path())
    model = build_model(SimParams.from_rig(rig, element_mm=element_mm, support=support, duration_ms=2.0,
                                           taper_ms=0.1), rig)
    for x_mm, y_mm, h_mm in DROPS:
        # the contact point's rotations recorded: they lie inside the kept cone, so they too must be exact up
        # to the window's last step (what a cone one row or column short would get wrong first)
        nodes, wts = model.bilinear(x_mm * 1e-3, y_mm * 1e-3)
        at_contact = (nodes.astype(np.int64), wts, wts)
        kw = dict(n_record=400, sensors=[at_contact])
        shrunk, whole = _window(model, x_mm, y_mm, h_mm, True, **kw), _window(model, x_mm, y_mm, h_mm, False, **kw)
        _same_window(shrunk, whole)
        rec = np.asarray(shrunk["sensors"])      # every step of the window, its last one included
        assert np.abs(rec).max() > 0 and np.array_equal(rec, np.asarray(whole["sensors"]))
        assert np.isnan(shrunk["w"]).all() and np.isfinite(whole["w"]).all()   # the plate's state is not kept
        assert np.array_equal(np.asarray(simulate.contact_window(model, x_mm * 1e-3, y_mm * 1e-3,
                                                                 float(impact_velocity(model.params, h_mm)))
                                         ["force_n"]), np.asarray(shrunk["force_n"]))


def test_a_touch_after_the_cone_shrank_runs_the_window_again_whole():
    rig = load_rig(bundled_session_path())
    model = build_model(SimParams.from_rig(rig, element_mm=5.0, duration_ms=2.0, taper_ms=0.1), rig)
    # a ball ten times as heavy, mid-plate: the plate comes back onto it after the first separation, when the
    # window's end had been predicted and the cone had begun to shrink
    whole = _window(model, 160.0, 150.0, 175.0, False, mass_factor=10.0)
    assert whole["contacts"] >= 2
    _same_window(_window(model, 160.0, 150.0, 175.0, True, mass_factor=10.0), whole)
