"""Zero-shot energy class: the twin's height estimate on measured drops, taken apart, and the class per seed.

The sim-trained model sees the rig only through the four calibration cases (zeroshot.fit_on_calibration_drops);
its energy class is the virtual drops' bagged stumps on the twin's log10-height estimate (the core's
twin_estimate at the forests' position). For each split seed (which also seeds the virtual set) this makes
that model the product's way and scores three fits of the twin's offsets and weights on the same estimate:

  before     the calibration drops with the many-drop estimator: 16 free offsets (medians), per-kind weights
             from the in-sample residual variance (twin.fit_twin's default; the product up to this bench)
  product    what fit_on_calibration_drops fits now: a channel + kind offset table, the virtual drops'
             weight shape with one scale from the calibration drops' residuals
  many drops reference only, not zero-shot: offsets and weights from the split's measured training drops

and prints, per fit: class accuracy on the split's test drops and on every drop but the calibration ones
(the sim-trained model saw none of them: 751 drops, a steadier figure than one split's ~155); the error of the
estimate e = est - log10 h split into a common bias, a per-case (site) term and the within-case scatter;
e by distance from the nearest edge and at the heights next to the class boundary (170 / 175 mm, 0.0063 in
log10 h from it); the calibration drops held out by position (each position's error with the fits on the
other three: what a new position sees, the only error the calibration itself can measure); and the height
bias the fit's offsets imply against the many-drop ones (sum w s d_off / sum w s^2). Then the product model's
evaluate figures (MAE, class), the measured-trained model on the same split and session-2.

    python3 benchmarks/bench_zeroshot_class.py [--calibration CAL.json] [--seeds 0 1 2 3] [--cache DIR]
        [--virtual 490] [--no-measured]

Targets (issue 4, exit 1 on a miss): the product model's evaluate figures on every seed's test split: MAE
<= 5 mm whole plate, <= 3.5 mm inner region, class >= 0.95.

The virtual sets and the calibration's site map are cached under --cache (a new calibration builds its map,
~2 min on 2 cores; each seed simulates its virtual set once, ~1-2 min).
"""

from __future__ import annotations

import argparse
import copy
import hashlib
from dataclasses import replace
from pathlib import Path

import numpy as np

from impactsense import zeroshot as zs
from impactsense.data import load_session
from impactsense.models import impact_energy_j
from impactsense.pipeline import featurize
from impactsense.sim import SimParams
from impactsense.sitemap import BUNDLED, twin_features
from impactsense.split import case_split
from impactsense.twin import estimate, fit_twin, position_groups
from impactsense.workflow import evaluate, train

EDGE_BINS_MM = (0, 30, 50, 80, 1000)


def edge_distance_mm(session) -> np.ndarray:
    rig = session.rig
    return np.minimum.reduce([session.x_mm, rig.plate_x_mm - session.x_mm, session.y_mm, rig.plate_y_mm - session.y_mm])


def decompose(err: np.ndarray, case: np.ndarray) -> tuple[float, float, float]:
    """(mean, sd of the case means about it, pooled within-case sd) of err, NaNs left out."""
    ok = np.isfinite(err)
    err, case = err[ok], case[ok]
    cases = np.unique(case)
    means = np.array([err[case == c].mean() for c in cases])
    within = np.concatenate([err[case == c] - err[case == c].mean() for c in cases])
    return float(err.mean()), float(means.std(ddof=1)), float(np.sqrt(np.sum(within ** 2) / (err.size - cases.size)))


def implied_bias(fit, reference) -> float:
    """The log10-height shift fit's offsets give against reference's, at fit's slopes and weights."""
    w, s = np.asarray(fit.weight), np.asarray(fit.slope)
    d = np.asarray(fit.offset) - np.asarray(reference.offset)
    return float(np.sum(w * s * d) / np.sum(w * s ** 2))


def held_out_by_position(site, feats, usable, xy, h, start_xy, fitter) -> np.ndarray:
    """Each calibration position's mean height error with the twin fitted on the other positions' drops."""
    groups = position_groups(xy)
    out = []
    for g in np.unique(groups):
        held = groups == g
        fit = fitter(feats[~held], usable[~held], xy[~held], h[~held])
        est = estimate(site, fit, feats[held], usable[held], start_xy[held])["log10_height_mm"]
        out.append(float(np.nanmean(est - np.log10(h[held]))))
    return np.array(out)


