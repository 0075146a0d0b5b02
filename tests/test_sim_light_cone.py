"""The stepper steps only the rows and 16-node blocks a run's light cone has reached (sim/src/step.cpp,
widen_cone): the nodes outside are at rest, so skipping them must give the same floats. A run given an
initial state (here all zeros: the same run) steps every node, so the two runs must agree bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from impactsense.data import bundled_session_path, load_rig
from impactsense.sim import SimParams
from impactsense.sim.model import build_model, impact_velocity


@pytest.fixture(scope="module")
def rig():
    return load_rig(bundled_session_path())


def _same(a: dict, b: dict, keys) -> None:
    for key in keys:
        x, y = np.asarray(a[key]), np.asarray(b[key])
        assert x.shape == y.shape, key
        assert np.array_equal(x.view(np.uint8), y.view(np.uint8)), f"{key} differs"


# 5 mm: 64 elements a row (node nx starts a block of its own); 6 mm: 54 (the last block masked)
@pytest.mark.parametrize("element_mm, support", [(5.0, "simply_supported"), (6.0, "elastic_rim")])
def test_light_cone_gives_the_full_pass_floats(rig, element_mm, support):
    p = SimParams.from_rig(rig, element_mm=element_mm, support=support, duration_ms=2.0, taper_ms=0.1)
    model = build_model(p, rig)
    assert model.subcycles == 1
    zeros = np.zeros(model.plate.nodes)
    v0 = float(impact_velocity(p, 175.0))
    n_rec = 120
    base = dict(dt_s=model.dt_s, n_steps=n_rec * model.record_every, record_every=model.record_every,
                n_record=n_rec, sensors=model.sensors)
    # a drop near a corner (the cone clipped on two sides), one mid-plate, one by an edge; energy steps
    # (the portable pass) mixed in on one of them
    for x_mm, y_mm, energy in ((12.0, 9.0, False), (160.0, 150.0, True), (300.0, 140.0, False)):
        ball = [x_mm * 1e-3, y_mm * 1e-3, model.ball_mass_kg, model.k_hertz, v0, p.g_m_s2]
        cone = model.plate.run(ball=ball, record_field=True, record_energy=energy, **base)
        full = model.plate.run(ball=ball, record_field=True, record_energy=energy, w0=zeros, **base)
        assert np.abs(np.asarray(cone["sensors"])).max() > 0       # the waves reached the discs
        _same(cone, full, ["sensors", "field", "force_n", "w", "bx", "by"] + (["energy"] if energy else []))
    # a reciprocal run (the hat load on a disc's functional) and a contact window cut after the touch
    cone = model.plate.run(load=model.sensors[2], record_field=True, **base)
    full = model.plate.run(load=model.sensors[2], record_field=True, w0=zeros, **base)
    _same(cone, full, ["field", "w"])
    ball = [0.1, 0.2, model.ball_mass_kg, model.k_hertz, v0, p.g_m_s2]
    kw = dict(dt_s=model.dt_s, n_steps=2000, record_every=model.record_every, n_record=0, ball=ball,
              stop_after_contact=True)
    _same(model.plate.run(**kw), model.plate.run(w0=zeros, **kw), ["force_n", "w", "bx", "by"])
