"""How each octave band rings out on a rig and on its twin's virtual drops (the twin's loss factor, issue 15).

    python3 benchmarks/bench_twin_decay.py DATA [V ...] [--drops 40] [--calibration CAL.json]

Per session folder (the rig's DATA, then any virtual sets V, e.g. `simulate-dataset --calibration CAL.json` output)
the energy decay rate (1/s) per octave band and broadband, by calibrate's own reading (`calibration.loss.
decay_by_band`: every k-th drop so that --drops are read, the median over their channels). A twin whose bands
decay as the rig's reads the same row; D_s alone gives a flat row. With --calibration: the loss factor rule on
that CAL.json's four drops (`calibration.loss.twin_loss`, what calibrate writes as `twin_loss`). A diagnosis: exits 0.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sessions", nargs="+")
    ap.add_argument("--drops", type=int, default=40)
    ap.add_argument("--calibration", type=Path, default=None)
    a = ap.parse_args()
    from impactsense.calibration.loss import decay_by_band, twin_loss
    from impactsense.data import load_session

    for path in a.sessions:
        s = load_session(path)
        rows = np.arange(0, len(s.case_id), max(1, len(s.case_id) // a.drops))[:a.drops]
        d = decay_by_band(s.adc[rows], float(s.rig.bias_counts), float(s.rig.fs_hz))
        bands = " ".join(f"{lo / 1e3:.0f}-{hi / 1e3:.0f} kHz {r:6.0f}" for (lo, hi), r in zip(d["bands_hz"], d["rate_per_s"]))
        print(f"{path}: {bands} | broadband {d['broadband_rate_per_s']:.0f} 1/s ({len(rows)} drops)")
    if a.calibration:
        cal = json.loads(a.calibration.read_text())
        s = load_session(cal["data"])
        loss = twin_loss(s, [r for rs in cal["drops"]["recording_ids"] for r in rs],
                         float(cal.get("twin_loss", {}).get("damping_stage_per_s", cal["sim_params"]["damping_per_s"])))
        print(f"loss factor rule on {a.calibration}'s drops: {loss['why']}; loss_factor {loss['loss_factor']:.5f} "
              f"(line's slope {loss.get('slope_loss_factor', float('nan')):.5f} +- "
              f"{loss.get('loss_factor_se', float('nan')):.5f}, intercept {loss.get('intercept_per_s', float('nan')):.0f}"
              f" 1/s), D_s {loss['damping_stage_per_s']:.0f} -> {loss['damping_per_s']:.0f} 1/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
