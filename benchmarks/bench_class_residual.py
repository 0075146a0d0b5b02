"""The energy class without a site map: what the product's linear height estimate leaves, and nine more ways to
read the core's outputs for it.

    python3 benchmarks/bench_class_residual.py [--rigs-dir DIR] [--seeds 4] [--splits 16] [--skip-bundled]
                                               [--json OUT.json]

Per session folder (the bundled session and the folders under --rigs-dir, as bench_rigs.py finds them) and split
seed: the localiser fitted on the training cases and the core's features of every drop, as `workflow.train` makes
them, then the held-out class accuracy of
- "linear estimate": height_class.fit_linear_height_class, the estimate `train` keeps where the training drops'
  out-of-fold accuracy prefers it to the class forest;
- "+ site forest": that estimate plus a regression forest of its out-of-fold residual (position-grouped folds on
  the training drops) on height-free descriptors of the site the core computes: each channel's energy share,
  first peak over the square root of its arrival energy, residual ratio, the summed difference energies over the
  summed arrival energy, and the physics position;
- "huber", "logistic": the same 14 terms fitted robustly (Huber loss) or as a logistic classifier (C 0.1);
- "bayes cut": the same estimate, cut where the training heights' discrete levels (their frequencies as the prior,
  the training drops' out-of-fold rms as the error) make both classes equally likely;
- "+ window sums", "+ low band": the linear estimate with five more inputs, the core's window energies summed over
  the channels, or with one, a low band's energy: the sum over [ToA, n2] of the squared 16-sample block sums (the
  boxcar the core's prefix table already holds; computed here in numpy as what a core feature would give);
- "mix forest": the estimate's class probability (Gaussian, out-of-fold rms) averaged 3:1 with the class forest's;
- "cut shift (out of fold)": the same estimate with its cut moved by the shift (-0.15..0.15 in log energy) that
  classes the training drops' out-of-fold estimates best, the smallest such (the class threshold calibrated on the
  training drops, boundary heights included);
- "channel median": the median over the channels of one linear estimate per channel (its own log energy and the
  cubic in the physics position): robust to one channel's gain drift, glitch or clipping;
- "+ edge offset @ P": the estimate plus a 1-D offset in the distance to the nearest plate edge: a Gaussian kernel
  smoother (2 mm) of the training drops' out-of-fold residuals against their true edge distance, read at the test
  drop's edge distance from position P: "true" (a bound), "reported" (what `train` + `evaluate` report: the
  forests', or the twin's match with a site map), "physics".
Then the same candidates over --splits more random 80/20 case splits of the first seed's features (the paired
difference against "linear estimate"; "reported" there is the out-of-fold position of one forest pair on the physics
position, 5 case folds: the product's forests are trained per seed only), the per-case residual against the edge
distance, the held-out cases the linear estimate classes wrong (per seed: height, position, edge and sensor
distance, boundary height or not, the estimate's error, the positions' errors, flagged drops), and the lab's gain
drift: the per-case mean of the linear estimate's out-of-fold residual against the recording order.

A study: nothing here changes the product; exit 0. Figures: docs/findings.md, "The class on the laminate: site
descriptors, robust and Bayes cuts, a low band, the edge offset" and "Session 20: rigcclass".
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import rig_study_args, rig_study_sessions  # noqa: E402

LOW_BAND_BLOCK = 16
EDGE_KERNEL_MM = 2.0
CUT_SHIFTS = np.linspace(-0.15, 0.15, 61)   # the cut's shifts (log energy) the out-of-fold calibration tries


def edge_distance(xy_mm: np.ndarray, plate_mm: tuple[float, float]) -> np.ndarray:
    x, y = xy_mm[:, 0], xy_mm[:, 1]
    return np.minimum(np.minimum(x, plate_mm[0] - x), np.minimum(y, plate_mm[1] - y))


def edge_offset(d_train: np.ndarray, residual: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The training residuals' kernel mean at edge distances d (shrunk to 0 where no training drop is near)."""
    w = np.exp(-0.5 * ((d[:, None] - d_train[None]) / EDGE_KERNEL_MM) ** 2)
    return (w * residual[None]).sum(1) / (w.sum(1) + 1e-3)


