"""A diagnosed move in the retrained model's rig, or not: loop sessions with a moved disc (loop_sessions.py),
each diagnosed against its `ref`, DATA_REF's recordings with the diagnosed effects put in (retrain's measured
training data, `loop.measured_training_session`) and, when given, a twin training session (bench_loop's
`<name>-twin` folder), trained with the declared rig and with the diagnosed one (`loop.diagnosed_rig`), scored
on the moved session (MAE and the physics localiser's MAE); and the reference model on the session and on its
`<name>-control` (loop_sessions --controls: the same drops without the move) when there is one.

    python3 benchmarks/bench_move_rig.py --sessions DIR --only move-10,move-55 [--twin-dir BENCH_OUT]
        [--trees 30] [--seeds 5,6]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    from impactsense.commands.retrain import score
    from impactsense.data import load_session
    from impactsense.diagnose import diagnose
    from impactsense.loop import diagnosed_rig, effect_dicts, measured_training_session
    from impactsense.models import ForestSettings
    from impactsense.workflow import train

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", required=True)
    ap.add_argument("--only", required=True, help="comma-separated moved sessions")
    ap.add_argument("--twin-dir", default=None, help="bench_loop's OUT (its <name>-twin training sessions)")
    ap.add_argument("--out", default="/tmp/impactsense-move-rig")
    ap.add_argument("--trees", type=int, default=30)
    ap.add_argument("--seeds", default="5,6")
    args = ap.parse_args(argv)
    S, out = Path(args.sessions), Path(args.out)
    seeds = [int(s) for s in args.seeds.split(",")]
    ref = load_session(S / "ref")
    truth = {k: v.get("truth") for k, v in json.loads((S / "manifest.json").read_text())["sessions"].items()}

    def fit(sess, seed):
        return train(sess, None, 0.0, seed, None, settings=ForestSettings(n_estimators=args.trees, seed=seed),
                     site_map=None)[0]

    def maes(sess, models):
        r = [score(sess, m) for m in models]
        v = [x["mae_mm"] for x in r]
        return " / ".join(f"{x:.2f}" for x in v) + f" (mean {np.mean(v):.2f}), phys {r[0]['physics_mae_mm']:.2f}"

    plain = [fit(ref, s) for s in seeds]
    for name in args.only.split(","):
        t0 = time.time()
        sess = load_session(S / name)
        _, det = diagnose(ref, sess, same=False)
        eff = effect_dicts(det["accepted"])
        t = truth[name]
        print(f"{name}: truth {t['effect']}[{t['sensor']}] {t['params']}; named "
              + (", ".join(f"{e['effect']}[{e['sensor']}] {e['params']}" for e in eff) or "none"), flush=True)
        print(f"  reference model on {name}: {maes(sess, plain)}", flush=True)
        control = S / f"{name}-control"
        if (control / "recordings.npz").exists():
            print(f"  reference model on {name}-control: {maes(load_session(control), plain)}", flush=True)
        if not any(e["effect"] == "sensor_position" for e in eff):
            continue
        runs = {"measured": measured_training_session(ref, det["accepted"], det["ref"], out / f"{name}-measured",
                                                      seeds[0])}
        twin = Path(args.twin_dir) / f"{name}-twin" if args.twin_dir else None
        if twin is not None and (twin / "recordings.npz").exists():
            runs["twin"] = load_session(twin)
        for kind, ts in runs.items():
            for label, rig in (("declared", ref.rig), ("diagnosed", diagnosed_rig(ref.rig, eff))):
                models = [fit(dataclasses.replace(ts, rig=rig), s) for s in seeds]
                print(f"  {kind}, {label} rig: {maes(sess, models)}", flush=True)
        print(f"  [{time.time() - t0:.0f} s]", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
