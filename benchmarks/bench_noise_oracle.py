"""The white-noise row's floor (issue 16): an oracle retrain. The reference drops with the noise session's TRUE
white noise put in (the generator's own signal model, `loop_sessions.signal_change`: the level known exactly, no
diagnosis, no twin drops), K independent draws per drop, trained as bench_loop trains the loop's model (the plain
kind, 30 trees) with the rig's pick settings or with `loop.pick_settings` under the true level; scored on

- the noise session as made (the row's "after"),
- its own drops with other draws of the same noise (`--test-draws`: the row's expectation over the noise, not
  one draw),
- its own drops with the noise taken out (`loop_sessions.without_change`),

against the yardsticks: the reference model (the clean `ref`, the same kind) on the unchanged sessions (bench_loop's
"unchanged") and on the noise session's own drops without the noise. If the oracle's ratio is above 1.2 x, no
retrain on these drops with this pipeline reaches the row: the floor is the noise's cost on the picks.

    python3 benchmarks/bench_noise_oracle.py SESSIONS --out OUT [--draws 1,3] [--settings rig,loop]
        [--test-draws 2] [--trees 30] [--seed 12] [--name noise] [--unchanged same-1,same-2,same-3]
        [--training DIR,DIR] [--white C]

SESSIONS: benchmarks/loop_sessions.py's folder (ref, the unchanged sessions, the noise session, manifest.json).
--training: also these training sessions (e.g. bench_loop's OUT/noise-measured: the loop's own, with the twin's
drops at new positions), trained and scored the same way (row "draws" = their drop count). --white C: another
level in place of the session's: the "noise session" is then its own drops with C counts put in (one draw).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import loop_sessions  # noqa: E402


def put_in(adc: np.ndarray, truth: dict, rig, seed: int) -> np.ndarray:
    """Recorded counts with the generator's change added (its rig noise and rounding already in: white noise adds
    in power, so the total is the noise session's)."""
    a = loop_sessions.signal_change(np.asarray(adc, float) - rig.bias_counts, truth, rig, seed)
    return np.clip(np.rint(a + rig.bias_counts), 0, rig.adc_max).astype(np.uint16)


def oracle_training(ref, truth: dict, draws: int, seed: int, folder: Path):
    """`ref` x `draws`, each copy with its own draw of `truth`'s noise, written to `folder` and loaded."""
    from impactsense.data import load_session, write_session

    adc = np.concatenate([put_in(ref.adc, truth, ref.rig, seed + 1000 * (j + 1)) for j in range(draws)])
    reps = np.concatenate([ref.repetition + j * (int(ref.repetition.max()) + 1) for j in range(draws)])
    cols = [np.tile(ref.x_mm, draws), np.tile(ref.y_mm, draws), np.tile(ref.height_mm, draws)]
    return load_session(write_session(folder, ref.rig, *cols, adc, np.tile(ref.case_id, draws), reps))


def true_noise(truth: dict):
    from impactsense.diagnose import Candidate

    return [Candidate("noise", None, {"white_rms_counts": truth["params"]["noise_counts_rms"], "hum_counts": 0.0,
                                      "hum_hz": 50.0}, 0.0, 0.0, True, True, [])]


def main(argv=None) -> int:
    from impactsense.commands.retrain import score
    from impactsense.data import load_session
    from impactsense.loop import pick_settings
    from impactsense.models import ForestSettings
    from impactsense.workflow import train

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sessions")
    ap.add_argument("--out", required=True, help="folder for the oracle training sessions")
    ap.add_argument("--name", default="noise")
    ap.add_argument("--draws", default="1,3", help="noise draws per reference drop in the training data")
    ap.add_argument("--settings", default="rig,loop", help="rig: the rig's pick settings; loop: loop.pick_settings")
    ap.add_argument("--test-draws", type=int, default=2)
    ap.add_argument("--unchanged", default="same-1,same-2,same-3")
    ap.add_argument("--trees", type=int, default=30)
    ap.add_argument("--seed", type=int, default=12)
    ap.add_argument("--white", type=float, help="another white level (counts rms) on the session's own drops")
    ap.add_argument("--training", default="", help="also these training sessions (comma-separated folders)")
    args = ap.parse_args(argv)
    d, out = Path(args.sessions), Path(args.out)
    spec = json.loads((d / "manifest.json").read_text())["sessions"][args.name]
    truth = spec["truth"]
    ref, sess = load_session(d / "ref"), load_session(d / args.name)
    own_clean = dataclasses.replace(sess, adc=loop_sessions.without_change(sess.adc, spec, sess.rig))
    if args.white is not None:   # the same drops at another level
        truth = {**truth, "params": {**truth["params"], "noise_counts_rms": args.white}}
        sess = dataclasses.replace(sess, adc=put_in(own_clean.adc, truth, sess.rig, spec["seed"]))
    others = [dataclasses.replace(sess, adc=put_in(own_clean.adc, truth, sess.rig, 7000 + k))
              for k in range(args.test_draws)]
    settings = ForestSettings(n_estimators=args.trees, seed=args.seed)
    t0 = time.time()
    ref_model, _ = train(ref, None, 0.0, args.seed, None, settings=settings, site_map=None)
    unchanged = [score(load_session(d / n), ref_model)["mae_mm"] for n in args.unchanged.split(",") if n]
    base, own = float(np.mean(unchanged)), score(own_clean, ref_model)["mae_mm"]
    print(f"white noise {truth['params']['noise_counts_rms']} counts; reference model: unchanged "
          f"{' / '.join(f'{v:.2f}' for v in unchanged)} mean {base:.2f} mm; the noise session's own drops without the "
          f"noise {own:.2f}; with it {score(sess, ref_model)['mae_mm']:.2f} ({time.time() - t0:.0f} s)", flush=True)
    print("| draws | picks | chosen threshold, factor, blend | noise session (physics) | other draws of the noise "
          "| own drops clean | ratio to unchanged | ratio to own drops clean | s |\n|---|---|---|---|---|---|---|---|---|")
    runs = [(str(k), lambda k=k: oracle_training(ref, truth, k, args.seed, out / f"oracle-{args.name}-x{k}"))
            for k in (int(v) for v in args.draws.split(",") if v)]
    runs += [(f"{Path(p).name} ({{n}} drops)", lambda p=p: load_session(p)) for p in args.training.split(",") if p]
    for label, make in runs:
        training = make()
        label = label.format(n=len(training))
        for kind in args.settings.split(","):
            t0 = time.time()
            cfg = pick_settings(training, true_noise(truth), ref) if kind == "loop" else None
            model, _ = train(training, None, 0.0, args.seed, None, settings=settings, signal=cfg, site_map=None)
            s = score(sess, model)
            o = [score(x, model)["mae_mm"] for x in others]
            c = score(own_clean, model)["mae_mm"]
            sig = model.signal
            mean = float(np.mean([s["mae_mm"], *o]))
            print(f"| {label} | {kind} | {sig.onset_threshold_counts:g}, {sig.onset_noise_factor:g}, {sig.aic_blend:g} | "
                  f"{s['mae_mm']:.2f} ({s['physics_mae_mm']:.2f}) | {' / '.join(f'{v:.2f}' for v in o)} (all: "
                  f"{mean:.2f}) | {c:.2f} | {s['mae_mm'] / base:.2f} (all: {mean / base:.2f}) | "
                  f"{s['mae_mm'] / own:.2f} | {time.time() - t0:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
