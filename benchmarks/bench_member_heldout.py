"""Each position member's held-out MAE of a trained model, the members' stack, and a smooth member tried beside them.

    python3 benchmarks/bench_member_heldout.py DATA --model M [--gp-lengths 25,60,100] [--no-gp]

M: `impactsense train DATA --out M [--seed S]` (bench_rigs.py's calls; or bench_threshold_forced.py's training with
the pick forced). On M's held-out drops (its split) and its training drops, the MAE per axis of every column the
stack (member_stack.py) chooses from: the members' mean (the reported position), each member's corrected position
and its base (the position before the forests' correction), with the stack's weights from the card.

The smooth member (not in the product): a member's base plus a Gaussian process (scikit-learn, normalised targets;
an RBF of a fixed length, and a white noise either as large as the signal (--gp-noise fixed) or with both fitted by
marginal likelihood (--gp-noise fit)) on the training drops' residual (truth - base) over the base position, per
axis: what a correction that interpolates smoothly between the training sites gives where the forests' is piecewise
constant. Printed held out, out of fold on the training drops (5 site folds) in brackets, and held out the members'
mean with the smooth member as one more member (the way every member joins). docs/findings.md "Session 30: rigcmodel" reads it.
"""

from __future__ import annotations

import argparse
import json
import warnings

import numpy as np


def member_columns(session, model):
    """(names, P [R, K, 2] the stack's columns on the rows the forests place, rows [R], reported xy [n, 2])."""
    from impactsense.level_members import LEVEL_MEMBERS, level_positions
    from impactsense.member_stack import columns
    from impactsense.models import location_matrix
    from impactsense.position_members import (EDGE_MEMBERS, POSITION_MEMBERS, each_member_position, edge_positions,
                                              mean_of_members, member_positions)
    from impactsense.travel_field import member_field_positions

    feats = model.featurize(session.adc)
    reported = model.predict(feats)["xy_mm"]
    L = location_matrix(feats, model.location_features)
    rows = np.flatnonzero(feats.usable & np.isfinite(L).all(1))
    sub = feats.take(rows)
    main = np.stack([sub.phys_xy_mm[:, k] + f.predict(L[rows]) for k, f in enumerate((model.forest_dx,
                                                                                         model.forest_dy))], 1)
    positions = member_positions(sub) if any(n in model.members for n in POSITION_MEMBERS) else None
    edges = (edge_positions(sub, model.signal, model.edge_travel)
             if model.edge_travel and any(n in model.members for n in EDGE_MEMBERS) else {})
    if any(n in model.members for n in LEVEL_MEMBERS):
        edges.update(level_positions(sub) or {})
    edges.update(member_field_positions(sub.raw, model.signal, model.card, model.members))
    each = each_member_position(main, sub.phys_xy_mm, model.members, L[rows], positions, edges,
                                model.location_features)
    names, P = columns(each, mean_of_members(each)[0])
    return names, P, rows, reported


def smooth_member(base, xy, fit, sites, length, noise="fixed"):
    """(base + GP correction fitted on rows `fit`, the same out of fold over 5 site folds on `fit`)."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
    from sklearn.model_selection import GroupKFold

    def fitted(rows, at):
        kernel = (ConstantKernel(1.0, "fixed") * RBF(length, "fixed") + WhiteKernel(1.0, "fixed") if noise == "fixed"
                  else ConstantKernel(1.0) * RBF(length, "fixed") + WhiteKernel(1.0, (1e-3, 1e3)))
        return np.stack([GaussianProcessRegressor(kernel, normalize_y=True).fit(base[rows], xy[rows, c] -
                                                                                base[rows, c]).predict(base[at])
                         for c in range(2)], 1)

    ok = fit & np.isfinite(base).all(1)
    idx = np.flatnonzero(ok)
    out = base + fitted(idx, np.arange(len(base)))
    oof = np.full_like(base, np.nan)
    for f, h in GroupKFold(5).split(idx, groups=sites[idx]):
        oof[idx[h]] = base[idx[h]] + fitted(idx[f], idx[h])
    return out, oof


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data")
    ap.add_argument("--model", required=True)
    ap.add_argument("--gp-lengths", default="30,60,100", help="the smooth member's RBF lengths, mm")
    ap.add_argument("--gp-columns", default="main@base,physics_edge@base,threshold_edge@base")
    ap.add_argument("--gp-noise", choices=("fixed", "fit"), default="fixed")
    ap.add_argument("--no-gp", action="store_true")
    args = ap.parse_args()
    warnings.filterwarnings("ignore")
    from impactsense.data import load_session
    from impactsense.models import ImpactModel

    session, model = load_session(args.data), ImpactModel.load(args.model)
    card, split = model.card, model.card["split"]
    test = np.isin(session.recording_id, split["test_recordings"])
    train = np.isin(session.recording_id, split["train_recordings"])
    names, P, rows, reported = member_columns(session, model)
    xy, te, tr = session.xy_mm[rows], test[rows], train[rows]

    def mae(p, r):
        return float(np.nanmean(np.abs(p[r] - xy[r])))

    sig = model.signal
    print(f"{session.name}, split seed {split['seed']}, threshold {sig.onset_threshold_counts:g} / blend "
          f"{sig.aic_blend:g}; correction scale {(card.get('correction_scale') or {}).get('scale')}")
    for key in ("member_stack", "level_members", "travel_field_members"):
        if card.get(key):
            print(f"{key}: " + json.dumps({k: v for k, v in card[key].items() if k != "weights"}))
    print(f"held-out drops {int(te.sum())}, reported MAE {float(np.nanmean(np.abs(reported[test] - session.xy_mm[test]))):.3f} mm")
    weights = (card.get("member_stack") or {}).get("weights", {})
    print("| column | held out | training drops | stack weight |\n|---|---|---|---|")
    for k, n in enumerate(names):
        print(f"| {n} | {mae(P[:, k], te):.3f} | {mae(P[:, k], tr):.3f} | {weights.get(n, 0):.3f} |")
    if weights:
        stacked = np.einsum("rkc,k->rc", P, np.array([weights.get(n, 0.0) for n in names]) / sum(weights.values()))
        print(f"| stack (its weights; kept: {card['member_stack']['keep']}) | {mae(stacked, te):.3f} | "
              f"{mae(stacked, tr):.3f} | |")
    if args.no_gp:
        return 0
    sites = np.unique(np.round(xy, 1), axis=0, return_inverse=True)[1].ravel()
    corrected = [k for k, n in enumerate(names) if n != "mean" and not n.endswith("@base")]
    lengths = [float(v) for v in args.gp_lengths.split(",")]
    print(f"\nsmooth member: base + GP(truth - base over the base position), noise {args.gp_noise}; held out (out of"
          f" fold on the training drops), and the members' mean with it\n| base | its own | " + " | ".join(f"RBF {v:g} mm" for v in lengths) + " |\n|---|---|"
          + "---|" * len(lengths))
    for n in args.gp_columns.split(","):
        if n not in names:
            continue
        base = P[:, names.index(n)]
        cells = []
        for length in lengths:
            out, oof = smooth_member(base, xy, tr, sites, length, args.gp_noise)
            joined = np.nanmean(np.concatenate([P[:, corrected], out[:, None]], 1), 1)
            cells.append(f"{mae(out, te):.3f} ({mae(oof, tr):.3f}), in the mean {mae(joined, te):.3f}")
        print(f"| {n} | {mae(base, te):.3f} ({mae(base, tr):.3f}) | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
