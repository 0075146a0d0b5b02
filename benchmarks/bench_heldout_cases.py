"""Which held-out drops carry a measured-trained model's position error, and does the edge reflections' phase explain
the per-case timing bias that is left.

    impactsense train DATA --out M --seed S          # the model bench_rigs.py scores on split seed S
    python3 benchmarks/bench_heldout_cases.py DATA --model M [--cases 12] [--no-interference]

Part 1, the held-out drops (`evaluate DATA --model M`'s rows; MAE per axis, mm): the cases that carry most of the
absolute error (share, cumulative share, declared position and height, distance to the nearest edge and sensor,
reported and physics MAE, the case's mean error vector, its class accuracy); the same by distance to the nearest
edge, inside / outside the sensors' hull, and the wrong-class drops with their heights and the class threshold's two
boundary heights (the highest training height below the threshold and the lowest at or above it).

Part 2, every drop of DATA at its declared position: each pick set's centred travel residual (the model's travel law,
edge_travel.pick_set_arrivals), its per-case part (the mean over a case's repeats) and the part of the per-case
variance that site-grouped 5-fold least squares (Huber, as edge_travel.fit_correction) explains out of fold with
(a) edge_travel's bases (distance, distance^2 and the edge images' exp(-(d_image - d) / L)), and (b) those plus
the images' phase: exp(-delta / L) cos(2 pi delta / lambda) and sin(...), delta = d_image - d, lambda = alpha v T
(T the channel's picked period, v the pick set's velocity) for a range of alpha. If the per-case bias were the
interference of an edge's reflection with the direct arrival (a shift of the picked cycle that turns with the
reflected path's extra length in wavelengths), (b) would explain more than (a) at some alpha.
No file is written and nothing is tuned (docs/findings.md "Session 27: rigcmt" reads it).
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

ALPHAS = (0.3, 0.4, 0.5, 0.6, 0.7, 0.85, 1.0, 1.2)
PHASE_SCALES_MM = (30.0, 80.0)
EDGE_BANDS_MM = ((0, 35), (35, 60), (60, 80), (80, np.inf))


def edge_distance(xy: np.ndarray, rig) -> np.ndarray:
    return np.minimum.reduce([xy[:, 0], rig.plate_x_mm - xy[:, 0], xy[:, 1], rig.plate_y_mm - xy[:, 1]])


def inside_hull(xy: np.ndarray, sensors: np.ndarray) -> np.ndarray:
    from scipy.spatial import Delaunay

    return Delaunay(sensors).find_simplex(xy) >= 0


def heldout_parts(session, model, n_cases: int) -> None:
    from impactsense.workflow import evaluate

    rep = evaluate(session, model)
    a = rep["_arrays"]
    rows, true, pred, phys = a["rows"], a["true_xy"], a["pred_xy"], a["phys_xy"]
    ok = np.isfinite(pred).all(1)
    case, height = session.case_id[rows], session.height_mm[rows]
    err = np.abs(pred - true)
    total = err[ok].sum()
    edge = edge_distance(true, session.rig)
    sensors = np.asarray(model.signal.sensor_xy_mm, float)
    near_sensor = np.min(np.linalg.norm(true[:, None] - sensors[None], axis=2), 1)
    right = a["energy_class"] == a["label"]
    print(f"{session.name}: {len(rows)} held-out drops, MAE {err[ok].mean():.2f} mm (physics "
          f"{np.abs(phys - true)[ok].mean():.2f}), class {right[ok].mean():.3f}")
    table = []
    for c in np.unique(case):
        m = (case == c) & ok
        if m.any():
            table.append((err[m].sum() / total, c, m))
    table.sort(key=lambda t: -t[0])
    print("  share  cum  case  n  declared (x, y)  height  edge  sensor  MAE  physics  mean error (x, y)  class")
    cum = 0.0
    for share, c, m in table[:n_cases]:
        cum += share
        i = np.flatnonzero(m)[0]
        e = (pred[m] - true[m]).mean(0)
        print(f"  {share:5.3f} {cum:4.2f} {c:5d} {m.sum():2d}  ({true[i, 0]:5.1f}, {true[i, 1]:5.1f})  {height[i]:6.0f}"
              f"  {edge[i]:4.0f}  {near_sensor[i]:6.0f}  {err[m].mean():5.2f}  {np.abs(phys[m] - true[m]).mean():6.2f}"
              f"  ({e[0]:+6.1f}, {e[1]:+6.1f})  {right[m].mean():.2f}")
    for lo, hi in EDGE_BANDS_MM:
        m = ok & (edge >= lo) & (edge < hi)
        if m.any():
            print(f"  edge {lo:.0f}-{hi:.0f} mm: {m.sum()} drops, MAE {err[m].mean():.2f} (physics "
                  f"{np.abs(phys - true)[m].mean():.2f}), {err[m].sum() / total:.2f} of the error, class {right[m].mean():.3f}")
    hull = inside_hull(true, sensors)
    for name, m in (("inside the sensors' hull", ok & hull), ("outside", ok & ~hull)):
        if m.any():
            print(f"  {name}: {m.sum()} drops, MAE {err[m].mean():.2f}, {err[m].sum() / total:.2f} of the error")
    train_h = np.unique(session.height_mm[np.setdiff1d(np.arange(len(session)), rows)])
    from impactsense.models import impact_energy_j

    above = impact_energy_j(train_h, session.rig.ball_mass_g) >= model.energy_threshold_j
    bounds = (train_h[~above].max() if (~above).any() else np.nan, train_h[above].min() if above.any() else np.nan)
    wrong = ok & ~right
    print(f"  wrong class: {wrong.sum()} drops, cases {sorted(set(case[wrong].tolist()))}, heights "
          f"{sorted(height[wrong].tolist())}; the boundary heights {bounds[0]:.0f} / {bounds[1]:.0f} mm")


def site_folds(case: np.ndarray, rows: np.ndarray, k: int = 5) -> np.ndarray:
    sites = np.random.default_rng(0).permutation(np.unique(case[rows]))
    fold = {c: i % k for i, c in enumerate(sites)}
    return np.array([fold.get(c, -1) for c in case])


def huber_fit(a: np.ndarray, y: np.ndarray, huber_us: float) -> np.ndarray:
    weight = np.ones(len(y))
    for _ in range(10):
        root = np.sqrt(weight)
        coef = np.linalg.lstsq(a * root[:, None], y * root, rcond=None)[0]
        weight = np.minimum(1.0, huber_us / np.maximum(np.abs(y - a @ coef), 1e-9))
    return coef


def explained_out_of_fold(bases: np.ndarray, resid: np.ndarray, per_case: np.ndarray, rows: np.ndarray,
                          fold: np.ndarray, huber_us: float) -> float:
    """The share of the per-case residual's variance the bases' out-of-fold prediction removes."""
    b = bases - bases.mean(1, keepdims=True)
    pred = np.full_like(resid, np.nan)
    for k in range(fold.max() + 1):
        fit, held = rows & (fold != k), rows & (fold == k)
        coef = huber_fit(b[fit].reshape(-1, b.shape[2]), resid[fit].ravel(), huber_us)
        pred[held] = b[held] @ coef
    left = per_case[rows] - pred[rows]
    return float(1.0 - np.var(left) / np.var(per_case[rows]))


def phase_bases(xy: np.ndarray, signal, pick_set: str, period_us: np.ndarray, v: float, alpha: float) -> np.ndarray:
    from impactsense.edge_travel import _metric
    from impactsense.travel import travel_distances

    metric = _metric(signal, pick_set)
    d = travel_distances(xy, signal.sensor_xy_mm, metric)
    w, h = float(signal.plate_x_mm), float(signal.plate_y_mm)
    x, y = xy[:, 0], xy[:, 1]
    pairs = ((np.c_[-x, y], np.c_[2 * w - x, y]), (np.c_[x, -y], np.c_[x, 2 * h - y]))
    lam = alpha * v * period_us
    cols = []
    for scale in PHASE_SCALES_MM:
        for pair in pairs:
            extra = [travel_distances(m, signal.sensor_xy_mm, metric) - d for m in pair]
            cols.append(sum(np.exp(-e / scale) * np.cos(2 * np.pi * e / lam) for e in extra))
            cols.append(sum(np.exp(-e / scale) * np.sin(2 * np.pi * e / lam) for e in extra))
    return np.stack(cols, 2)


def interference(session, model) -> None:
    from impactsense import edge_travel as et
    from impactsense.pipeline import featurize
    from impactsense.travel import travel_distances

    signal = model.signal
    raw = featurize(session.adc, signal).raw
    xy, case = session.xy_mm, session.case_id
    period = np.asarray(raw["pick_period"], float) / signal.fs_hz * 1e6
    period = np.where(np.isfinite(period) & (period > 0), period, np.nanmedian(period))
    for pick_set in et.PICK_SETS:
        if pick_set == "band" and not (float(signal.band_pick_hz) > 0 and float(signal.band_velocity_mm_per_us) > 0):
            continue
        toa, use, scale, v = et.pick_set_arrivals(raw, signal, pick_set)
        resid = toa - travel_distances(xy, signal.sensor_xy_mm, et._metric(signal, pick_set)) * scale / v
        rows = use.all(1) & np.isfinite(resid).all(1)
        resid = resid - resid.mean(1, keepdims=True)
        per_case = np.full_like(resid, np.nan)
        for c in np.unique(case[rows]):
            m = rows & (case == c)
            per_case[m] = resid[m].mean(0)
        fold = site_folds(case, rows)
        base = et.travel_bases(xy, signal, pick_set)
        plain = explained_out_of_fold(base, resid, per_case, rows, fold, et.HUBER_US)
        print(f"{session.name} {pick_set} picks ({rows.sum()} drops, median period {np.median(period):.1f} us, v "
              f"{v:.3f} mm/us): per-case sd {np.std(per_case[rows]):.2f} us, within a case "
              f"{np.std((resid - per_case)[rows]):.2f} us")
        print(f"  out of fold, share of the per-case variance explained: edge_travel's bases {plain:.3f}")
        with_phase = []
        for alpha in ALPHAS:
            both = np.concatenate([base, phase_bases(xy, signal, pick_set, period, v, alpha)], 2)
            with_phase.append(explained_out_of_fold(both, resid, per_case, rows, fold, et.HUBER_US))
        print("  + the images' phase, alpha " + " ".join(f"{a:g}: {e:.3f}" for a, e in zip(ALPHAS, with_phase)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data")
    ap.add_argument("--model", required=True, help="a model trained on DATA (`impactsense train DATA --out M`)")
    ap.add_argument("--cases", type=int, default=12)
    ap.add_argument("--no-interference", action="store_true", help="part 1 only")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", category=UserWarning)
    from impactsense.data import load_session
    from impactsense.models import ImpactModel

    session, model = load_session(args.data), ImpactModel.load(args.model)
    heldout_parts(session, model, args.cases)
    if not args.no_interference:
        interference(session, model)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
