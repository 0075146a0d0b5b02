"""Where a zero-shot chain's energy class is lost near the boundary: the classifier's cut against the session's gap,
and the twin's height estimate at the heights either side of it (issue 15).

    python3 benchmarks/bench_zeroshot_class_cut.py DATA --model M [M ...]

M are chain models (`train V --out M --test-fraction 0 --site-map auto`, as bench_zeroshot_rigs.py makes them)
for the session DATA. Per model, on every drop but its calibration drops: the class accuracy (labels m g h >= the
card's energy_threshold_j, as evaluate scores them); the cut the classifier puts on the twin's log10-height estimate
(the virtual drops' bagged stumps, found by scanning them) against the middle of the session's gap between drop
heights (the card's energy_class_boundary_j); the misses per height; and, at the session's two heights either side
of the gap, the estimate's mean bias (log10 h) and its scatter. A cut that drifts below the gap's middle, or a bias
that grows at the low side's height, moves that height's drops into the high class. A diagnosis: exits 0.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data")
    ap.add_argument("--model", nargs="+", required=True)
    a = ap.parse_args()
    from impactsense.calibration_drops import calibration_rows
    from impactsense.data import load_session
    from impactsense.models import ImpactModel, impact_energy_j

    s = load_session(a.data)
    g = 9.80665 * s.rig.ball_mass_g * 1e-3
    for path in a.model:
        m = ImpactModel.load(path)
        cal = m.card.get("calibration")
        keep = np.ones(len(s.case_id), bool)
        if isinstance(cal, str):
            keep[calibration_rows(s, json.loads(Path(cal).read_text()))] = False
        out = m.predict(m.featurize(s.adc[keep]))
        h = np.asarray(s.height_mm, float)[keep]
        label = (impact_energy_j(h, s.rig.ball_mass_g) >= m.energy_threshold_j).astype(int)
        cls = np.asarray(out["energy_class"])
        ok = cls >= 0
        grid = np.linspace(np.log10(h.min()) - 0.1, np.log10(h.max()) + 0.1, 4001)
        step = m.forest_energy.predict(grid[:, None])
        cut = 10 ** grid[np.argmax(step != step[0])]
        gap = m.card.get("energy_class_boundary_j")
        lo, hi = h[h * g * 1e-3 < m.energy_threshold_j].max(), h[h * g * 1e-3 >= m.energy_threshold_j].min()
        miss = ok & (cls != label)
        u, c = np.unique(h[miss], return_counts=True)
        print(f"{path}: class {np.mean(cls[ok] == label[ok]):.4f} ({ok.sum()} drops); cut {cut:.1f} mm, session's gap "
              f"{lo:.0f} | {hi:.0f} mm, its middle {gap / g * 1e3 if gap else float('nan'):.1f} mm")
        print("   misses by height (mm: n): " + ", ".join(f"{x:.0f}: {n}" for x, n in zip(u, c)))
        est = np.log10(np.asarray(out["height_mm"], float))
        for side in (lo, hi):
            b = (h == side) & np.isfinite(est)
            e = est[b] - np.log10(h[b])
            print(f"   {side:.0f} mm: n {b.sum()}, estimate bias {e.mean():+.4f} log10 h, scatter {e.std():.4f}, "
                  f"classed high {np.mean(cls[b] == 1):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