def run_seed(session, cal_path: Path, seed: int, cache: Path, n_virtual: int, measured: bool, session2) -> dict:
    params = SimParams.from_json(cal_path)
    cal_rows = zs.calibration_rows(session, zs.read_calibration(cal_path))
    cache.mkdir(parents=True, exist_ok=True)
    virtual, _ = zs.virtual_set(params, session, cache / f"virtual-{n_virtual}-s{seed}", n_virtual, seed, 2, False)
    site = zs.twin_site_map(params, session, cache, False)
    model, _ = train(virtual, None, test_fraction=0.0, seed=seed, site_map=site)
    virtual_fit = copy.deepcopy(model.twin_fit)
    train_rows, test_rows = case_split(session.case_id, 0.2, seed, cal_rows)
    cal_sim = zs.calibration_twins(params, session, cal_rows, seed, 2)
    zs.fit_on_calibration_drops(model, session, cal_rows, cal_sim, site, virtual)

    f = featurize(session.adc, model.signal)       # every drop as the adapted model reads it
    feats, usable = twin_features(f)
    start = model.predict(f)["forest_xy_mm"]
    h, lh = session.height_mm, np.log10(session.height_mm)
    slope = np.asarray(virtual_fit.slope)
    xy = session.xy_mm

    def before(fe, us, p, hh):
        return fit_twin(fe, us, site, p, hh, slope=slope)

    def product(fe, us, p, hh):
        return fit_twin(fe, us, site, p, hh, slope=slope, weight_shape=np.asarray(virtual_fit.weight),
                        additive_offsets=True)

    c = cal_rows
    many = before(feats[train_rows], usable[train_rows], xy[train_rows], h[train_rows])
    fits = {"before": replace(model.twin_fit, **_fields(before(feats[c], usable[c], xy[c], h[c]))),
            "product": model.twin_fit,
            "many drops": replace(model.twin_fit, **_fields(many))}
    label = (impact_energy_j(h, session.rig.ball_mass_g) >= model.energy_threshold_j).astype(int)
    rest = np.setdiff1d(np.arange(len(session)), cal_rows)
    edge = edge_distance_mm(session)
    out = {"seed": seed, "fits": {}}
    for name, fit in fits.items():
        est = estimate(site, fit, feats[rest], usable[rest], start[rest])
        e = np.asarray(est["log10_height_mm"], float)
        ok = np.isfinite(e)
        cls = np.full(rest.size, -1)
        cls[ok] = model.forest_energy.predict(e[ok, None])
        in_test = np.isin(rest, test_rows)
        err = e - lh[rest]
        r = {"acc_test": float(np.mean(cls[in_test] == label[rest][in_test])),
             "acc_all": float(np.mean(cls == label[rest])),
             "test": decompose(err[in_test], session.case_id[rest][in_test]),
             "all": decompose(err, session.case_id[rest]),
             "mae_mm": float(np.nanmean(np.abs(np.asarray(est["xy_mm"], float) - xy[rest])[in_test])),
             "edge": [(float(np.nanmean(err[m])), float(np.nanstd(err[m])), int(m.sum()))
                      for m in ((edge[rest] >= a) & (edge[rest] < b) for a, b in zip(EDGE_BINS_MM, EDGE_BINS_MM[1:]))],
             "boundary": {int(v): float(np.nanmean(err[h[rest] == v])) for v in (165, 170, 175, 180)},
             "implied_bias": implied_bias(fit, many)}
        if name != "many drops":
            fitter = before if name == "before" else product
            r["held_out"] = held_out_by_position(site, feats[c], usable[c], xy[c], h[c], start[c], fitter)
        out["fits"][name] = r
    out["eval"] = {}
    for name in ("before", "product"):   # the whole model's figures with each fit
        m = replace(model, twin_fit=fits[name])
        rep = evaluate(session, m, rows=test_rows)
        out["eval"][name] = {"class": rep["energy_class_accuracy"], "mae": rep["all"]["mae_mm"],
                             "mae_inner": rep["inner"]["mae_mm"]}
        if session2 is not None:
            rep2 = evaluate(session2, m, rows=np.arange(len(session2)))
            out["eval"][name].update(s2_class=rep2["energy_class_accuracy"], s2_mae=rep2["all"]["mae_mm"])
    out["p50_mm"] = stump_p50_mm(model)
    out["uncertainty"] = zs.uncertainty_figures(session, model, test_rows)
    if measured:
        meas, _ = train(session, None, 0.2, seed, exclude_rows=cal_rows, site_map=site)
        repm = evaluate(session, meas, rows=test_rows)
        out["measured"] = {"class": repm["energy_class_accuracy"], "mae": repm["all"]["mae_mm"]}
    out["n_test"], out["n_all"] = int(test_rows.size), int(rest.size)
    out["n_boundary_test"] = {int(v): int(np.sum(h[test_rows] == v)) for v in (170, 175)}
    return out


def _fields(fit) -> dict:
    return {"offset": fit.offset, "weight": fit.weight}


def stump_p50_mm(model) -> float:
    """Where the bagged stumps call 'high' with probability 0.5 (mm)."""
    g = np.linspace(np.log10(150.0), np.log10(200.0), 5001)
    return float(10 ** g[np.argmax(model.forest_energy.predict_proba(g[:, None])[:, 1] >= 0.5)])


