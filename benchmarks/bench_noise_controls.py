"""A raised white noise floor on more than one draw of positions: the loop's retrained model scored on the noise
session and on every unchanged session with the diagnosed noise put in (a study for issue 16's white-noise row).

    python3 benchmarks/bench_noise_controls.py --sessions SESSIONS [--out OUT] [--trees 60] [--seed 0] [--draws 3]
        [--no-twin] [the loop_sessions.py options SESSIONS was made with: --rig RIG --calibration CAL|rig ...]

SESSIONS is benchmarks/loop_sessions.py's output (its `ref`, `noise` and unchanged sessions; reused, not rebuilt;
every white-noise session in it is scored, `noise-<C>` too). The twin the retrain adds drops from is the one the
sessions were made with (as bench_loop's: the generator's own FEM); --no-twin trains without it (the measured
drops alone, as `retrain` without a twin).
The noise session is one draw of 40 positions, so its "after" against 1.2 x the unchanged MAE is one sample of
the ratio. Here the diagnosed noise effect (its own signal model, `impactsense.effects.apply`) is also put into
each unchanged session's recordings, and the same retrained model (as `impactsense retrain` and bench_loop train
it: `loop.measured_training_session` with the twin's drops at new positions, `loop.pick_settings`) scores each; the clean columns are the reference
model on the unchanged sessions as they are. Prints the per-session MAE and ratio to the clean mean; no target
of its own (exit 0; bench_loop holds the issue's target).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import loop_sessions  # noqa: E402


def sessions_twin(sessions: Path, gen: list[str]):
    """The twin SESSIONS were made with (loop_sessions' settings must be the manifest's: same rig and calibration)."""
    from impactsense.data import load_session

    gen_args = loop_sessions.parse(["--out", str(sessions)] + gen)
    rig = load_session(gen_args.rig).rig
    man = json.loads((sessions / "manifest.json").read_text())
    if loop_sessions.settings_key(gen_args, rig) != man.get("settings"):
        raise SystemExit(f"{sessions}: made with other loop_sessions.py settings than {gen or 'the defaults'} "
                         "(give the --rig / --calibration it was made with)")
    return loop_sessions.twin_params(loop_sessions.base_params(gen_args, rig), gen_args)


def run(args) -> dict:
    from impactsense.commands.retrain import augment, score
    from impactsense.data import load_session
    from impactsense.diagnose import diagnose
    from impactsense.loop import measured_training_session, pick_settings
    from impactsense.models import ForestSettings
    from impactsense.workflow import train

    sessions = Path(args.sessions)
    man = json.loads((sessions / "manifest.json").read_text())
    unchanged = sorted(n for n, s in man["sessions"].items() if s.get("kind") == "none" and n != "ref")
    noisy = [n for n, s in man["sessions"].items() if (s.get("truth") or {}).get("effect") == "noise"
             and "noise_counts_rms" in s["truth"]["params"]]
    if not unchanged or not noisy:
        raise SystemExit(f"{sessions}: needs unchanged sessions and a white-noise session (loop_sessions.py)")
    ref = load_session(sessions / "ref")
    twin = None if args.no_twin else sessions_twin(sessions, args.gen)
    settings = ForestSettings(n_estimators=args.trees, seed=args.seed)
    ref_model, _ = train(ref, None, 0.0, args.seed, None, settings=settings, site_map=None)
    out = {"rows": []}
    for name in noisy:
        sess = load_session(sessions / name)
        res, det = diagnose(ref, sess, same=False)
        accepted = det["accepted"]
        named = [(c.effect, c.sensor, {k: round(float(v), 3) for k, v in c.params.items()}) for c in accepted]
        m_sess = measured_training_session(ref, accepted, det["ref"], Path(args.out) / f"{name}-measured", args.seed,
                                           twin=twin)
        cfg = pick_settings(m_sess, accepted, ref)
        model, _ = train(m_sess, None, 0.0, args.seed, None, settings=settings, signal=cfg, site_map=None)
        own = score(sess, model)["mae_mm"]
        rows = []
        for k, u in enumerate(unchanged):
            clean = load_session(sessions / u)
            draws = [score(replace(clean, adc=augment(clean, accepted, det["ref"], args.seed + 100 + 10 * k + j)),
                           model)["mae_mm"] for j in range(args.draws)]
            rows.append({"session": u, "clean": score(clean, ref_model)["mae_mm"], "with_noise": float(np.mean(draws)),
                         "draws": draws})
        out["rows"].append({"session": name, "named": named, "truth": man["sessions"][name]["truth"]["params"],
                            "after": own, "controls": rows, "training_drops": len(m_sess),
                            "training_positions": int(len(np.unique(m_sess.case_id))),
                            "picks": {k: model.signal.to_dict()[k] for k in
                                      ("onset_threshold_counts", "aic_blend", "posterior_grid", "localiser_starts")}})
    return out


def table(out: dict) -> None:
    for r in out["rows"]:
        clean = float(np.mean([c["clean"] for c in r["controls"]]))
        noisy = [c["with_noise"] for c in r["controls"]]
        print(f"\n{r['session']}: truth {r['truth']}, named {r['named']}, retrained picks {r['picks']}, trained on "
              f"{r.get('training_drops', '?')} drops at {r.get('training_positions', '?')} positions")
        every = [d for c in r["controls"] for d in c["draws"]]
        print("| session | clean, reference model (mm) | with the diagnosed noise, retrained: mean of the draws (each) "
              "| / clean mean |")
        print("|---|---|---|---|")
        for c in r["controls"]:
            each = ", ".join(f"{d:.2f}" for d in c["draws"])
            print(f"| {c['session']} | {c['clean']:.3f} | {c['with_noise']:.3f} ({each}) | {c['with_noise'] / clean:.2f} |")
        print(f"| mean | {clean:.3f} | {np.mean(noisy):.3f} | {np.mean(noisy) / clean:.2f} |")
        print(f"| {r['session']} (its own positions and draw) | - | {r['after']:.3f} | {r['after'] / clean:.2f} |")
        print(f"ratio over the {len(every)} noisy controls (session x draw): {min(every) / clean:.2f} .. "
              f"{max(every) / clean:.2f}, sd {np.std(every, ddof=1) / clean:.2f}; the issue's bar 1.2 x {clean:.3f} = "
              f"{1.2 * clean:.3f} mm")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", required=True, help="benchmarks/loop_sessions.py's output folder")
    ap.add_argument("--out", default="/tmp/impactsense-noise-controls")
    ap.add_argument("--trees", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--draws", type=int, default=3, help="draws of the diagnosed noise per unchanged session")
    ap.add_argument("--no-twin", action="store_true", help="train on the reference's drops alone (no twin drops)")
    args, args.gen = ap.parse_known_args(argv)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    out = run(args)
    (Path(args.out) / "bench_noise_controls.json").write_text(json.dumps(out, indent=1, default=float))
    table(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
