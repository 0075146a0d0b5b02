"""retrain's model choice (`impactsense.model_choice.keep_retrained_or_reference`) against drops it did not see.

For each changed session of a bench_loop run, the reference model and the loop's model (trained again as
bench_loop trains it, from the training data its run kept in OUT: `<name>-measured`, or `<name>-twin` for a
twin-trained after) are placed on the session (where the choice is made), on its control (`--controls`), and on
fresh drops with the same change: the run's five unchanged sessions (same-1..5, other positions and noise) with the
change's true size put in by its signal model (a gain keeping the amplifier's noise, as the generator's gain lies
before the noise; a delay as a shift; D_s as the damping effect's extra decay). The model better on the fresh drops
is the one the choice should keep; printed: the rule's choice, two other rules' (the in-sample minimum; one
standard error: the reference kept only when its paired per-case lead exceeds one SE) and what each costs there.

    python3 benchmarks/bench_loop.py --seed 12 ... --sessions DIR --out OUT --only same-1,gain,delay,damping
    python3 benchmarks/bench_model_choice.py --sessions DIR --bench OUT --seed 12 --only gain,delay,damping
        [--trees 30] [--json FILE]

The seed and trees must be bench_loop's (the models are trained again with them). Needs same-1..5 in DIR.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_loop import train_score  # noqa: E402


def loop_model(name: str, row: dict, ref, bench: Path, trees: int, seed: int):
    """The loop's after as bench_loop trained it (measured-trained or twin-trained, delays in its picks)."""
    from impactsense.commands.retrain import carry_delays
    from impactsense.data import load_session
    from impactsense.loop import channel_delays, pick_settings

    acc = [SimpleNamespace(effect=a["effect"], sensor=a["sensor"], params=a["params"]) for a in row["effects_added"]]
    kind = "twin" if "twin" in row else "measured"
    if kind == "twin":
        return carry_delays(train_score(load_session(bench / f"{name}-twin"), trees, seed), channel_delays(acc))[0]
    ms = load_session(bench / f"{name}-measured")
    return carry_delays(train_score(ms, trees, seed, signal=pick_settings(ms, acc, ref)), channel_delays(acc))[0]


def true_change(truth: dict, damping_per_s: float) -> list[dict]:
    """The generator's change as the effect library's signal model, at its true size."""
    p = dict(truth["params"])
    if truth["effect"] == "damping":
        return [{"effect": "damping", "sensor": None,
                 "params": {"extra_decay_per_s": (p["damping_scale"] - 1.0) * damping_per_s}}]
    if truth["effect"] == "sensor_gain":
        return [{"effect": "sensor_gain", "sensor": truth["sensor"], "params": {**p, "noise_kept": True}}]
    if truth["effect"] == "channel_delay":
        return [{"effect": "channel_delay", "sensor": truth["sensor"], "params": p}]
    raise ValueError(f"bench_model_choice: no signal model for the change {truth['effect']!r}")


def per_case(model, session) -> np.ndarray:
    from impactsense.model_choice import drop_errors

    e = drop_errors(model, session)
    return np.array([np.nanmean(e[session.case_id == c]) for c in np.unique(session.case_id)])


def one_row(name, spec, row, ref, ref_model, same, args, bench_out) -> dict:
    from impactsense.data import load_session
    from impactsense.effects.apply import apply_effects
    from impactsense.model_choice import keep_retrained_or_reference

    model = loop_model(name, row, ref, Path(args.bench), args.trees, args.seed)
    sess = load_session(Path(args.sessions) / name)
    choice = keep_retrained_or_reference(model, ref_model, sess, args.seed)
    ctx = {"bias": float(ref.rig.bias_counts), "adc_max": int(ref.rig.adc_max), "fs_hz": float(ref.rig.fs_hz),
           "sensor_xy_mm": ref.rig.sensor_xy_mm.astype(float)}
    change = true_change(spec["truth"], bench_out["D_s"])
    fresh = {"reference": [], "loop": []}
    for k, s in same.items():
        s = replace(s, adc=apply_effects(s.adc, change, ctx, args.seed + 100 + k))
        fresh["reference"].append(per_case(ref_model, s))
        fresh["loop"].append(per_case(model, s))
    fr = {k: float(np.mean(np.concatenate(v))) for k, v in fresh.items()}
    sess_mae = {"reference": choice["reference_mae_mm"], "loop": choice["retrained_mae_mm"]}
    lead, se = choice["reference_lead_mm"], choice["reference_lead_se_mm"]
    rules = {"rule": "reference" if choice["chosen"] == "reference" else "loop",
             "minimum": min(sess_mae, key=sess_mae.get),
             "one_se": "reference" if lead > se else "loop"}
    better = min(fr, key=fr.get)
    out = {"session": name, "after_kind": "twin" if "twin" in row else "measured", "session_mae_mm": sess_mae,
           "reference_lead_mm": lead, "reference_lead_se_mm": se, "fresh_mae_mm": fr,
           "fresh_sessions_loop_better": int(sum(np.mean(a) < np.mean(b)
                                                 for a, b in zip(fresh["loop"], fresh["reference"]))),
           "better_on_fresh": better, "choices": rules,
           "cost_on_fresh_mm": {r: fr[c] - fr[better] for r, c in rules.items()}}
    print(f"  {name} ({out['after_kind']}): session reference {sess_mae['reference']:.3f} loop {sess_mae['loop']:.3f}"
          f" (lead {lead:+.3f} SE {se:.3f}); fresh reference {fr['reference']:.3f} loop {fr['loop']:.3f}"
          f" ({out['fresh_sessions_loop_better']} of {len(same)} loop better); kept: rule {rules['rule']},"
          f" minimum {rules['minimum']}, one SE {rules['one_se']}", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", required=True)
    ap.add_argument("--bench", required=True, help="bench_loop's --out of a run on these sessions")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trees", type=int, default=30)
    ap.add_argument("--only", required=True, help="changed sessions (a gain, a delay, damping)")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    from impactsense.data import load_session

    S = Path(args.sessions)
    man = json.loads((S / "manifest.json").read_text())
    bench_out = json.loads((Path(args.bench) / "bench_loop.json").read_text())
    ref = load_session(S / "ref")
    ref_model, _ = train_score(ref, args.trees, args.seed)
    same = {k: load_session(S / f"same-{k}") for k in range(1, 6)}
    rows = []
    for name in args.only.split(","):
        row = next((r for r in bench_out["rows"] if r["session"] == name and r.get("effects_added")), None)
        if row is None or row.get("bond_choice"):
            print(f"  {name}: no loop model in {args.bench} (nothing named, or a bond's choice): skipped")
            continue
        rows.append(one_row(name, man["sessions"][name], row, ref, ref_model, same, args, bench_out))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    for rule in ("rule", "minimum", "one_se"):
        worse = [r for r in rows if r["choices"][rule] != r["better_on_fresh"]]
        print(f"{rule}: kept the model worse on the fresh drops in {len(worse)} of {len(rows)}"
              + "".join(f"; {r['session']} +{r['cost_on_fresh_mm'][rule]:.3f} mm" for r in worse))
    return 0


if __name__ == "__main__":
    sys.exit(main())
