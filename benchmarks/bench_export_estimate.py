"""Export's per-event estimate (board.cost, export_check.event_estimate) against what qemu measured, by part, on
every kind of exported model (issue 15; docs/findings.md "Session 26: exportest"). The refit of board.cost's
coefficients reads this table.

    python benchmarks/bench_export_estimate.py Q1.json Q2.json ... [--json OUT]

Each Q.json is `bench_firmware_cost.py ... --json Q.json` (qemu's ticks per drop: the event, the models, the
features, the localiser, a twin's match; the JSON names the board model and the trees it ran). The estimate is made
again from that board model with this tree's board.cost, so a refit is checked without running qemu again. Per run:
the clean events (every channel kept) against 'total', the flagged ones (a channel left out: the twin's cued search
or the three-sensor path) against 'flagged', and per part the estimate against the measured maximum: the signal
(the event less its models, the app's accounting on top) against base + band + localiser + check, the models
against the forests + the twin's match. Target: estimate / slowest clean event within 0.99..1.03 (the estimate:
export_check.estimate_total, export's verdict; 'per drop': the drops each priced whole, board.drop_cost; 'parts':
each part at its worst, board.cost).

    python benchmarks/bench_export_estimate.py Q1.json ... --loo FIT1.json ...

prints each run's estimate / qemu with the per-drop rates fitted on the FIT runs without it, by the estimate's form,
and the band per form: export's verdict (export_check.event_verdict) reads board.cost's ESTIMATE_RATIO_BAND, this
band rounded outwards.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.optimize import linprog

from impactsense.board import cost, drop_cost
from impactsense.board.cost import EVENT_BUDGET
from impactsense.data import load_session
from impactsense.export import load_models
from impactsense.export_check import estimate_form, estimate_total, event_estimate, event_verdict, flagged_total
from impactsense.signal import SignalConfig

LOW, HIGH = 0.99, 1.03


def load_run(qjson: str) -> tuple[dict, object, dict, dict]:
    """(the run's JSON, its board model, the trees it ran, the host's counts on its drops: cached beside the JSON)."""
    q = json.loads(Path(qjson).read_text())
    model_dir = q["model_dir"]
    if model_dir == "shipped":
        raise SystemExit(f"{qjson}: a shipped-model run names no board model; pass its board model (the bench's "
                         "cache, build/bench-cache/shipped-*/out/board-model) as --model-dir to the bench")
    models = load_models(model_dir)
    trees = {r: int(q["export"]["trees"][r]) for r in ("x", "y", "energy")}
    cache = Path(qjson).with_suffix(".counts.npz")
    if cache.is_file():
        z = np.load(cache)
        counts = {k: z[k] for k in z.files}
        counts["fields"] = [str(f) for f in counts["fields"]]
    else:
        s = load_session(None if q["data"] == "bundled" else q["data"])
        counts = drop_cost.drop_counts(models, trees, s.subset(np.asarray(q["rows"])))
        np.savez(cache, **counts)
    differ = int(np.count_nonzero(counts["evaluations"] != np.asarray(q["per_drop"]["localiser_evaluations"])))
    if differ > 0.01 * len(counts["evaluations"]):   # a fixture's first drop: the app starts cold there
        raise SystemExit(f"{qjson}: the host's localiser evaluations differ from qemu's on {differ} drops")
    return q, models, trees, counts


def clean_mask(q: dict) -> np.ndarray:
    p = q["per_drop"]
    n = len(p["event"])
    return np.asarray(p["left_out"]) == 4 if len(p.get("left_out", ())) == n else np.ones(n, bool)


def bound_fit(rows_X: list, rows_y: list) -> np.ndarray:
    """Non-negative counter rates and free fixed parts (the last two columns): the bound at or above every row with
    the least total slack (a column no row varies gets no rate)."""
    X, y = np.vstack(rows_X), np.concatenate(rows_y)
    used = X.std(axis=0) > 0
    used[-2:] = X[:, -2:].any(axis=0)   # the fixed parts: one per model kind the runs hold
    Xu = X[:, used]
    n_rates = int(used[:-2].sum())
    lp = linprog(c=Xu.sum(axis=0), A_ub=-Xu, b_ub=-y,
                 bounds=[(0, None)] * n_rates + [(None, None)] * (Xu.shape[1] - n_rates))
    if not lp.success:
        raise SystemExit(f"the linear programme failed: {lp.message}")
    coef = np.zeros(X.shape[1])
    coef[used] = lp.x
    return coef


def fit(qjsons: list[str]) -> None:
    """The features and report per clean drop (the event less its localiser, its models, the bond inverse's bound
    and the channel check's share) bounded by the host's counters (non-negative rates) and one fixed part per model
    kind (forests, twin): a linear programme, the bound at or above every drop of every run with the least total
    slack; prints the rates for board.cost, the localiser's screening + rate line and each run's slack."""
    rows_X, rows_y, names, loc, twin_ticks = [], [], None, {0: [], 1: []}, []
    for qj in qjsons:
        q, models, trees, counts = load_run(qj)
        p, c = q["per_drop"], clean_mask(q)
        ev, lo, mo = (np.asarray(p[k], float) for k in ("event", "localiser", "models"))
        cfg = SignalConfig.from_dict(models.signal)
        bond = cost.BOND_PER_SAMPLE * cost.bond_samples(cfg) + checked(q, event_estimate(models, trees))["check"]
        k = 0 if cost.isotropic((cfg.travel_metric_xx, cfg.travel_metric_xy, cfg.travel_metric_yy)) else 1
        loc[k].append(np.c_[counts["evaluations"], lo])
        if "twin" in p:   # the twin's match (its ticks) against the grid points it visited, clean drops
            twin_ticks.append(np.c_[np.asarray(p["twin_points"])[c], np.asarray(p["twin"])[c],
                                    np.full(c.sum(), cost.twin_points_bound(models.twin["grid"],
                                                                            models.twin["config"]))])
        twin = models.twin is not None
        X = np.c_[counts["work"], np.full(len(ev), float(not twin)), np.full(len(ev), float(twin))][c]
        rows_X.append(X)
        rows_y.append((ev - lo - mo - bond)[c])
        names = counts["fields"] + ["fixed_forests", "fixed_twin"]
    coef = bound_fit(rows_X, rows_y)
    print("fit (a bound at or above every clean drop, the least total slack; board.cost FEATURES_PER_COUNT, "
          "FEATURES_FIXED): " + ", ".join(f"{n} {c:.1f}" for n, c in zip(names, coef) if c))
    for k, runs in loc.items():   # the localiser: the least screening + rate line at or above every drop
        if runs:
            e, lo = np.vstack(runs).T
            lp = linprog(c=[len(e), e.sum()], A_ub=-np.c_[np.ones_like(e), e], b_ub=-lo, bounds=[(0, None)] * 2)
            rate = cost.LOCALISER_PER_EVALUATION[k]
            print(f"  localiser ({'isotropic' if k == 0 else 'metric'}): screening {lp.x[0]:.0f} + {lp.x[1]:.1f} an "
                  f"evaluation bounds every drop with the least total slack; at board.cost's {rate} an evaluation "
                  f"the least screening is {int(np.ceil((lo - rate * e).max()))} ({len(e)} drops, evaluations "
                  f"{int(e.min())}..{int(e.max())}, the most at {int(e.max())}: {int(lo[e == e.max()].max())})")
    if twin_ticks:
        pts, ticks, most = np.vstack(twin_ticks).T
        lp = linprog(c=[len(pts), pts.sum()], A_ub=-np.c_[np.ones_like(pts), pts], b_ub=-ticks, bounds=[(0, None)] * 2)
        print(f"  twin match: {lp.x[0]:.0f} + {lp.x[1]:.1f} a visited point bounds every clean drop ({len(pts)} drops, "
              f"{int(pts.min())}..{int(pts.max())} points, the bound {int(most.max())}; ticks max {int(ticks.max())})")
    for i, (qj, Xr, yr) in enumerate(zip(qjsons, rows_X, rows_y)):
        res = yr - Xr @ coef
        others = [j for j in range(len(rows_X)) if j != i]
        left = ""
        if others and rows_X[i][:, -2:].any(axis=0)[np.flatnonzero(Xr[:, -2:].any(axis=0))].all() and \
                np.vstack([rows_X[j] for j in others])[:, -2:][:, np.flatnonzero(Xr[:, -2:].any(axis=0))].any():
            out = bound_fit([rows_X[j] for j in others], [rows_y[j] for j in others])
            left = f"; fitted without this run: slowest {(Xr @ out).max():.0f} ({(Xr @ out).max() - yr.max():+.0f})"
        print(f"  {Path(qj).parent.name}: measured less the bound {res.min():.0f}..{res.max():.0f}; slowest bound "
              f"{(Xr @ coef).max():.0f} / measured {yr.max():.0f}{left}")


def checked(q: dict, est: dict) -> dict:
    """est without the channel check's share when the run's export kept the check on the host."""
    if est["check"] and q["export"].get("channel_check") is not True:
        est["total"] -= est.pop("check")
        est["check"] = 0
        est.pop("flagged", None)
    return est


def stored(qjson: str) -> dict:
    """A run as tests/data/board_cost_measured.json keeps it: what board.cost and board.drop_cost read of the model
    (its signal configuration, front end, trees' deepest walks, inputs, twin arrays' grid and config, the models'
    fixed cost), the host's counts on each drop and qemu's slowest clean and flagged events."""
    q, models, trees, counts = load_run(qjson)
    est = checked(q, event_estimate(models, trees))
    p, c = q["per_drop"], clean_mask(q)
    ev = np.asarray(p["event"]) + max(0, int(q["instructions"]["app_event_max"])
                                       - int(q["instructions"]["event_max_over_drops"]))
    return {"run": Path(qjson).parent.name, "signal": models.signal, "front_end": models.card.get("board_front_end"),
            **drop_cost.model_inputs(models, trees),
            "twin": (None if models.twin is None else
                     {k: np.asarray(models.twin[k]).tolist() for k in ("grid", "config")}),
            "check": est["check"],
            "check_terms": (max((len(m.terms) for m in models.three_channel.values()), default=0)
                            if est["check"] else None),
            "counts": {"fields": counts["fields"], "work": counts["work"][c].astype(int).tolist(),
                       "evaluations": counts["evaluations"][c].tolist(), "walk": counts["walk"][c].tolist()},
            "measured": {"clean_max": int(ev[c].max()), "flagged_max": int(ev[~c].max()) if (~c).any() else None,
                         "command": q.get("command", "bench_firmware_cost.py --json")}}


def run_row(qjson: str) -> dict:
    q, models, trees, counts = load_run(qjson)
    est = checked(q, event_estimate(models, trees))
    cfg = SignalConfig.from_dict(models.signal)
    per = drop_cost.drop_instructions(counts, est, cfg, models.twin is not None,
                                      drop_cost.forests_fixed(**drop_cost.model_inputs(models, trees)))
    p = q["per_drop"]
    ev, mo, lo = (np.asarray(p[k], np.int64) for k in ("event", "models", "localiser"))
    app = max(0, int(q["instructions"]["app_event_max"]) - int(q["instructions"]["event_max_over_drops"]))
    ev = ev + app
    c = clean_mask(q)
    drops = drop_cost.slowest(per, est, np.asarray(q["rows"]), drop_cost.beyond_base(counts),   # every drop, as export
                              drop_cost.any_hum(counts))
    row_est = dict(est, drops=drops)
    est["drops"] = drops["slowest"]
    name = Path(qjson).stem if Path(qjson).stem != "q" else Path(qjson).parent.name
    row = {"run": name, "drops": int(len(ev)), "clean": int(c.sum()), "estimate": est, "drops_detail": drops,
           "measured": {"clean_max": int(ev[c].max()) if c.any() else None,
                        "flagged_max": int(ev[~c].max()) if (~c).any() else None,
                        "signal_max": int((ev - mo)[c].max()) if c.any() else None,
                        "localiser_max": int(lo.max()), "models_max": int(mo[c].max()) if c.any() else None,
                        "twin_max": int(np.max(p["twin"])) if "twin" in p else None}}
    m = row["measured"]
    row["estimate_total"] = estimate_total(row_est)
    row["verdict"] = event_verdict(row_est)
    row["flagged_verdict"] = event_verdict(row_est, flagged=True)
    row["ratio"] = row["estimate_total"] / m["clean_max"] if m["clean_max"] else None
    row["drops_ratio"] = est["drops"] / m["clean_max"] if m["clean_max"] else None
    res = (ev - per)[c]
    row["per_drop_residual"] = {"min": int(res.min()), "max": int(res.max()), "sd": float(res.std())}
    # per part, the slowest drop's measured less the largest predicted (features and report, localiser, models)
    k = 0 if cost.isotropic((cfg.travel_metric_xx, cfg.travel_metric_xy, cfg.travel_metric_yy)) else 1
    loc = cost.LOCALISER_SCREEN[k] + counts["evaluations"] * cost.LOCALISER_PER_EVALUATION[k]
    feat = (drop_cost.features_instructions(counts, models.twin is not None)
            + cost.BOND_PER_SAMPLE * cost.bond_samples(cfg))
    rest = per - loc - feat
    row["part_max"] = {name: (int(meas[c].max()), int(np.ceil(pred[c].max()))) for name, meas, pred in
                       (("features_report", ev - lo - mo, feat), ("localiser", lo, loc), ("models", mo, rest))}
    row["flagged_estimate"] = flagged_total(row_est)
    row["flagged_drops"] = drops.get("flagged")
    row["flagged_ratio"] = (row["flagged_estimate"] / m["flagged_max"]
                            if m["flagged_max"] and "flagged" in est else None)
    return row


def with_rates(coef: np.ndarray, names: list[str]):
    """board.cost's per-drop rates set to a fit's coefficients (fields then fixed_forests, fixed_twin) until the
    returned function restores them."""
    saved = dict(cost.FEATURES_PER_COUNT), dict(cost.FEATURES_FIXED)
    cost.FEATURES_PER_COUNT.clear()
    cost.FEATURES_PER_COUNT.update({n: float(c) for n, c in zip(names[:-2], coef[:-2]) if c})
    cost.FEATURES_FIXED.update({"forests": float(coef[-2]), "twin": float(coef[-1])})

    def restore():
        cost.FEATURES_PER_COUNT.clear()
        cost.FEATURES_PER_COUNT.update(saved[0])
        cost.FEATURES_FIXED.update(saved[1])
    return restore


def fit_rows(qjson: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """A run's clean drops as the fit reads them: (the counters and the two fixed parts' indicators, the features
    and report measured, the columns' names)."""
    q, models, trees, counts = load_run(qjson)
    p, c = q["per_drop"], clean_mask(q)
    ev, lo, mo = (np.asarray(p[k], float) for k in ("event", "localiser", "models"))
    cfg = SignalConfig.from_dict(models.signal)
    bond = cost.BOND_PER_SAMPLE * cost.bond_samples(cfg) + checked(q, event_estimate(models, trees))["check"]
    twin = models.twin is not None
    X = np.c_[counts["work"], np.full(len(ev), float(not twin)), np.full(len(ev), float(twin))][c]
    return X, (ev - lo - mo - bond)[c], counts["fields"] + ["fixed_forests", "fixed_twin"]


def form(row: dict) -> str:
    """Which of export's estimates a run's verdict reads (export_check.estimate_form)."""
    return estimate_form(dict(row["estimate"], drops=row["drops_detail"]))


def loo(fit_runs: list[str], runs: list[str]) -> list[dict]:
    """Each run's estimate / qemu with the per-drop rates fitted without it (a run outside fit_runs: the rates of
    all fit_runs), by the estimate's form (the drops priced whole, the larger with the parts on a hum session);
    the parts' worst cases alone (export without the model's session) need no fit."""
    data = {qj: fit_rows(qj) for qj in dict.fromkeys(fit_runs)}
    out = []
    for qj in runs:
        others = [k for k in data if k != qj]
        coef = bound_fit([data[k][0] for k in others], [data[k][1] for k in others])
        names = next(iter(data.values()))[2]
        restore = with_rates(coef, names)
        try:
            r = run_row(qj)
        finally:
            restore()
        m = r["measured"]
        out.append({"run": r["run"], "form": form(r), "clean_max": m["clean_max"], "estimate": r["estimate_total"],
                    "ratio": r["ratio"], "parts_ratio": r["estimate"]["total"] / m["clean_max"],
                    "flagged_ratio": r["flagged_ratio"], "left_out": qj in data})
    return out


def print_band(rows: list[dict]) -> None:
    for r in rows:
        fl = f", flagged {r['flagged_ratio']:.3f}" if r["flagged_ratio"] else ""
        print(f"  {r['run']:<14} {r['form']:<6} qemu {r['clean_max']:>7,} estimate {r['estimate']:>7,} "
              f"ratio {r['ratio']:.3f} (parts alone {r['parts_ratio']:.3f}){fl}"
              f"{'' if r['left_out'] else ' (not in the fit)'}")
    for f in ("drops", "hum"):
        rs = [r["ratio"] for r in rows if r["form"] == f]
        if rs:
            print(f"BAND {f}: estimate / qemu in [{min(rs):.3f}, {max(rs):.3f}] ({len(rs)} runs, each left out)")
    ps = [r["parts_ratio"] for r in rows]
    print(f"BAND parts: [{min(ps):.3f}, {max(ps):.3f}] ({len(ps)} runs)")
    fl = [r["flagged_ratio"] for r in rows if r["flagged_ratio"]]
    if fl:
        print(f"BAND flagged: [{min(fl):.3f}, {max(fl):.3f}] ({len(fl)} runs)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="bench_firmware_cost.py --json files")
    ap.add_argument("--json", help="write the rows here")
    ap.add_argument("--fit", action="store_true", help="print the per-drop rates' fit on the runs")
    ap.add_argument("--loo", nargs="*", metavar="FIT_RUN",
                    help="each run's estimate / qemu with the rates fitted without it on these runs (the fit's set; "
                         "default every run given): the verdict's ratio band (board.cost ESTIMATE_RATIO_BAND)")
    ap.add_argument("--store", help="write the runs as the tests' stored measurement (tests/data/...json)")
    args = ap.parse_args()
    if args.store:
        Path(args.store).write_text(json.dumps([stored(q) for q in args.runs], separators=(",", ":")) + "\n")
    if args.fit:
        fit(args.runs)
    if args.loo is not None:
        print_band(loo(args.loo or args.runs, args.runs))
        return 0
    rows = [run_row(q) for q in args.runs]
    print(f"{'run':<16}{'drops':>6} {'estimate':>9} {'clean max':>10} {'est/meas':>9} {'per drop':>9} {'ratio':>6}"
          f"  {'signal est/meas':>17} {'models est/meas':>17} {'flagged est (parts) / meas':>28}")
    ok = True
    for r in rows:
        e, m = r["estimate"], r["measured"]
        sig = e["base"] + e["band"] + e["localiser"] + e["check"]
        mod = e["models"] + e["twin"]
        within = r["ratio"] is not None and LOW <= r["ratio"] <= HIGH
        ok &= within or r["ratio"] is None
        fl = (f"{r['flagged_estimate']:,} ({e['flagged']:,}) / {m['flagged_max']:,}" if m["flagged_max"]
              and "flagged" in e else "-")
        print(f"{r['run']:<16}{r['drops']:>6} {r['estimate_total']:>9,} {m['clean_max'] or 0:>10,} "
              f"{r['ratio'] or 0:>9.3f}{'' if within else '*'} {e['drops']:>8,} {r['drops_ratio'] or 0:>6.3f}  "
              f"{sig:>8,}/{m['signal_max'] or 0:<8,} {mod:>8,}/{m['models_max'] or 0:<8,} {fl:>28}")
        verdict_est = r["verdict"] + (f" (flagged {r['flagged_verdict']})" if r["flagged_verdict"] else "")
        verdict_meas = "over" if (m["clean_max"] or 0) > EVENT_BUDGET else "within"
        rs = r["per_drop_residual"]
        print(f"{'':<18}parts {', '.join(f'{k} {v:,}' for k, v in e.items() if v is not None)}; per drop: measured "
              f"less predicted {rs['min']:,}..{rs['max']:,} (sd {rs['sd']:.0f}); export says {verdict_est}, "
              f"qemu's clean events {verdict_meas}")
        print(f"{'':<18}per drop, measured / predicted max: "
              + ", ".join(f"{k} {a:,} / {b:,}" for k, (a, b) in r["part_max"].items()))
    print(f"RESULT estimate / slowest clean event within {LOW}..{HIGH} on "
          f"{sum(1 for r in rows if r['ratio'] and LOW <= r['ratio'] <= HIGH)} of {len(rows)} runs")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
