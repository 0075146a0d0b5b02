"""diagnose's names on many sessions of one loop folder (benchmarks/loop_sessions.py), the reference prepared once.

    python3 benchmarks/diagnose_names.py DIR NAME[,NAME...] [--plain] [--move-fits] [--json OUT]

Each NAME is diagnosed against DIR/ref exactly as `impactsense diagnose --baseline DIR/ref --data DIR/NAME`
(the picker `choose_picker` chooses, the band picks, the site terms, the design effect of `case_correlation`),
the reference's work done once for all names. Printed per session: the named effects with their held-out score,
tempered score (over the design effects) and per-case p. --plain: also the names with the design effect off (the
evidence rule's plain Markov half, as before Session 26). --icc-only: also the names with the timing design
effect of the ICC alone for every candidate (Session 26's rule, before each candidate's between-case share of the
site terms' error, `case_correlation.timing_design_effect`). --move-fits: for each NAME that is a moved sensor
(manifest truth), the move's fit on its session and on its `-control` session (the same drops without the move),
and the error of each against the truth (docs/findings.md, Session 26 falsenames)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def prepare(folder: Path) -> dict:
    """The reference of diagnose(DIR/ref, ...), once (`diagnose.prepared_reference`)."""
    from impactsense import diagnose as D
    from impactsense.data import load_session

    ref, _, picker, _, band = D.prepared_reference(load_session(folder / "ref"))
    return {"ref": ref, "picker": picker, "band": band}


def features(P: dict, folder: Path, name: str):
    from impactsense import diagnose as D
    from impactsense.data import load_session

    return D.session_features(P["ref"], load_session(folder / name), P["picker"], P["band"])


def names(P: dict, F, plain: bool = False, icc_only: bool = False) -> list[dict]:
    from impactsense import case_correlation as CC
    from impactsense import diagnose as D

    ref = P["ref"]
    if plain:
        ref = ref.copy()
        ref.case_icc = None
    shared = CC.off_case_site_cov
    if icc_only:   # Session 26's rule: the timing design effect 1 + (m - 1) ICC for every candidate
        CC.off_case_site_cov = lambda site, F: None   # diagnose reads it through session_design_effects
    try:
        accepted, _, _ = D.select(ref, F)
    finally:
        CC.off_case_site_cov = shared
    return [{"effect": c.effect, "sensor": c.sensor, "params": D._jsonable(c.params), "score": c.score,
             "tempered": c.tempered, "p_value": c.p_value} for c in accepted]


def move_fits(P: dict, folder: Path, name: str, truth: dict) -> dict:
    from impactsense.effects import EFFECTS

    s, t = truth["sensor"], np.array([truth["params"]["dx_mm"], truth["params"]["dy_mm"]])
    out = {"sensor": s, "truth": t.tolist()}
    for tag, session in (("move", name), ("control", f"{name}-control")):
        if not (folder / session).exists():
            continue
        p = EFFECTS["sensor_position"].fit(P["ref"], features(P, folder, session), s)
        out[tag] = [p["dx_mm"], p["dy_mm"]]
    if "move" in out:
        out["error_mm"] = float(np.hypot(*(np.array(out["move"]) - t)))
    if "control" in out:
        out["error_less_control_mm"] = float(np.hypot(*(np.array(out["move"]) - out["control"] - t)))
    return out


def _fmt(named: list[dict]) -> str:
    return ", ".join(f"{e['effect']}[{e['sensor']}] {e['score']:.1f} nats"
                     + (f" (tempered {e['tempered']:.1f})" if e["tempered"] is not None else "")
                     + f" p {e['p_value']:.3f}" for e in named) or "none"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder")
    ap.add_argument("names", help="comma-separated session names")
    ap.add_argument("--plain", action="store_true", help="also the names with the design effect off")
    ap.add_argument("--icc-only", action="store_true",
                    help="also the names with every candidate's timing design effect 1 + (m - 1) ICC (Session 26's rule)")
    ap.add_argument("--move-fits", action="store_true", help="the move's fit on a move session and its control")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    folder = Path(args.folder)
    truths = json.loads((folder / "manifest.json").read_text())["sessions"]
    P = prepare(folder)
    print("design effects' ICC:", {k: round(v, 3) for k, v in P["ref"].case_icc.items()}, flush=True)
    out = {}
    for name in args.names.split(","):
        truth = truths.get(name, {}).get("truth")
        row = {"truth": truth}
        if args.move_fits:
            if truth and truth["effect"] == "sensor_position":
                row["move_fit"] = move_fits(P, folder, name, truth)
                print(name, {k: np.round(v, 2).tolist() for k, v in row["move_fit"].items()}, flush=True)
        else:
            F = features(P, folder, name)
            row["named"] = names(P, F)
            print(f"{name}: {_fmt(row['named'])}", flush=True)
            if args.plain:
                row["named_plain"] = names(P, F, plain=True)
                print(f"{name} (plain Markov half): {_fmt(row['named_plain'])}", flush=True)
            if args.icc_only:
                row["named_icc_only"] = names(P, F, icc_only=True)
                print(f"{name} (design effect of the ICC alone): {_fmt(row['named_icc_only'])}", flush=True)
        out[name] = row
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
