"""Three more routes to the energy class on a new rig: late (reverberant) energy, a learnt position field, and
a regression of log height against the rig's discrete heights.

    python3 benchmarks/bench_class_field.py [--rigs-dir DIR] [--seeds 4] [--json OUT.json]

Per session folder (the bundled session and the folders under --rigs-dir, as bench_rigs.py finds them):
1. Late energy (the core's own outputs: the five equal windows from ToA to n2, `window_energy`, summed over the
   channels). After a few plate transits a diffuse field would make the late energy independent of the impact
   site. Out-of-fold (5 case folds x 3 shuffles) rms error of log height, with a cubic in the true position,
   from: the whole arrival, its first window, the last three windows, and the energy extrapolated back to
   ToA with the decay fitted on windows 1..4 of the same record; and how much the decay itself differs between
   cases (a diffuse field has one decay) against between the repetitions of a case.
2. A learnt position field: a Gaussian process on (x, y) of the training drops' out-of-fold log-height residual
   (ridge of log height on the core's summed energies and the physics position's cubic), added to the ridge's
   estimate at the drop's true position (a bound) and at the forests' position (what a product would have).
   Its fitted length scale against the spacing of the training cases (nearest other case, median).
3. Per split seed (`workflow.train` without a site map, as `train DATA` on a rig without a calibration): the
   model's held-out class, and on the same drops a regression forest of log height, the ridge thresholded at the
   boundary between the rig's two heights around the 75th percentile (class_boundary_log) or at a threshold
   fitted on the training drops' out-of-fold estimates (logistic), and the ridge plus the field. Which heights
   the model gets wrong, and how far their case's ridge estimate is off.

A study: nothing here changes the product; exit 0. Figures: docs/findings.md, "Late energy, a learnt field, the
heights".
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_class_cues import class_boundary_log, oof_log_height, position_design, ridge  # noqa: E402
from benchlib import rig_study_args, rig_study_sessions  # noqa: E402

ENERGY_SUMS = ["log_arrival_energy_sum", "log_diff1_energy_sum", "log_diff2_energy_sum", "log_diff3_energy_sum",
               "log_energy_mean"]


def case_means(values: np.ndarray, case_id: np.ndarray) -> np.ndarray:
    _, inv = np.unique(case_id, return_inverse=True)
    return (np.bincount(inv, values) / np.bincount(inv))[inv]


def late_energy(session) -> dict:
    """Section 1, on the core's window energies (default signal configuration of the rig)."""
    from impactsense.pipeline import featurize
    from impactsense.signal import SignalConfig

    cfg = SignalConfig.for_rig(session.rig)
    f = featurize(session.adc, cfg)
    w = f.raw["window_energy"].astype(float).sum(1)          # [R, 5], summed over the channels
    ok = f.usable & np.isfinite(w).all(1) & (w > 0).all(1)
    lw = np.log(w[ok])
    t = np.arange(5) + 0.5
    fit = np.polyfit(t[1:], lw[:, 1:].T, 1)                   # per drop: decay slope and log energy at ToA
    span_ms = (f.raw["n2"][ok].max(1) - f.toa_us[ok].min(1) * cfg.fs_hz * 1e-6) / cfg.fs_hz * 1e3
    xy, case = session.xy_mm[ok], session.case_id[ok]
    log_h = np.log(session.height_mm[ok])
    cubic = position_design(xy, (session.rig.plate_x_mm, session.rig.plate_y_mm), edges=False)
    cues = {"whole arrival (windows 0-4)": np.log(w[ok].sum(1)), "first window": lw[:, 0],
            "last three windows": np.log(w[ok, 2:].sum(1)), "decay-extrapolated to ToA": fit[1]}
    out = {"arrival_span_ms": float(np.median(span_ms))}
    for k, v in cues.items():
        rms, acc = oof_log_height(np.c_[v, cubic], log_h, case)
        out[k] = {"rms": rms, "class": acc, "repeat_sd": float(np.sqrt(np.mean((v - case_means(v, case)) ** 2)))}
    slope = fit[0]
    per_case = case_means(slope, case)
    out["decay_per_window"] = {"mean": float(slope.mean()), "between_cases_sd": float(np.std(np.unique(per_case))),
                               "within_case_sd": float(np.sqrt(np.mean((slope - per_case) ** 2)))}
    return out


