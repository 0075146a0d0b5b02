"""The board's signal cost per drop from the host core's work counters (issue 15; docs/findings.md "Session 23:
aacount"): can export bound each rig's slowest event less its models from the rig's own drops instead of
board.cost's one constant (BASE_INSTRUCTIONS + FRONT_END_INSTRUCTIONS + the localiser's worst case)?

    python benchmarks/bench_signal_work.py Q1.json Q2.json ...

Each Q.json is `bench_firmware_cost.py --data DATA --export OUT --all --json Q.json` (qemu's TICKS per drop: the
event, its models, the features, the localiser; the JSON names DATA and OUT/board-model). The host core (its build
counts impactcore.h WorkCounts; the board's does not) runs the same signal configuration on the same board
captures, giving each drop's counters and localiser evaluations. The fit: the signal less the localiser's bound at
the drop's evaluations (board.cost's LOCALISER_SCREEN + evaluations x LOCALISER_PER_EVALUATION) against the counters,
non-negative rates and one fixed part, by a linear programme (the least total slack with the bound at or above every
drop of every session). Then per session: the per-drop bound's slowest drop (max over drops of the counters' bound +
the drop's localiser bound) against qemu's slowest signal and board.cost's constant form (BASE + the localiser's
worst case), also with the rates fitted without the session's own drops (leave one session out: the rates on a rig
they were not fitted on), each with three allowances for what a lab drop may have that the session did not: none;
absent = one hum channel (its fit and its modelling) and one spike hunt added to the slowest drop when no drop of
the session had one; floor = every drop counted with at least one of each.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.optimize import linprog

from impactsense import _core
from impactsense.board import cost
from impactsense.board.capture import board_captures
from impactsense.data import load_session
from impactsense.pipeline import as_int16

ALLOWED = {"hum_fits": 1, "hum_channels": 1, "spike_hunts": 1}


def session_rows(qjson: str) -> dict:
    """qemu's per-drop figures and the host core's counters on the same board captures."""
    q = json.loads(Path(qjson).read_text())
    card = json.loads((Path(q["model_dir"]) / "model_card.json").read_text())
    s = load_session(q["data"])
    caps, rows, cfg = board_captures(s, int(card.get("board_fs_hz", 50000)), card["signal"])
    if [int(r) for r in rows] != [int(r) for r in q["rows"]]:
        raise SystemExit(f"{qjson}: the board captured other drops than qemu timed")
    out = _core.process_batch(as_int16(caps, cfg), cfg.core(), cfg.localiser())
    p = q["per_drop"]
    ev = np.asarray(out["localiser_evaluations"])[:, 0]
    if not np.array_equal(ev, np.asarray(p["localiser_evaluations"])):
        raise SystemExit(f"{qjson}: the host's localiser evaluations differ from qemu's")
    k = 0 if cost.isotropic((cfg.travel_metric_xx, cfg.travel_metric_xy, cfg.travel_metric_yy)) else 1
    return {"name": Path(qjson).stem, "work": np.asarray(out["work"], float), "fields": list(out["work_fields"]),
            "signal": np.asarray(p["event"]) - np.asarray(p["models"]), "models": np.asarray(p["models"]),
            "loc_bound": cost.LOCALISER_SCREEN[k] + ev * cost.LOCALISER_PER_EVALUATION[k],
            "loc_worst": cost.localiser_run_instructions(cfg.localiser_starts, k == 0, cost.evaluations_cap(cfg)),
            "base": cost.base_instructions(card.get("board_front_end")), "cfg": cfg}


def fit(sessions: list[dict]) -> np.ndarray:
    """Rates (one per counter) and the fixed part, last: the bound >= every drop, the least total slack."""
    X = np.vstack([np.column_stack([s["work"], np.ones(len(s["work"]))]) for s in sessions])
    y = np.concatenate([s["signal"] - s["loc_bound"] for s in sessions])
    lp = linprog(c=X.sum(0), A_ub=-X, b_ub=-y, bounds=[(0, None)] * (X.shape[1] - 1) + [(None, None)])
    if not lp.success:
        raise SystemExit(f"the linear programme failed: {lp.message}")
    return lp.x


def bound(s: dict, coef: np.ndarray, allowance: str) -> int:
    w = s["work"].copy()
    idx = {f: j for j, f in enumerate(s["fields"])}
    if allowance == "floor":
        for f, n in ALLOWED.items():
            w[:, idx[f]] = np.maximum(w[:, idx[f]], n)
    per = w @ coef[:-1] + coef[-1] + s["loc_bound"]
    if allowance == "absent":
        per = per + sum(coef[idx[f]] * n for f, n in ALLOWED.items() if s["work"][:, idx[f]].max() == 0)
    return int(np.ceil(per.max()))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("qemu_json", nargs="+")
    args = ap.parse_args()
    sessions = [session_rows(q) for q in args.qemu_json]
    fields = sessions[0]["fields"]
    coef = fit(sessions)
    print("rates (instructions a count): " + ", ".join(f"{f} {c:.0f}" for f, c in zip(fields, coef[:-1]))
          + f"; fixed {coef[-1]:.0f}")
    for s in sessions:
        names = ", ".join(f"{f} {int(v)}" for f, v in zip(fields, s["work"].max(0)) if v)
        print(f"{s['name']}: counters' max per drop: {names}")
    kinds = ("none", "absent", "floor")
    print("per session: qemu's slowest signal (the event less its models) and models; board.cost's constant form; the "
          "per-drop bound with each allowance (" + " / ".join(kinds) + "), fitted on all sessions and leaving it out")
    for i, s in enumerate(sessions):
        rest = [t for j, t in enumerate(sessions) if j != i]
        out = fit(rest) if rest else None
        per = " / ".join(f"{bound(s, coef, a):,}" for a in kinds)
        left = " / ".join(f"{bound(s, out, a):,}" for a in kinds) if out is not None else "-"
        if out is not None:   # the left-out rates, drop by drop (no allowance): drops they under-count
            under = s["signal"] - (s["work"] @ out[:-1] + out[-1] + s["loc_bound"])
            left += f" (under on {int((under > 0).sum())} drops, by up to {max(0, int(np.ceil(under.max()))):,})"
        print(f"  {s['name']}: qemu {int(s['signal'].max()):,} (models {int(s['models'].max()):,}); constant "
              f"{s['base'] + s['loc_worst']:,}; per drop {per}; left out {left}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
