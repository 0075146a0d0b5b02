"""Self-calibration of a model's channel constants from a new session's own picks, without labels
(`benchmarks/selfcal_study.py`, a study kept out of the package: not used by `retrain`), on the loop's sessions (benchmarks/loop_sessions.py): per session the offsets
(centred, us, with their jackknife standard errors), whether the rule applies them, and the reference model's
MAE before and with them (labels used only to score).

    python3 benchmarks/bench_self_calibration.py --sessions SESSIONS [--trees 60] [--seed 0] [--only NAME,NAME]

The reference model is bench_loop's (all of `ref`, no site map). Target (exit 1 on a miss): no offset applied on
an unchanged session (the controls' MAE stays theirs).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None) -> int:
    import argparse


    from bench_loop import train_score
    from impactsense.commands.retrain import score
    from impactsense.data import load_session
    from selfcal_study import recentred, self_calibrate

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", required=True, help="a loop_sessions.py folder (with ref/ and manifest.json)")
    ap.add_argument("--trees", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", default=None)
    args = ap.parse_args(argv)
    root = Path(args.sessions)
    man = json.loads((root / "manifest.json").read_text())
    ref = load_session(root / "ref")
    model, _ = train_score(ref, args.trees, args.seed)
    only = set(args.only.split(",")) if args.only else None
    print("| session | truth | offsets us (se) | combinations kept | applied | "
          "MAE before -> with the offsets put in (applied or not) |")
    print("|---|---|---|---|---|---|")
    false_alarms = 0
    for name, spec in man["sessions"].items():
        if name == "ref" or (only and name not in only):
            continue
        sess = load_session(root / name)
        off = self_calibrate(model, ref.adc, sess.adc)
        before = score(sess, model)["mae_mm"]
        with_offsets = score(sess, recentred(model, off))["mae_mm"]
        t = spec.get("truth")
        truth = "none" if t is None else f"{t['effect']}[{t['sensor']}]"
        false_alarms += t is None and off.applied
        offs = ", ".join(f"{o:+.2f} ({s:.2f})" for o, s in zip(off.offset_us, off.se_us))
        print(f"| {name} | {truth} | {offs} | {off.n_modes} | {'yes' if off.applied else 'no'} | "
              f"{before:.2f} -> {with_offsets:.2f} |", flush=True)
    print(f"\nunchanged sessions with offsets applied: {false_alarms} (target 0)")
    return 1 if false_alarms else 0


if __name__ == "__main__":
    sys.exit(main())
