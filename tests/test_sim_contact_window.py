"""The fast path's contact window (sim.simulate.contact_window) ends once the ball has been off the plate for
100 us and half the contact's duration: a longer wait (the former rule, the contact's whole duration) must find
no touch after it, so the force history, and the disc voltages convolved from it, are the same floats."""

from __future__ import annotations

import numpy as np
import pytest

from impactsense.data import bundled_session_path, load_rig
from impactsense.sim import SimParams, simulate
from impactsense.sim.model import build_model, impact_velocity


@pytest.fixture(scope="module")
def model():
    rig = load_rig(bundled_session_path())
    return build_model(SimParams.from_rig(rig, element_mm=5.0, duration_ms=2.0, taper_ms=0.1), rig)


def test_the_shorter_quiet_time_loses_no_touch(model):
    p = model.params
    for x_mm, y_mm, h_mm in ((14.0, 12.0, 40.0), (160.0, 150.0, 175.0), (305.0, 140.0, 250.0), (60.0, 290.0, 110.0)):
        v0 = float(impact_velocity(p, h_mm))
        ball = [x_mm * 1e-3, y_mm * 1e-3, model.ball_mass_kg, model.k_hertz, v0, p.g_m_s2]
        short = simulate.contact_window(model, *ball[:2], v0)
        long = model.plate.run(dt_s=model.dt_s, n_steps=int(np.ceil(p.contact_window_ms * 1e-3 / model.dt_s)),
                               record_every=model.record_every, n_record=0, ball=ball, stop_after_contact=True,
                               quiet_after_contact_s=100e-6, quiet_after_contact_fraction=1.0)
        f_short, f_long = np.asarray(short["force_n"]), np.asarray(long["force_n"])
        contact = short["contact_end_s"] - short["contact_start_s"]
        assert contact > 100e-6                                     # long enough for the rules to differ
        assert f_short.size < f_long.size                           # the window is shorter ...
        assert np.array_equal(f_short, f_long[:f_short.size])       # ... the same force while it runs
        assert not np.any(f_long[f_short.size:])                    # and no touch in the part left out
        assert short["contacts"] == long["contacts"]
        quiet = (f_short.size - 1) * model.dt_s - short["contact_end_s"]
        assert quiet == pytest.approx(max(simulate.QUIET_AFTER_CONTACT_S,
                                          simulate.QUIET_AFTER_CONTACT_FRACTION * contact), abs=2 * model.dt_s)