def nearest_case_mm(xy_mm: np.ndarray, case_id: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    _, first = np.unique(case_id, return_index=True)
    d, _ = cKDTree(xy_mm[first]).query(xy_mm[first], 2)
    return float(np.median(d[:, 1]))


def field(pos_tr: np.ndarray, residual: np.ndarray):
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    kernel = ConstantKernel(0.01, (1e-4, 1.0)) * RBF(30.0, (3.0, 300.0)) + WhiteKernel(0.003, (1e-5, 0.1))
    return GaussianProcessRegressor(kernel, random_state=0).fit(pos_tr, residual)


def oof_estimates(X: np.ndarray, log_h: np.ndarray, case_id: np.ndarray) -> np.ndarray:
    from sklearn.model_selection import GroupKFold

    pred = np.zeros_like(log_h)
    for a, b in GroupKFold(5).split(X, groups=case_id):
        pred[b] = ridge().fit(X[a], log_h[a]).predict(X[b])
    return pred


def seed_study(session, seeds: int) -> dict:
    """Sections 2 and 3 per split seed."""
    from sklearn.ensemble import RandomForestRegressor
    from sklearn.linear_model import LogisticRegression

    from impactsense.models import MEASURED_ENERGY_FEATURES, ForestSettings, columns
    from impactsense.pipeline import featurize
    from impactsense.workflow import evaluate, train

    plate = (session.rig.plate_x_mm, session.rig.plate_y_mm)
    log_h = np.log(session.height_mm)
    keys = ["model", "regression forest", "ridge", "ridge, fitted threshold", "ridge + field (forests' position)",
            "ridge + field (true position)"]
    acc = {k: [] for k in keys}
    scales, wrong, seen, offsets = [], Counter(), Counter(), {}
    for seed in range(seeds):
        model, split = train(session, None, 0.2, seed, None, ForestSettings(n_estimators=100, seed=seed), site_map=None)
        rep = evaluate(session, model)
        acc["model"].append(float(rep["energy_class_accuracy"]))
        feats = featurize(session.adc, model.signal)
        rows = {k: np.searchsorted(session.recording_id, split[f"{k}_recordings"]) for k in ("train", "test")}
        tr, te = (r[feats.usable[r]] for r in (rows["train"], rows["test"]))
        b, thr = class_boundary_log(session.height_mm[tr])
        high = session.height_mm >= thr
        forest_xy = model.predict(feats.take(te))["forest_xy_mm"]
        M = feats.vector[:, columns(MEASURED_ENERGY_FEATURES)]
        rf = RandomForestRegressor(100, max_features=0.5, random_state=seed, n_jobs=-1).fit(M[tr], log_h[tr])
        acc["regression forest"].append(float(np.mean((rf.predict(M[te]) >= b) == high[te])))
        sums = feats.vector[:, columns(ENERGY_SUMS)]
        X_tr = np.c_[sums[tr], position_design(feats.phys_xy_mm[tr], plate, edges=False)]
        X_te = np.c_[sums[te], position_design(feats.phys_xy_mm[te], plate, edges=False)]
        fit = ridge().fit(X_tr, log_h[tr])
        est = fit.predict(X_te)
        acc["ridge"].append(float(np.mean((est >= b) == high[te])))
        oof = oof_estimates(X_tr, log_h[tr], session.case_id[tr])
        logit = LogisticRegression(C=100.0).fit(oof[:, None], high[tr])
        cut = -logit.intercept_[0] / logit.coef_[0, 0]
        acc["ridge, fitted threshold"].append(float(np.mean((est >= cut) == high[te])))
        gp = field(feats.phys_xy_mm[tr], log_h[tr] - oof)
        scales.append(float(gp.kernel_.k1.k2.length_scale))
        for key, xy in (("forests'", forest_xy), ("true", session.xy_mm[te])):
            corrected = est + gp.predict(np.where(np.isfinite(xy), xy, feats.phys_xy_mm[te]))
            acc[f"ridge + field ({key} position)"].append(float(np.mean((corrected >= b) == high[te])))
        test_rows = rep["_arrays"]["rows"]
        miss = rep["_arrays"]["energy_class"] != rep["_arrays"]["label"]
        for h, m in zip(session.height_mm[test_rows], miss):
            seen[float(h)] += 1
            wrong[float(h)] += int(m)
        err = est - log_h[te]
        for c in np.unique(session.case_id[te]):
            rows_c = session.case_id[te] == c
            if ((est[rows_c] >= b) != high[te][rows_c]).any():
                offsets[int(c)] = (float(session.height_mm[te][rows_c][0]), float(err[rows_c].mean()))
    return {"class": acc, "field_length_scale_mm": scales,
            "nearest_case_mm": nearest_case_mm(session.xy_mm, session.case_id),
            "model_wrong_by_height": {f"{h:g}": [wrong[h], seen[h]] for h in sorted(seen) if wrong[h]},
            "ridge_wrong_cases": {str(c): {"height_mm": h, "log_error": e} for c, (h, e) in sorted(offsets.items())}}


def main(argv=None) -> int:
    from impactsense.data import load_session

    a = rig_study_args(__doc__.splitlines()[0], argv)
    report = {}
    for path in rig_study_sessions(a):
        s = load_session(path)
        r = {"late": late_energy(s), **seed_study(s, a.seeds)}
        report[s.name] = r
        print(f"\n== {s.name}: {len(s)} drops; ToA..n2 median {r['late']['arrival_span_ms']:.1f} ms")
        for k, v in r["late"].items():
            if isinstance(v, dict) and "rms" in v:
                print(f"  late energy: {k:28s} repeat sd {v['repeat_sd']:.3f}  out-of-fold rms log h {v['rms']:.3f}"
                      f"  class {v['class']:.3f}")
        d = r["late"]["decay_per_window"]
        print(f"  decay (log energy per window): mean {d['mean']:.3f}, between cases sd {d['between_cases_sd']:.3f}, "
              f"within a case sd {d['within_case_sd']:.3f}")
        print(f"  field length scale {np.round(r['field_length_scale_mm'], 1).tolist()} mm; nearest other case "
              f"{r['nearest_case_mm']:.1f} mm (median)")
        for k, v in r["class"].items():
            print(f"  class, seeds 0-{a.seeds - 1}: {k:36s} {' '.join(f'{x:.3f}' for x in v)}  mean {np.mean(v):.3f}")
        print("  model's wrong drops by height (wrong / seen): " + ", ".join(
            f"{h}: {w}/{n}" for h, (w, n) in r["model_wrong_by_height"].items()))
        print("  cases the ridge gets wrong (height, mean log error): " + ", ".join(
            f"{v['height_mm']:g} {v['log_error']:+.2f}" for v in r["ridge_wrong_cases"].values()))
    if a.json:
        Path(a.json).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
