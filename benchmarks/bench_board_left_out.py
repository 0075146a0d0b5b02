"""A model that leaves a channel out (the core's channel_left_out, what `impactsense retrain` sets for a change
the models cannot absorb) on the emulated board against the host.

A board-rate model (no twin) is trained on every other drop of a session (board.models.train_board_models,
as `impactsense export` trains the board's models: all four channels, then the channel left out), exported
(export_models), and its held-out drops run through the firmware app (the emulated board, the exported tables)
clean, with the channel debonded and with it dead. The host model (ImpactModel.predict) runs on the board's own
captures. For each it prints the reports, MAE per axis, class accuracy and the channel the reports name, and
the board's distance from the host; the same tables with channel_left_out cleared are the reference.

    python benchmarks/bench_board_left_out.py [--data SESSION] [--channel 2] [--trees 10] [--four-channel]

--four-channel: the model is a four-channel one (what `impactsense train` + `export` ship): the channel is left
out only by the fault (dead: no onset; debonded: the channel check's flag); the board's three-sensor position
with the export's per-channel pairs (board.models.board_three_positions) against the same tables without them
(the plain three-sensor position), the clean rows the four-channel forests'.

Exits 1 when a drop gets no report, a report does not name the channel, a position is more than 0.051 mm from
the host's (the wire carries 0.1 mm steps) or more than 2 % of the classes differ.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None, help="session folder (default: the bundled session-1)")
    ap.add_argument("--channel", type=int, default=2, help="the channel left out (default 2)")
    ap.add_argument("--trees", type=int, default=10, help="trees per forest (default 10)")
    ap.add_argument("--four-channel", action="store_true",
                    help="a four-channel model: its three-sensor pairs against the plain three-sensor position")
    args = ap.parse_args()
    if args.four_channel:
        return four_channel(args)

    from impactsense.board.models import train_board_models
    from impactsense.board.scores import board_reports
    from impactsense.data import load_session
    from impactsense.export import export_models, firmware_models
    from impactsense.faults import FaultSpec, inject_session
    from impactsense.models import ForestSettings, ImpactModel

    c = args.channel
    s = load_session(args.data)
    sub = s.subset(np.arange(0, len(s), 2))
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        d = train_board_models(sub, Path(tmp) / "model", settings=ForestSettings(n_estimators=args.trees),
                               channel_left_out=[int(k == c) for k in range(4)])
        summary = export_models(d, Path(tmp) / "export", write_m2cgen=False)
        card = json.loads((d / "model_card.json").read_text())
        model = ImpactModel.load(d)
        models, signal = firmware_models(Path(tmp) / "export")
        test = sub.subset(np.flatnonzero(np.isin(sub.recording_id, card["test_recording_ids"])))
        print(f"{s.name}: {len(sub)} drops, {len(test)} held out; channel {c} left out; "
              f"three-channel tables {summary['table_bytes'].get('three_channel', 0)} B")
        print(f"{'drops':<10} {'tables':<16} {'reported':>9} {'MAE mm':>7} {'class':>6} {'named':>6}  board vs host")
        four = {**signal, "channel_left_out": [0, 0, 0, 0]}
        for name, fault in (("clean", None), ("debonded", FaultSpec(debond=c, debond_hz=4000, seed=1)),
                            ("dead", FaultSpec(dead_channel=c, noise=1, seed=1))):
            sess = test if fault is None else inject_session(test, fault)
            for label, sig in ((f"channel {c} out", signal), ("four channels", four)):
                got = board_reports(sess, models, sig)
                line, rows, named, dist, same = score_row(name, label, sess, got, model, sig if sig is signal else None)
                if sig is signal:
                    ok &= rows.size == len(sess) and named == [c] and dist <= 0.051 and same >= 0.98
                print(line, flush=True)
    print(f"RESULT the board's answers with channel {c} left out {'are' if ok else 'are NOT'} the host's")
    return 0 if ok else 1


def four_channel(args) -> int:
    """The --four-channel run: a four-channel board model, its held-out drops clean / channel debonded / dead on
    the emulated board with the export's three-sensor pairs and without them, and the host's answers."""
    from impactsense.board.models import train_board_models
    from impactsense.board.scores import board_reports
    from impactsense.data import load_session
    from impactsense.export import export_models, firmware_models
    from impactsense.faults import FaultSpec, inject_session
    from impactsense.models import ForestSettings, ImpactModel

    c = args.channel
    s = load_session(args.data)
    sub = s.subset(np.arange(0, len(s), 2))
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        d = train_board_models(sub, Path(tmp) / "model", settings=ForestSettings(n_estimators=args.trees))
        summary = export_models(d, Path(tmp) / "export", write_m2cgen=False)
        card = json.loads((d / "model_card.json").read_text())
        model = ImpactModel.load(d)
        test = sub.subset(np.flatnonzero(np.isin(sub.recording_id, card["test_recording_ids"])))
        rec = (card.get("board_three_position") or {}).get("channels", {})
        print(f"{s.name}: {len(sub)} drops, {len(test)} held out; four-channel model; three-sensor pairs "
              f"{summary['table_bytes'].get('three_position', 0)} B, {card.get('board_three_position', {}).get('stages')}"
              f" stages; out of fold per channel: "
              + ", ".join(f"{k} {v.get('out_of_fold_mae_mm')} kept {v['kept']}" for k, v in sorted(rec.items())))
        print(f"{'drops':<10} {'tables':<16} {'reported':>9} {'MAE mm':>7} {'class':>6} {'named':>6}  board vs host")
        for name, fault in (("clean", None), ("debonded", FaultSpec(debond=c, debond_hz=4000, seed=1)),
                            ("dead", FaultSpec(dead_channel=c, noise=1, seed=1))):
            sess = test if fault is None else inject_session(test, fault)
            for label, with_pairs in (("with pairs", True), ("plain", False)):
                models, signal = firmware_models(Path(tmp) / "export", three_position=with_pairs)
                got = board_reports(sess, models, signal)
                line, rows, _, dist, same = score_row(name, label, sess, got, model, signal if with_pairs else None)
                if with_pairs:
                    ok &= rows.size == len(sess) and dist <= 0.051 and same >= 0.98
                print(line, flush=True)
    print(f"RESULT the board's answers {'are' if ok else 'are NOT'} the host's")
    return 0 if ok else 1


def score_row(name, label, sess, got, model, host_signal=None):
    """One printed row: the board's reports `got` on `sess` (count, MAE per axis, class accuracy, the channels
    they name); with host_signal, the host model on the board's own captures beside them. Returns (line, rows,
    named, max |board - host| mm, share of classes the same); the last two NaN without host_signal."""
    from impactsense.board.capture import board_captures
    from impactsense.models import impact_energy_j
    from impactsense.pipeline import featurize

    rows = np.asarray(sorted(got), int)
    xy = np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in rows]).reshape(-1, 2)
    cls = np.array([got[i]["energy_class"] for i in rows], int)
    label_true = impact_energy_j(sess.height_mm[rows], sess.rig.ball_mass_g) >= model.energy_threshold_j
    named = sorted({int(got[i]["left_out"]) for i in rows})
    mae = float(np.mean(np.abs(xy - sess.xy_mm[rows]))) if rows.size else float("nan")
    line = (f"{name:<10} {label:<16} {rows.size:>4}/{len(sess):<4} {mae:7.2f} "
            f"{np.mean(cls == label_true) if rows.size else float('nan'):6.3f} {str(named):>6}")
    dist = same = float("nan")
    if host_signal is not None:
        caps, r2, s2 = board_captures(sess, 50000, host_signal)
        pred = model.predict(featurize(caps, s2))
        have = np.isin(r2, rows)
        bxy = np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in r2[have]]).reshape(-1, 2)
        bc = np.array([got[i]["energy_class"] for i in r2[have]], int)
        dist = float(np.max(np.abs(bxy - pred["xy_mm"][have]))) if have.any() else float("nan")
        same = float(np.mean(bc == pred["energy_class"][have])) if have.any() else float("nan")
        line += (f"  host MAE {np.mean(np.abs(pred['xy_mm'] - sess.xy_mm[r2])):.2f} mm, "
                 f"max |board - host| {dist:.3f} mm, class the same {same:.3f}")
    return line, rows, named, dist, same


if __name__ == "__main__":
    sys.exit(main())
