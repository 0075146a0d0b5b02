"""What a measured-trained model's held-out position error is made of: per case or per drop, picks or model.

    python3 benchmarks/bench_error_parts.py DATA [--seeds 0 1 2 3] [--trees 100] [--edge-mm 80]

Per split seed: `train DATA` + `evaluate` as bench_rigs.py calls them (default split: 20 % of the cases held out),
then on the held-out drops (MAE per axis, mm):
- drops: the model's reported position (bench_rigs.py's figure);
- case mean: each held-out case's mean reported position against its declared one (what averaging a case's
  repeats would give: the floor of anything that only removes the drops' own scatter);
- within: the drops' scatter about their case's mean (n / (n - 1) corrected); bias share: the case means' part of
  the squared error;
- mean features: the model on each case's mean feature vector (every float feature averaged over the case's
  repeats): the pick noise averaged out before the model instead of after;
- timing oracle, the core's localiser on the threshold picks (the model's travel law, the localiser the edge members
  run): as picked; less each case's own mean travel residual at its declared position (its per-case timing bias,
  a quantity no model has); less each drop's deviation from that mean (its pick noise); less both;
- each of these within --edge-mm of a plate edge (declared position) and beyond.
No file is written; nothing is tuned here (docs/findings.md "Session 24: rigc7" reads it).
"""

from __future__ import annotations

import argparse
import sys
import warnings
import numpy as np


def case_means(values: np.ndarray, case: np.ndarray) -> np.ndarray:
    """values [R, ...] with each row replaced by its case's mean (NaN-aware; non-float arrays unchanged)."""
    out = np.array(values, copy=True)
    if out.dtype.kind != "f" or out.ndim == 0 or out.shape[0] != len(case):
        return out
    for c in np.unique(case):
        m = case == c
        with warnings.catch_warnings():   # a column without a value in a case stays NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            out[m] = np.nanmean(out[m], axis=0)
    return out


def mean_features(features, case: np.ndarray):
    from impactsense.pipeline import Features

    f = features
    return Features(case_means(f.vector, case), case_means(f.phys_xy_mm, case), case_means(f.phys_cov, case),
                    f.accepted, f.status, f.flags, case_means(f.toa_us, case), case_means(f.energy, case),
                    {k: case_means(v, case) for k, v in f.raw.items()}, f.left_out)


def mae(pred: np.ndarray, true: np.ndarray, rows: np.ndarray | None = None) -> float:
    ok = np.isfinite(pred).all(1) & (True if rows is None else rows)
    return float(np.mean(np.abs(pred[ok] - true[ok]))) if ok.any() else float("nan")


def timing_oracle(features, true_xy: np.ndarray, case: np.ndarray, signal) -> dict:
    """The localiser on the threshold picks as picked, less the per-case bias, less the pick noise, less both."""
    from impactsense.edge_travel import _localise, pick_set_arrivals
    from impactsense.travel import travel_distances

    raw = features.raw
    toa, use, scale, v = pick_set_arrivals(raw, signal, "threshold")
    metric = (signal.travel_metric_xx, signal.travel_metric_xy, signal.travel_metric_yy)
    resid = toa - travel_distances(true_xy, np.asarray(signal.sensor_xy_mm, float), metric) * scale / v
    resid = np.where(use, resid, np.nan)
    resid = resid - np.nanmean(resid, 1, keepdims=True)
    bias = case_means(resid, case)
    run = lambda corr: _localise(raw, signal, "threshold", np.nan_to_num(corr))  # noqa: E731
    return {"picks": run(np.zeros_like(resid)), "bias removed": run(bias), "noise removed": run(resid - bias),
            "both removed": run(resid)}


def one_split(session, seed: int, trees: int, edge_mm: float) -> dict:
    from impactsense.models import ForestSettings
    from impactsense.sitemap import resolve_site_map
    from impactsense.workflow import evaluate, train

    model, _ = train(session, None, 0.2, seed, None, ForestSettings(n_estimators=trees, seed=seed),
                     site_map=resolve_site_map("auto", session.rig), choose_class=True)
    rep = evaluate(session, model)
    a = rep["_arrays"]
    rows, true, pred = a["rows"], a["true_xy"], a["pred_xy"]
    case = session.case_id[rows]
    mean_pred = case_means(pred, case)
    n = np.array([np.sum(case == c) for c in case], float)
    within = (pred - mean_pred) * np.sqrt(n / np.maximum(n - 1, 1))[:, None]
    ok = np.isfinite(pred).all(1)
    sq_b, sq_w = np.mean((mean_pred - true)[ok] ** 2), np.mean(within[ok] ** 2)
    feats = model.featurize(session.adc[rows])
    mean_feat = model.predict(mean_features(feats, case))["xy_mm"]
    rig = session.rig
    edge = np.minimum.reduce([true[:, 0], rig.plate_x_mm - true[:, 0], true[:, 1], rig.plate_y_mm - true[:, 1]])
    near = edge < edge_mm
    out = {"drops": pred, "case mean": mean_pred, "mean features": mean_feat,
           **{f"timing: {k}": v for k, v in timing_oracle(feats, true, case, model.signal).items()}}
    table = {k: (mae(v, true), mae(v, true, near), mae(v, true, ~near)) for k, v in out.items()}
    return {"table": table, "within": float(np.mean(np.abs(within[ok]))), "bias_share": float(sq_b / (sq_b + sq_w)),
            "n": len(rows), "n_near": int(near.sum()),
            "near_share": float(np.abs(pred - true)[ok & near].sum() / np.abs(pred - true)[ok].sum())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--trees", type=int, default=100)
    ap.add_argument("--edge-mm", type=float, default=80.0)
    args = ap.parse_args()
    from impactsense.data import load_session

    session = load_session(args.data)
    for seed in args.seeds:
        r = one_split(session, seed, args.trees, args.edge_mm)
        print(f"{session.name} seed {seed}: {r['n']} held-out drops, {r['n_near']} within {args.edge_mm:g} mm of an "
              f"edge ({100 * r['near_share']:.0f} % of the error); within-case scatter {r['within']:.2f} mm, "
              f"bias share of the squared error {r['bias_share']:.2f}")
        print(f"  {'MAE per axis, mm':28s} {'all':>6s} {'near':>6s} {'beyond':>6s}")
        for k, (a, b, c) in r["table"].items():
            print(f"  {k:28s} {a:6.2f} {b:6.2f} {c:6.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
