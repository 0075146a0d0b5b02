"""`calibrate --disc-bond fit`: how much plate the discs stiffen (SimParams `disc_stiffness_scale`; 1 = a
perfectly bonded ceramic, < 1 a compliant bond line), fitted to the calibration drops' band group delays.

The twin with perfectly bonded discs stiffens too much plate under them (docs/findings.md: the disc's
mechanical footprint). Each candidate scale is scored as `plate_nu.choose_support` scores a support: every
accepted repetition's position fitted at the current E, nu and D_s, then chi^2 / dof of the group delays
against the rig's noise. The search: a coarse scan (`COARSE`), then parabolas through the best evaluated scale
and its evaluated neighbours (a few more FEM evaluations), within `BOUNDS`.
"""

from __future__ import annotations

import time

import numpy as np

from . import fem, plate_nu
from .problem import DropsAndTwin

FIELD = fem.DISC_BOND_FIELD
BOUNDS = (0.2, 1.0)
COARSE = (0.25, 0.5, 0.75, 1.0)
REFINE = 3              # parabola steps after the coarse scan
XTOL = 0.01             # a parabola's vertex this close to an evaluated scale ends the search


def search(chi2_dof, bounds=BOUNDS, coarse=COARSE, refine=REFINE, xtol=XTOL) -> tuple[float, dict]:
    """The scale in `bounds` minimising chi2_dof(s): the `coarse` scan, then up to `refine` steps to the vertex
    of the parabola through the best evaluated scale and its nearest evaluated neighbours (one-sided at an
    edge of the scan), clipped to the bracket they span (or to `bounds` at an edge). Returns the best evaluated
    scale and every evaluation {scale: chi2_dof}."""
    lo, hi = float(bounds[0]), float(bounds[1])
    seen: dict[float, float] = {}

    def ev(s):
        s = round(float(np.clip(s, lo, hi)), 4)
        if s not in seen:
            seen[s] = float(chi2_dof(s))
        return seen[s]

    for s in coarse:
        ev(s)
    for _ in range(refine):
        xs = sorted(seen)
        i = int(np.argmin([seen[s] for s in xs]))
        j = min(max(i, 1), len(xs) - 2)               # the three points around the best (shifted at an edge)
        pts = xs[j - 1:j + 2]
        if len(pts) < 3:
            break
        a, b, _ = np.polyfit(pts, [seen[s] for s in pts], 2)
        left = xs[i - 1] if i > 0 else lo
        right = xs[i + 1] if i < len(xs) - 1 else hi
        v = -b / (2 * a) if a > 0 else (left if seen[pts[0]] < seen[pts[-1]] else right)
        v = float(np.clip(v, left, right))
        if min(abs(v - s) for s in xs) < xtol:
            break
        ev(v)
    best = min(seen, key=seen.get)
    return best, dict(sorted(seen.items()))


def fit(drops: DropsAndTwin, params: dict, *, bounds=BOUNDS, coarse=COARSE, refine=REFINE, progress=None) -> dict:
    """CAL.json's `disc_bond` block: the fitted scale, chi^2 / dof per evaluated scale (each with every
    repetition's position fitted at params' E, nu, D_s), chi^2 / dof at 1 (the bonded disc) and at the fit,
    and the seconds it took. progress(): called after each evaluated scale (at most len(coarse) + refine)."""
    t0 = time.perf_counter()
    setup = plate_nu.GroupDelaySetup.build(drops, params)
    rows = {}

    def chi2_dof(s):
        rows[s] = plate_nu.score_candidate(drops, setup, params, {FIELD: s})
        if progress is not None:
            progress()
        return rows[s]["chi2_dof"]

    best, table = search(chi2_dof, bounds, coarse, refine)
    at_one = table.get(1.0)
    return {"scale": best, "chi2_dof": {f"{s:.4g}": v for s, v in table.items()},
            "chi2_dof_bonded": at_one, "chi2_dof_fit": table[best],
            "position_shift_rms_mm": rows[best]["position_shift_rms_mm"], "rms_us_fit": rows[best]["rms_us"],
            "bounds": list(bounds), "repetitions": int(setup.per_rep.shape[0]),
            "seconds": round(time.perf_counter() - t0, 3),
            "method": f"SimParams {FIELD} in [{bounds[0]:g}, {bounds[1]:g}]: every accepted repetition's position "
                      "fitted to its band group delays at the plate's E, nu and D_s, chi^2 / dof against the rig's "
                      f"noise; scan {', '.join(f'{s:g}' for s in coarse)}, then up to {refine} parabola steps"}