def report(rows: list[dict]) -> None:
    names = list(rows[0]["fits"])
    print("\nper seed (test split; all = every drop but the calibration drops):")
    for r in rows:
        b = r["n_boundary_test"]
        print(f"seed {r['seed']}: {r['n_test']} test drops ({b[170]} at 170 mm, {b[175]} at 175 mm), "
              f"stumps' 50 % at {r['p50_mm']:.1f} mm (boundary {np.sqrt(170 * 175):.1f})")
        for name in names:
            x = r["fits"][name]
            t, a = x["test"], x["all"]
            ho = x.get("held_out")
            print(f"  {name:10s} class test {x['acc_test']:.3f} all {x['acc_all']:.3f} | e test: bias {t[0]:+.4f} "
                  f"case sd {t[1]:.4f} within {t[2]:.4f}; all: {a[0]:+.4f} / {a[1]:.4f} / {a[2]:.4f} | "
                  f"offsets' bias vs many drops {x['implied_bias']:+.4f} | twin MAE {x['mae_mm']:.2f} mm"
                  + ("" if ho is None else " | calibration held out by position: " + " ".join(f"{v:+.4f}" for v in ho)
                     + f" (rms {np.sqrt(np.mean(ho ** 2)):.4f})"))
        for name, ev in r["eval"].items():
            line = f"  {name} evaluate: class {ev['class']:.3f}, MAE {ev['mae']:.2f} mm (inner {ev['mae_inner']:.2f})"
            if "s2_class" in ev:
                line += f" | session-2 (all drops): class {ev['s2_class']:.3f}, MAE {ev['s2_mae']:.2f} mm"
            print(line)
        u = r["uncertainty"]
        print(f"  product uncertainty_mm on the test split: within 1x {u['within_1x']:.2f}, 2x {u['within_2x']:.2f}, "
              f"rms(r / u) {u['rms_error_over_u']:.2f} (0.63 / 0.98 / 1 if calibrated)")
        if "measured" in r:
            print(f"  measured-trained evaluate: class {r['measured']['class']:.3f}, MAE {r['measured']['mae']:.2f} mm")
    print("\nover the seeds (mean):")
    for name in names:
        fx = [r["fits"][name] for r in rows]
        edge = np.mean([[m for m, _, _ in x["edge"]] for x in fx], axis=0)
        sd = np.mean([[s for _, s, _ in x["edge"]] for x in fx], axis=0)
        bnd = {v: np.mean([x["boundary"][v] for x in fx]) for v in (165, 170, 175, 180)}
        print(f"  {name:10s} class test " + " ".join(f"{x['acc_test']:.3f}" for x in fx)
              + f" (min {min(x['acc_test'] for x in fx):.3f}) | all " + " ".join(f"{x['acc_all']:.3f}" for x in fx))
        print(f"  {'':10s} e (all drops) by edge distance {EDGE_BINS_MM} mm: mean "
              + " ".join(f"{v:+.4f}" for v in edge) + ", sd " + " ".join(f"{v:.4f}" for v in sd)
              + " | at 165/170/175/180 mm: " + " ".join(f"{v:+.4f}" for v in bnd.values()))
    if "measured" in rows[0]:
        print("  measured-trained class test " + " ".join(f"{r['measured']['class']:.3f}" for r in rows))
    for name in rows[0]["eval"]:
        ev = [r["eval"][name] for r in rows]
        print(f"  {name:10s} evaluate MAE " + " ".join(f"{e['mae']:.2f}" for e in ev) + " mm"
              + ("" if "s2_class" not in ev[0] else " | session-2 class " + " ".join(f"{e['s2_class']:.3f}" for e in ev)
                 + ", MAE " + " ".join(f"{e['s2_mae']:.2f}" for e in ev) + " mm"))


TARGET = {"mae": 5.0, "mae_inner": 3.5, "class": 0.95}    # issue 4: MAE <= 5 / 3.5 mm, class >= 0.95


def target_misses(rows: list[dict]) -> list[str]:
    """The seeds on which the product model's evaluate figures miss issue 4's targets (empty: met)."""
    out = []
    for r in rows:
        ev = r["eval"]["product"]
        for k, bound in TARGET.items():
            if (ev[k] < bound) if k == "class" else (ev[k] > bound):
                out.append(f"seed {r['seed']}: {k} {ev[k]:.3f} (target {'>=' if k == 'class' else '<='} {bound})")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calibration", default=str(BUNDLED.parent / "calibration.json"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--cache", default="/tmp/impactsense-bench-zeroshot-class")
    ap.add_argument("--virtual", type=int, default=490)
    ap.add_argument("--no-measured", action="store_true", help="skip the measured-trained model")
    ap.add_argument("--no-session2", action="store_true")
    args = ap.parse_args()
    cal_path = Path(args.calibration).resolve()
    cache = Path(args.cache) / hashlib.sha256(cal_path.read_bytes()).hexdigest()[:12]
    session = load_session("bundled:session-1")
    session2 = None if args.no_session2 else load_session("bundled:session-2")
    print(f"calibration {cal_path} (cache {cache})", flush=True)
    rows = []
    for seed in args.seeds:
        rows.append(run_seed(session, cal_path, seed, cache, args.virtual, not args.no_measured, session2))
        print(f"seed {seed} done", flush=True)
    report(rows)
    missed = target_misses(rows)
    print("target (issue 4, the product model on every seed's test split): MAE <= 5 mm, inner <= 3.5 mm, "
          "class >= 0.95: " + ("met" if not missed else "MISSED: " + "; ".join(missed)))
    return 1 if missed else 0


if __name__ == "__main__":
    raise SystemExit(main())