def low_band_energy(adc: np.ndarray, raw: dict) -> np.ndarray:
    """[R] log10 of the sum over channels and over [threshold ToA, n2] of the squared 16-sample block sums."""
    x = adc.astype(np.float64) - raw["baseline"].astype(np.float64)[:, :, None]
    out = np.zeros(len(x))
    toa = np.nan_to_num(raw["toa_threshold"].astype(float), nan=0.0).astype(int)
    for r in range(len(x)):
        for c in range(x.shape[1]):
            a = toa[r, c]
            seg = x[r, c, a:max(int(raw["n2"][r, c]), a + LOW_BAND_BLOCK)]
            m = len(seg) // LOW_BAND_BLOCK * LOW_BAND_BLOCK
            out[r] += np.sum(seg[:m].reshape(-1, LOW_BAND_BLOCK).sum(1) ** 2)
    return np.log10(np.maximum(out, 1e-6))


def site_descriptors(vector: np.ndarray, raw: dict) -> np.ndarray:
    """Height-free numbers the core computes about the site (see the module docstring)."""
    from impactsense.pipeline import FEATURE_NAMES

    col = lambda names: vector[:, [FEATURE_NAMES.index(n) for n in names]]  # noqa: E731
    arrival = np.log10(np.maximum(raw["window_energy"].astype(float).sum(2), 1e-6))
    return np.hstack([col([f"log_energy_rel_{c}" for c in range(4)]),
                      col([f"log_first_peak_{c}" for c in range(4)]) - 0.5 * arrival,
                      col([f"residual_ratio_{c}" for c in range(4)]),
                      col([f"log_diff{k}_energy_sum" for k in (1, 2, 3)]) - col(["log_arrival_energy_sum"]),
                      col(["phys_x_mm", "phys_y_mm"])])


def oof_log_energy(X, log_e, xy, threshold_j, energy_j) -> np.ndarray:
    from sklearn.model_selection import GroupKFold

    from impactsense.height_class import fit_linear_height_class, position_groups

    out = np.zeros(len(X))
    for a, b in GroupKFold(5).split(X, groups=position_groups(xy)):
        out[b] = fit_linear_height_class(X[a], energy_j[a], threshold_j).log_energy(X[b])
    return out


def terms(X_tr, X):
    """The linear estimate's standardised design (14 terms) of X, standardised as on X_tr."""
    from impactsense.height_class import _products, design_terms

    off, sd = X_tr.mean(0), X_tr.std(0)
    sc = 1.0 / np.where(sd > 0, sd, 1.0)
    t = design_terms(X_tr.shape[1])
    D_tr, D = _products((X_tr - off) * sc, t), _products((X - off) * sc, t)
    mu, s = D_tr.mean(0), D_tr.std(0)
    s = np.where(s > 0, s, 1.0)
    return (D_tr - mu) / s, (D - mu) / s


