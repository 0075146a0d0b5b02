"""The board's accuracy against the host's on the same held-out drops (issue 17: within 1.5x per axis).

Host: `impactsense train DATA` (the lab's recordings at the rig's rate, the trainer's case split), its reported
position (ImpactModel.predict: the twin's match where the model has a site map) on the held-out drops.
Board: the same model made again for the board as `impactsense export` does (board.models.retrain_for_board:
the same training drops as the board captures them, 4 x 50 kHz with the SAADC scan delays, and the twin's
board-rate site map), exported to node tables (--trees), and the firmware app on the emulated board over the
same held-out drops (board.scores.board_reports). Both are scored on the drops where both report a valid
position: MAE per axis (Eq. 36, x and y averaged), and the ratio board / host.

    python benchmarks/bench_board_accuracy.py [DATA] [--seed 0] [--trees 10] [--work DIR] [--json OUT]

The board's site map takes a few minutes the first time; it is cached in --work (default build/bench-cache/).
Exits 1 when the ratio is above the target.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGET_RATIO = 1.5


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default="bundled", help="session folder (default: bundled)")
    ap.add_argument("--seed", type=int, default=0, help="the trainer's split and forest seed")
    ap.add_argument("--trees", type=int, default=10, help="trees per localisation forest on the board")
    ap.add_argument("--work", type=Path, default=ROOT / "build" / "bench-cache" / "board-accuracy")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()

    from impactsense import api
    from impactsense.board.models import BOARD_SITE_MAP, retrain_for_board
    from impactsense.board.scores import board_reports
    from impactsense.export import export_models, firmware_models
    from impactsense.metrics import localisation_metrics
    from impactsense.modelfolder import read_card

    s = api.load_session(args.data)
    work = args.work / f"{Path(str(s.path)).name}-seed{args.seed}"
    work.mkdir(parents=True, exist_ok=True)
    host_dir = work / "host-model"
    host = api.train(s, out=host_dir, seed=args.seed)
    card, _ = read_card(host_dir)
    ids = card["split"]["test_recordings"]
    index = {int(r): k for k, r in enumerate(s.recording_id)}
    rows = np.asarray([index[int(r)] for r in ids], int)
    hp = api.predict(host, s.adc[rows])["xy_mm"]

    board_dir = retrain_for_board(host_dir, work / "board-model", 50000, site_map_cache=work.parent / BOARD_SITE_MAP)
    out = work / "export"
    export_models(board_dir, out, trees=args.trees, write_m2cgen=False)
    models, signal = firmware_models(out)
    got = board_reports(s.subset(rows), models, signal, 50000)
    bp = np.full((rows.size, 2), np.nan)
    for i, r in got.items():
        bp[i] = r["x_mm"], r["y_mm"]

    both = np.isfinite(hp).all(1) & np.isfinite(bp).all(1)
    truth = s.xy_mm[rows]
    h = localisation_metrics(truth[both], hp[both])
    b = localisation_metrics(truth[both], bp[both])
    ratio = b["mae_mm"] / h["mae_mm"]
    inner = s.rig.inner_region_mm
    from impactsense.metrics import inner_mask

    m = both & inner_mask(truth, inner)
    hi, bi = localisation_metrics(truth[m], hp[m]), localisation_metrics(truth[m], bp[m])
    summary = {"data": str(s.path), "held_out": int(rows.size), "scored": int(both.sum()),
               "host_valid": int(np.isfinite(hp).all(1).sum()), "board_valid": int(np.isfinite(bp).all(1).sum()),
               "host": h, "board": b, "ratio_mae": ratio, "inner": {"host": hi, "board": bi},
               "board_trees": args.trees, "twin": "twin" in card}
    print(f"{s.path}: {rows.size} held-out drops (seed {args.seed}), {both.sum()} with a valid position from both")
    print(f"  host  (rig's rate, {'twin' if summary['twin'] else 'forests'}): MAE per axis {h['mae_mm']:.2f} mm, "
          f"mean distance {h['euclid_mm']:.2f} mm (inner {hi['mae_mm']:.2f} mm)")
    print(f"  board (4 x 50 kHz, firmware app, {args.trees} trees): MAE per axis {b['mae_mm']:.2f} mm, "
          f"mean distance {b['euclid_mm']:.2f} mm (inner {bi['mae_mm']:.2f} mm)")
    ok = ratio <= TARGET_RATIO
    print(f"board / host MAE: {ratio:.2f}x (target <= {TARGET_RATIO}x: {'met' if ok else 'MISSED'})")
    if args.json:
        args.json.write_text(json.dumps(summary, indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
