"""size_plate_change states what the picks allow in E: the pick velocity change's 95 % interval (the diagnosis's
fold jackknife) mapped through the scan's and the A0 curve's exponents, E = (1 + change)^(1 / n)."""

from __future__ import annotations

import numpy as np

from impactsense import loop
from impactsense.diagnose import Candidate, _param_ci, _param_se


def test_the_e_interval_is_the_pick_velocity_interval_through_both_exponents(monkeypatch):
    n, n_curve = 0.44, 0.34
    change = -4.0
    folds = [{"change_pct": change + d, "velocity_m_s": 800.0} for d in (-0.3, -0.1, 0.0, 0.1, 0.3)]
    cand = Candidate("wave_speed", None, {"change_pct": change, "velocity_m_s": 800.0}, 50.0, 1e-6, True, True,
                     folds)
    scale, curve = (1 + change / 100) ** (1 / n), (1 + change / 100) ** (1 / n_curve)
    monkeypatch.setattr(loop, "e_scale_scan", lambda *a, **k: {"e_scale": np.sqrt(scale * curve), "exponent": n,
                                                                 "scan_e_scale": scale, "first_guess": curve})
    (out,) = loop.size_plate_change(None, None, [cand], None)
    p = out.params
    lo, hi = _param_ci(cand, _param_se(cand))["change_pct"]
    assert p["e_scale_lo"] < p["e_scale"] < p["e_scale_hi"]
    # the low end through the curve's smaller exponent, the high end through the scan's
    np.testing.assert_allclose([p["e_scale_lo"], p["e_scale_hi"]],
                               [(1 + lo / 100) ** (1 / n_curve), (1 + hi / 100) ** (1 / n)], rtol=1e-9)
    assert p["e_scale_lo"] < curve < scale < p["e_scale_hi"]
    # another effect is passed through untouched
    other = Candidate("damping", None, {"extra_decay_per_s": 10.0}, 5.0, 0.01, True, True, [])
    assert loop.size_plate_change(None, None, [other], None)[0] is other