def candidates(d: dict, tr: np.ndarray, te: np.ndarray) -> dict:
    """Held-out class (bool per test drop) of each candidate; d holds the features of every drop."""
    from scipy.stats import norm
    from sklearn.ensemble import RandomForestRegressor
    from sklearn.linear_model import HuberRegressor, LogisticRegression, RidgeCV

    from impactsense.height_class import class_cut, fit_linear_height_class
    from impactsense.models import ForestSettings

    E, X = d["energy_j"], d["X_linear"]
    log_e = np.log(E)
    thr = float(np.percentile(E[tr], 75))
    cut = class_cut(E[tr], thr)
    label = (E >= thr).astype(int)
    m = fit_linear_height_class(X[tr], E[tr], thr)
    est = m.log_energy(X[te])
    oof = oof_log_energy(X[tr], log_e[tr], d["xy"][tr], thr, E[tr])
    sigma = float(np.std(log_e[tr] - oof))
    out = {"linear estimate": est > cut}
    out["cut shift (out of fold)"] = est - cut + oof_cut_shift(oof - cut, label[tr]) > 0
    out["channel median"] = channel_median(d, tr, te, thr) > cut
    S = d["site"]
    forest = RandomForestRegressor(200, min_samples_leaf=5, max_features=0.5, random_state=0, n_jobs=1)
    out["+ site forest"] = est + forest.fit(S[tr], log_e[tr] - oof).predict(S[te]) > cut
    D_tr, D_te = terms(X[tr], X[te])
    out["huber"] = HuberRegressor(alpha=1e-3, max_iter=2000).fit(D_tr, log_e[tr]).predict(D_te) > cut
    out["logistic"] = LogisticRegression(C=0.1, max_iter=5000).fit(D_tr, label[tr]).predict(D_te) == 1
    levels, counts = np.unique(np.round(log_e[tr], 9), return_counts=True)
    like = np.exp(-0.5 * ((est[:, None] - levels[None]) / sigma) ** 2) * counts
    high = levels >= np.log(thr) - 1e-9
    out["bayes cut"] = like[:, high].sum(1) > like[:, ~high].sum(1)
    for name, extra in (("+ window sums", d["window_sums"]), ("+ low band", d["low_band"][:, None])):
        Xe = np.hstack([X[:, :-2], extra, X[:, -2:]])
        De_tr, De_te = terms(Xe[tr], Xe[te])
        out[name] = RidgeCV(alphas=np.logspace(-3, 3, 13)).fit(De_tr, log_e[tr]).predict(De_te) > cut
    p_forest = ForestSettings(n_estimators=100, seed=0).classifier().fit(d["X_forest"][tr], label[tr]) \
        .predict_proba(d["X_forest"][te])[:, 1]
    out["mix forest"] = 0.75 * norm.cdf((est - cut) / sigma) + 0.25 * p_forest > 0.5
    d_tr = edge_distance(d["xy"][tr], d["plate_mm"])
    for where in ("true", "reported", "physics"):
        P = {"true": d["xy"], "reported": d["xy_reported"], "physics": d["xy_physics"]}[where]
        offset = edge_offset(d_tr, log_e[tr] - oof, edge_distance(P[te], d["plate_mm"]))
        out[f"+ edge offset @ {where}"] = est + offset > cut
    return {k: float(np.mean(v == label[te].astype(bool))) for k, v in out.items()}


def oof_cut_shift(oof_score: np.ndarray, label: np.ndarray) -> float:
    """The shift of the class cut (log energy, added to the score) that classes the training drops' out-of-fold
    scores best (estimate - cut); among equal accuracies the smallest shift (0 when nothing beats it)."""
    acc = np.array([np.mean((oof_score + s > 0) == label.astype(bool)) for s in CUT_SHIFTS])
    best = CUT_SHIFTS[acc >= acc.max() - 1e-12]
    return float(best[np.argmin(np.abs(best))])


def channel_median(d: dict, tr: np.ndarray, te: np.ndarray, thr: float) -> np.ndarray:
    """The median over the channels of one linear estimate of log m g h per channel (its own log energy and a cubic
    in the physics position, fitted as the product's): one channel's gain or glitch moves the sum, not the median."""
    from impactsense.height_class import fit_linear_height_class

    E = d["energy_j"]
    est = []
    for c in range(d["log_channel_energy"].shape[1]):
        Xc = np.column_stack([d["log_channel_energy"][:, c], d["xy_physics"]])
        est.append(fit_linear_height_class(Xc[tr], E[tr], thr).log_energy(Xc[te]))
    return np.median(est, 0)


