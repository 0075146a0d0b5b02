"""The channel check on the emulated board against the host, on the fault rows of bench_faults.py.

For each session (the bundled session-1 by default; --data one or more session folders) a board-rate model
without a twin is trained on its default split (board.models.train_board_models, as `impactsense export` trains
the board's models; no site map, so the channel check is in its card) and exported (export_models); its held-out
drops run through the firmware app (the emulated board, the exported tables) clean, with one channel debonded
(x0.4, 3-5 kHz first-order low-pass; --draws draws, the channel (d + 2) % 4 as bench_faults) and with one dead
(channel d % 4, noise 1). The host's model (ImpactModel.predict) runs on the board's own captures. Printed per row:
drops reported, the share whose report names the faulted channel (flag), the share naming another one (wrong),
the share where the board's named channel differs from the host's (board != host) and the board's MAE per axis.

    python benchmarks/bench_board_check.py [--data SESSION ...] [--draws 2] [--trees 10] [--json OUT]

Targets (exit 1 on a miss): debonded flag >= 0.95, wrong 0 on every row, clean unflagged, dead flag 1.00 (the
core's dead-channel path), the board naming the host's channel on every drop, a flagged drop's position within the
wire's 0.05 mm of the host's (xy-host: the largest gap).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchlib import targets_exit_code, write_json


XY_TOLERANCE_MM = 0.051   # the report's 0.1 mm steps


def rows_for(draws: int):
    from impactsense.faults import FaultSpec

    yield "clean", FaultSpec(seed=0), -1
    for d in range(draws):
        yield f"debonded (draw {d})", FaultSpec(debond=(d + 2) % 4, seed=d), (d + 2) % 4
    for d in range(draws):
        yield f"dead (draw {d})", FaultSpec(dead_channel=d % 4, noise=1, seed=d), d % 4


def score_row(model_dir, out, session, bad: int) -> dict:
    from impactsense.board.capture import board_captures
    from impactsense.board.scores import board_reports
    from impactsense.export import firmware_models
    from impactsense.models import ImpactModel
    from impactsense.pipeline import featurize

    models, signal = firmware_models(out)
    got = board_reports(session, models, signal)
    caps, rows, sig = board_captures(session, 50000, signal)
    pred = ImpactModel.load(model_dir).predict(featurize(caps, sig))
    host_bad = np.asarray(pred["bad_channel"], int) if "bad_channel" in pred else np.full(len(rows), -1)
    host_bad = np.where(pred["three_channel"], np.where(host_bad >= 0, host_bad, -2), host_bad)
    named = np.array([got[i]["left_out"] if i in got else -3 for i in rows])
    board_dead = np.array([bool(got[i]["dead"]) if i in got else False for i in rows])
    xy = np.array([[got[i]["x_mm"], got[i]["y_mm"]] if i in got else [np.nan, np.nan] for i in rows])
    err = np.abs(xy - session.xy_mm[rows])
    # the flagged rows' positions, board against host (the wire carries 0.1 mm steps)
    flagged = (named >= 0) & (named == host_bad)
    gap = np.abs(xy[flagged] - np.asarray(pred["xy_mm"], float)[flagged])
    # the host's name for a dead channel's row (no onset) is its three-sensor path's; compare the check's flags only
    check_rows = ~board_dead
    return {"n": len(session), "reported": len(got),
            "flag": float(np.mean(named == bad)) if bad >= 0 else float(np.mean(named >= 0)),
            "wrong": float(np.mean((named >= 0) & (named != bad))),
            "board_vs_host": float(np.mean(named[check_rows] != np.where(host_bad >= 0, host_bad, -1)[check_rows]))
            if check_rows.any() else 0.0,
            "mae_mm": float(np.nanmean(err)),
            "xy_vs_host_mm": float(np.max(gap)) if gap.size else 0.0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", nargs="*", default=[None], help="session folders (default: the bundled session-1)")
    ap.add_argument("--draws", type=int, default=2)
    ap.add_argument("--trees", type=int, default=10)
    ap.add_argument("--json", default=None)
    ap.add_argument("--no-targets", action="store_true")
    args = ap.parse_args(argv)

    from impactsense.board.models import train_board_models
    from impactsense.data import load_session
    from impactsense.export import export_models
    from impactsense.faults import inject_session
    from impactsense.models import ForestSettings

    t0, out_rows, misses = time.time(), {}, []
    print(f"{'session / fault':<40} {'drops':>5} {'rep':>5} {'flag':>5} {'wrong':>5} {'!=host':>6} {'MAE mm':>7} "
          f"{'xy-host':>7}")
    for data in args.data:
        sess = load_session(data)
        with tempfile.TemporaryDirectory() as tmp:
            d = train_board_models(sess, Path(tmp) / "model", settings=ForestSettings(n_estimators=args.trees, seed=0))
            summary = export_models(d, Path(tmp) / "out", write_m2cgen=False)
            if "channel_check" not in summary["table_bytes"]:
                misses.append(f"{sess.name}: the export carries no channel check")
            import json
            card = json.loads((d / "model_card.json").read_text())
            test = sess.subset(np.flatnonzero(np.isin(sess.recording_id, card["test_recording_ids"])))
            for name, spec, bad in rows_for(args.draws):
                v = score_row(d, Path(tmp) / "out", inject_session(test, spec) if spec.active() else test, bad)
                label = f"{sess.name}: {name}"
                out_rows[label] = v
                print(f"{label:<40} {v['n']:5d} {v['reported']:5d} {v['flag']:5.2f} {v['wrong']:5.2f} "
                      f"{v['board_vs_host']:6.2f} {v['mae_mm']:7.2f} {v['xy_vs_host_mm']:7.3f}", flush=True)
                if name.startswith("debonded") and not v["flag"] >= 0.95:
                    misses.append(f"{label}: flag {v['flag']:.2f} < 0.95")
                if name.startswith("dead") and not v["flag"] >= 1.0:
                    misses.append(f"{label}: flag {v['flag']:.2f} < 1.00")
                if name == "clean" and v["flag"] > 0:
                    misses.append(f"{label}: flagged {v['flag']:.2f}")
                if v["wrong"] > 0:
                    misses.append(f"{label}: wrong {v['wrong']:.2f}")
                if v["xy_vs_host_mm"] > XY_TOLERANCE_MM:
                    misses.append(f"{label}: a flagged drop's position {v['xy_vs_host_mm']:.3f} mm from the host's")
                if v["board_vs_host"] > 0:
                    misses.append(f"{label}: board != host on {v['board_vs_host']:.3f}")
    write_json(args.json, out_rows)
    return targets_exit_code(misses, args.no_targets, t0)


if __name__ == "__main__":
    sys.exit(main())
