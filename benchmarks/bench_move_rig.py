"""A diagnosed move in the retrained model's rig, or not: loop sessions with a moved disc (loop_sessions.py),
each diagnosed against its `ref`, DATA_REF's recordings with the diagnosed effects put in (retrain's measured
training data, `loop.measured_training_session`) and, when given, a twin training session (bench_loop's
`<name>-twin` folder), trained with the declared rig and with the diagnosed one (`loop.diagnosed_rig`), scored
on the moved session (MAE and the physics localiser's MAE); and the reference model on the session and on its
`<name>-control` (loop_sessions --controls: the same drops without the move) when there is one.

With `--twin` (and the loop_sessions options the sessions were made with, e.g. `--rig RIG --calibration rig`):
the twin path (DATA_REF's drops simulated by the corrected twin, the disc moved in the FEM:
`loop.twin_training_session`), kept in OUT/<name>-twin, the twin with no effect (OUT/twin-none, simulated once)
on the control (the twin path's own yardstick), and the one `impactsense retrain` with a twin keeps (of the
measured and the twin path, the lower MAE on the session: `commands.retrain.training_session`'s choice, here on
the forest seeds' mean). Each after is printed with its ratio to the reference model's MAE on the control.

    python3 benchmarks/bench_move_rig.py --sessions DIR --only move-10,move-55 [--twin-dir BENCH_OUT]
        [--twin [loop_sessions options]] [--trees 30] [--seeds 5,6] [--no-measured] [--declared-only]
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
    from impactsense.loop import diagnosed_rig, effect_dicts, measured_training_session, twin_training_session
    from impactsense.models import ForestSettings
    from impactsense.workflow import train

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", required=True)
    ap.add_argument("--only", required=True, help="comma-separated moved sessions")
    ap.add_argument("--twin-dir", default=None, help="bench_loop's OUT (its <name>-twin training sessions)")
    ap.add_argument("--out", default="/tmp/impactsense-move-rig")
    ap.add_argument("--trees", type=int, default=30)
    ap.add_argument("--seeds", default="5,6")
    ap.add_argument("--twin", action="store_true", help="also the twin path with the diagnosed move (simulated)")
    ap.add_argument("--no-measured", action="store_true", help="skip the measured path")
    ap.add_argument("--declared-only", action="store_true", help="train with the declared rig only")
    args, gen = ap.parse_known_args(argv)
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
    sim = twin_sim(S, ref, gen) if args.twin else None
    unchanged = None
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
        ctrl = load_session(control) if (control / "recordings.npz").exists() else None
        c_mae = None
        if ctrl is not None:
            c_mae = float(np.mean([score(ctrl, m)["mae_mm"] for m in plain]))
            print(f"  reference model on {name}-control: {maes(ctrl, plain)}", flush=True)
        if not any(e["effect"] == "sensor_position" for e in eff):
            continue
        runs = {} if args.no_measured else {
            "measured": measured_training_session(ref, det["accepted"], det["ref"], out / f"{name}-measured",
                                                  seeds[0])}
        twin = Path(args.twin_dir) / f"{name}-twin" if args.twin_dir else None
        if twin is not None and (twin / "recordings.npz").exists():
            runs["twin"] = load_session(twin)
        if sim is not None:
            slow = det["ref"].slowness_us_per_mm
            if unchanged is None and ctrl is not None:
                none = cached(out / "twin-none", lambda f: twin_training_session(ref, sim, [], f, slow, seeds[0], 1))
                unchanged = [fit(none, s) for s in seeds]
            runs["twin path"] = cached(out / f"{name}-twin", lambda f: twin_training_session(
                ref, sim, eff, f, slow, seeds[0], 1))
            if unchanged is not None:
                print(f"  twin with no effect on {name}-control: {maes(ctrl, unchanged)}", flush=True)
        declared = {}
        for kind, ts in runs.items():
            for label, rig in (("declared", ref.rig), ("diagnosed", diagnosed_rig(ref.rig, eff)))[
                    : 1 if args.declared_only else 2]:
                models = [fit(dataclasses.replace(ts, rig=rig), s) for s in seeds]
                got = float(np.mean([score(sess, m)["mae_mm"] for m in models]))
                declared.setdefault(kind, got)
                ratio = "" if c_mae is None else f"; / control {got / c_mae:.2f} x"
                print(f"  {kind}, {label} rig: {maes(sess, models)}{ratio}", flush=True)
        if {"measured", "twin path"} <= set(declared):   # retrain with a twin: the one placing DATA_NEW better
            kept = min(("measured", "twin path"), key=lambda k: declared[k])
            ratio = "" if c_mae is None else f" ({declared[kept] / c_mae:.2f} x the control)"
            print(f"  retrain with a twin keeps: {kept}, {declared[kept]:.2f}{ratio}", flush=True)
        print(f"  [{time.time() - t0:.0f} s]", flush=True)
    return 0


def twin_sim(S: Path, ref, gen: list):
    """The sessions' twin (loop_sessions' generator at its mesh and window), from their manifest's seed and the
    loop_sessions options `gen` they were made with."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import loop_sessions

    seed = json.loads((S / "manifest.json").read_text())["settings"]["seed"]
    g = loop_sessions.parse(["--out", str(S), "--seed", str(seed), "--workers", "1"] + gen)
    return loop_sessions.twin_params(loop_sessions.base_params(g, ref.rig), g)


def cached(folder: Path, make):
    """A training session kept in `folder` (loaded when its recordings are there; else made by make(folder))."""
    from impactsense.data import load_session

    return load_session(folder) if (folder / "recordings.npz").exists() else make(folder)


if __name__ == "__main__":
    sys.exit(main())