def wrong_cases(session, d: dict, tr: np.ndarray, te: np.ndarray) -> list[dict]:
    """The held-out drops the linear estimate classes wrong, one row per case: its height, position, distance to the
    nearest edge and sensor, whether its height is one of the two boundary heights (the training drops' highest
    below the threshold and lowest at or above it), the estimate's error and the height's distance from the cut
    (log energy), the reported and physics positions' errors, the drops flagged by the core (glitch, clip)."""
    from impactsense.height_class import class_cut, fit_linear_height_class

    E = d["energy_j"]
    thr = float(np.percentile(E[tr], 75))
    cut = class_cut(E[tr], thr)
    est = fit_linear_height_class(d["X_linear"][tr], E[tr], thr).log_energy(d["X_linear"][te])
    log_e = np.log(E[te])
    wrong = (est > cut) != (E[te] >= thr)
    bnd = np.isin(E[te], [E[tr][E[tr] < thr].max(), E[tr][E[tr] >= thr].min()])
    sensors = np.array([[s.x_mm, s.y_mm] for s in session.rig.sensors])
    xy = d["xy"][te]
    rows = []
    for c in np.unique(session.case_id[te][wrong]):
        k = session.case_id[te] == c
        near = lambda P: float(np.mean(np.hypot(*(P[te][k] - xy[k]).T)))  # noqa: E731
        rows.append({"case": int(c), "height_mm": float(session.height_mm[te][k][0]), "xy_mm": xy[k][0].tolist(),
                     "wrong": int(wrong[k].sum()), "drops": int(k.sum()),
                     "edge_mm": float(edge_distance(xy[k][:1], d["plate_mm"])[0]),
                     "sensor_mm": float(np.min(np.hypot(*(sensors - xy[k][0]).T))), "boundary": bool(bnd[k][0]),
                     "estimate_error": float(np.mean(est[k] - log_e[k])), "height_from_cut": float(log_e[k][0] - cut),
                     "reported_error_mm": near(d["xy_reported"]), "physics_error_mm": near(d["xy_physics"]),
                     "flagged": int((d["flags"][te][k] != 0).any(1).sum())})
    return rows


def oof_forest_positions(d: dict, case_id: np.ndarray) -> np.ndarray:
    """Every usable drop's position from one forest pair (100 trees) on the physics position, out of fold (5 case
    folds): a stand-in for the reported position on the random splits."""
    from sklearn.ensemble import RandomForestRegressor
    from sklearn.model_selection import GroupKFold

    out = d["xy_physics"].copy()
    use = np.flatnonzero(d["usable"])
    X = np.nan_to_num(d["X_location"])
    for a, b in GroupKFold(5).split(use, groups=case_id[use]):
        for k in (0, 1):
            f = RandomForestRegressor(100, max_features=0.5, random_state=0, n_jobs=1)
            f.fit(X[use[a]], d["xy"][use[a], k] - out[use[a], k])
            out[use[b], k] += f.predict(X[use[b]])
    return out


