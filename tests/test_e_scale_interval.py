"""size_plate_change states what the picks allow in E: the pick velocity change's 95 % interval (the diagnosis's
fold jackknife) mapped through the exponent the E put in implies, E = (1 + change)^(1 / n)."""

from __future__ import annotations

import numpy as np

from impactsense import loop
from impactsense.diagnose import Candidate, _param_ci, _param_se


def test_the_e_interval_is_the_pick_velocity_interval_through_the_exponent_used(monkeypatch):
    n = 0.4
    change = -4.0
    folds = [{"change_pct": change + d, "velocity_m_s": 800.0} for d in (-0.3, -0.1, 0.0, 0.1, 0.3)]
    cand = Candidate("wave_speed", None, {"change_pct": change, "velocity_m_s": 800.0}, 50.0, 1e-6, True, True,
                     folds)
    scale = (1 + change / 100) ** (1 / n)
    monkeypatch.setattr(loop, "e_scale_scan", lambda *a, **k: {"e_scale": scale, "exponent": n,
                                                                 "first_guess": scale})
    (out,) = loop.size_plate_change(None, None, [cand], None)
    p = out.params
    lo, hi = _param_ci(cand, _param_se(cand))["change_pct"]
    assert p["e_scale_lo"] < p["e_scale"] < p["e_scale_hi"]
    np.testing.assert_allclose([p["e_scale_lo"], p["e_scale_hi"]], [(1 + lo / 100) ** (1 / n), (1 + hi / 100) ** (1 / n)],
                               rtol=1e-9)
    # the picks' change moves E by about change / n: the interval in E is ~1 / n times the change's
    assert 2.0 < (p["e_scale_hi"] - p["e_scale_lo"]) / ((hi - lo) / 100) < 3.0
    # another effect is passed through untouched
    other = Candidate("damping", None, {"extra_decay_per_s": 10.0}, 5.0, 0.01, True, True, [])
    assert loop.size_plate_change(None, None, [other], None)[0] is other