def seed_features(session, seed: int) -> tuple[dict, np.ndarray, np.ndarray]:
    """The features of every drop as `train DATA` (split seed `seed`) makes them, and its reported positions."""
    from impactsense.height_class import LINEAR_CLASS_FEATURES
    from impactsense.models import LOCATION_FEATURES, MEASURED_ENERGY_FEATURES, ForestSettings, columns, impact_energy_j
    from impactsense.pipeline import featurize
    from impactsense.sitemap import resolve_site_map
    from impactsense.split import case_split
    from impactsense.workflow import train

    tr, te = case_split(session.case_id, 0.2, seed, None)
    model, _ = train(session, None, 0.2, seed, None, ForestSettings(n_estimators=100, seed=seed),
                     site_map=resolve_site_map("auto", session.rig), choose_class=True)
    f = featurize(session.adc, model.signal)
    v = f.vector.astype(float)
    d = {"energy_j": impact_energy_j(session.height_mm, session.rig.ball_mass_g), "xy": session.xy_mm,
         "X_linear": v[:, columns(LINEAR_CLASS_FEATURES)], "X_forest": v[:, columns(MEASURED_ENERGY_FEATURES)],
         "X_location": v[:, columns(LOCATION_FEATURES)],
         "site": site_descriptors(v, f.raw), "low_band": low_band_energy(session.adc, f.raw),
         "window_sums": np.log10(np.maximum(f.raw["window_energy"].astype(float).sum(1), 1e-6)),
         "usable": f.usable, "plate_mm": (session.rig.plate_x_mm, session.rig.plate_y_mm),
         "xy_physics": f.phys_xy_mm.astype(float), "flags": np.asarray(f.raw["flags"]),
         "log_channel_energy": np.log(np.maximum(np.asarray(f.raw["energy"], float), 1e-30)), "xy_reported": np.asarray(model.predict(f)["xy_mm"], float)}
    d["xy_reported"] = np.where(np.isfinite(d["xy_reported"]), d["xy_reported"], d["xy_physics"])
    return d, np.intersect1d(tr, np.flatnonzero(f.usable)), np.intersect1d(te, np.flatnonzero(f.usable))


def gain_drift(session, d: dict) -> dict:
    """Per-case mean out-of-fold residual of the linear estimate (10 position-grouped folds, all drops) against
    the recording order: correlation, and the mean residual of each quarter of the session."""
    use = np.flatnonzero(d["usable"])
    E = d["energy_j"]
    res = np.log(E[use]) - oof_log_energy(d["X_linear"][use], np.log(E[use]), d["xy"][use],
                                          float(np.percentile(E[use], 75)), E[use])
    _, inv = np.unique(session.case_id[use], return_inverse=True)
    case_res = np.bincount(inv, res) / np.bincount(inv)
    case_t = np.bincount(inv, session.recording_id[use].astype(float)) / np.bincount(inv)
    quarters = np.array_split(np.argsort(case_t), 4)
    return {"r_case_residual_vs_order": float(np.corrcoef(case_res, case_t)[0, 1]),
            "quarter_mean_residual": [float(case_res[q].mean()) for q in quarters],
            "case_sd": float(case_res.std()), "within_case_sd": float(np.std(res - case_res[inv]))}


def edge_distance_error(d: dict, te: np.ndarray) -> dict:
    """How far the reported position's nearest-edge distance is from the true one, held-out drops within 60 mm of
    an edge and the others: median and 90th percentile (mm)."""
    true = edge_distance(d["xy"][te], d["plate_mm"])
    err = np.abs(edge_distance(d["xy_reported"][te], d["plate_mm"]) - true)
    near = true < 60
    return {k: [float(np.median(err[m])), float(np.percentile(err[m], 90))] if m.any() else [float("nan")] * 2
            for k, m in (("near", near), ("interior", ~near))}


def edge_profile(d: dict) -> dict:
    """Per-case mean out-of-fold residual of the linear estimate (all drops, 10 folds) by the case's true distance
    to the nearest edge: mean and sd per bin."""
    use = np.flatnonzero(d["usable"])
    E = d["energy_j"][use]
    res = np.log(E) - oof_log_energy(d["X_linear"][use], np.log(E), d["xy"][use], float(np.percentile(E, 75)), E)
    dist = edge_distance(d["xy"][use], d["plate_mm"])
    out = {}
    for lo, hi in ((0, 35), (35, 46), (46, 60), (60, 80), (80, np.inf)):
        m = (dist >= lo) & (dist < hi)
        if m.any():
            key = f"{lo}-{hi:g} mm" if np.isfinite(hi) else f">= {lo} mm"
            out[key] = {"mean": float(res[m].mean()), "sd": float(res[m].std()), "n": int(m.sum())}
    return out


def main(argv=None) -> int:
    import argparse

    from impactsense.data import load_session

    extra = argparse.ArgumentParser(add_help=False)
    extra.add_argument("--splits", type=int, default=16)
    more, rest = extra.parse_known_args(argv)
    a = rig_study_args(__doc__.splitlines()[0], rest)
    report = {}
    for path in rig_study_sessions(a):
        s = load_session(path)
        r = {"seeds": {}, "splits": {}}
        for seed in range(a.seeds):
            d, tr, te = seed_features(s, seed)
            if seed == 0:
                first = d
            r.setdefault("edge_distance_error_mm", []).append(edge_distance_error(d, te))
            r.setdefault("wrong_cases", []).append(wrong_cases(s, d, tr, te))
            for k, v in candidates(d, tr, te).items():
                r["seeds"].setdefault(k, []).append(v)
        rng = np.random.default_rng(0)
        use = first["usable"]
        cases = np.unique(s.case_id[use])
        first = {**first, "xy_reported": oof_forest_positions(first, s.case_id)}   # seed 0's forests saw them
        for _ in range(more.splits):
            held = rng.choice(cases, int(round(0.2 * len(cases))), replace=False)
            te = np.flatnonzero(use & np.isin(s.case_id, held))
            tr = np.flatnonzero(use & ~np.isin(s.case_id, held))
            for k, v in candidates(first, tr, te).items():
                r["splits"].setdefault(k, []).append(v)
        r["gain_drift"] = gain_drift(s, first)
        r["edge_profile"] = edge_profile(first)
        report[s.name] = r
        base = np.array(r["splits"]["linear estimate"])
        print(f"\n== {s.name}: held-out class, split seeds 0-{a.seeds - 1} | {more.splits} random case splits: "
              f"mean, paired difference to the linear estimate (+- se), splits >= 0.95")
        for k, v in r["seeds"].items():
            sp = np.array(r["splits"][k])
            print(f"  {k:26s} {' '.join(f'{x:.3f}' for x in v)}  mean {np.mean(v):.3f} | {sp.mean():.3f} "
                  f"{np.mean(sp - base):+.3f} +- {np.std(sp - base) / np.sqrt(len(sp)):.3f}  {int(np.sum(sp >= 0.95))}/"
                  f"{len(sp)}")
        print("  residual by edge distance (true): " + ", ".join(
            f"{k} {v['mean']:+.3f} (sd {v['sd']:.3f}, {v['n']})" for k, v in r["edge_profile"].items()))
        e = r["edge_distance_error_mm"]
        print("  reported position's edge-distance error, median / 90th pct per seed (mm): within 60 mm of an edge "
              + ", ".join(f"{x['near'][0]:.1f}/{x['near'][1]:.1f}" for x in e) + "; further in "
              + ", ".join(f"{x['interior'][0]:.1f}/{x['interior'][1]:.1f}" for x in e))
        for seed, cases_wrong in enumerate(r["wrong_cases"]):
            for w in cases_wrong:
                print(f"  seed {seed} wrong case {w['case']}: {w['wrong']}/{w['drops']} drops, {w['height_mm']:.0f} mm at "
                      f"({w['xy_mm'][0]:.1f}, {w['xy_mm'][1]:.1f}), edge {w['edge_mm']:.0f} mm, sensor "
                      f"{w['sensor_mm']:.0f} mm, {'boundary' if w['boundary'] else 'off-boundary'} height "
                      f"{w['height_from_cut']:+.3f} from the cut, estimate {w['estimate_error']:+.3f}, position error "
                      f"reported {w['reported_error_mm']:.1f} / physics {w['physics_error_mm']:.1f} mm, "
                      f"{w['flagged']} flagged")
        g = r["gain_drift"]
        print(f"  gain drift: per-case residual vs recording order r {g['r_case_residual_vs_order']:+.2f}; quarters "
              f"{' '.join(f'{x:+.3f}' for x in g['quarter_mean_residual'])}; per-case sd {g['case_sd']:.3f}, "
              f"within a case {g['within_case_sd']:.3f}")
    if a.json:
        Path(a.json).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
