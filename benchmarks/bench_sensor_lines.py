"""Where the position error lies against the sensors' geometry: the lines through two sensors, the TDOA dilution,
the plate's edges; and whose error it is there (the physics localiser's or what the forests leave).

    python3 benchmarks/bench_sensor_lines.py [--rigs-dir DIR] [--seeds 4] [--skip-bundled] [--json OUT.json]
                                             [--save DIR] [--load DIR]

Per session folder and split seed: `train` + `evaluate` as bench_rigs.score calls them (100 trees, held-out 20 %),
then per held-out drop, at its true position p:
- "line": the distance to the nearest of the six lines through two sensors (the pair's hyperbola is flat beyond
  the pair and its delay says nothing about the position across the line near it);
- "dilution": 1 / sqrt(smallest eigenvalue of J^T J), J's rows u_c - mean_c u_c, u_c the unit vector from sensor c
  to p (one wave speed): how many mm the position moves along its worst direction per mm of centred path error;
- "edge": the distance to the nearest plate edge.
Printed per seed: the physics and reported (evaluate's) MAE per axis by band of each, the share of the seed's
error, "bias": the MAE per axis of each drop's case mean (the part of the reported error a site's repetitions
share), the reported error's components along / across the worst direction (mm, absolute), and the four worst held-out cases
(their mean physics and reported offsets). Then per rig (without --load), every case's mean physics offset under
seed 0's localiser against the inverse-distance mean of its 3 nearest cases' ("left": what a correction read from
neighbour sites leaves; as large as the offset itself: the offset is the site's own, no smooth field carries it).
--save DIR writes each seed's held-out arrays; --load DIR reads them
instead of training (the same figures without the forests' time).

A study: nothing here changes the product; exit 0. Figures: docs/findings.md, "Session 20: sensorline".
"""

from __future__ import annotations

import json
import sys
from itertools import combinations
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import rig_study_args, rig_study_sessions  # noqa: E402

LINE_BANDS_MM = (10.0, 26.0)       # within 10 mm, 10-26 mm (the farthest of rigcclass's nine worst sites), beyond
DILUTION_BANDS = (1.5, 3.0)
EDGE_BAND_MM = 80.0
NEIGHBOURS = 3


def line_distance(xy_mm: np.ndarray, sensors_mm: np.ndarray) -> np.ndarray:
    """Each point's distance to the nearest of the lines through two sensors."""
    d = []
    for i, j in combinations(range(len(sensors_mm)), 2):
        a, b = sensors_mm[i], sensors_mm[j]
        n = np.array([b[1] - a[1], a[0] - b[0]]) / np.linalg.norm(b - a)
        d.append(np.abs((xy_mm - a) @ n))
    return np.min(d, axis=0)


def dilution(xy_mm: np.ndarray, sensors_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the worst direction's dilution, that direction as a unit vector) of the centred TDOA at each point."""
    out, direction = np.empty(len(xy_mm)), np.empty((len(xy_mm), 2))
    for k, p in enumerate(xy_mm):
        u = p - sensors_mm
        u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-9)
        j = u - u.mean(0)
        w, v = np.linalg.eigh(j.T @ j)
        out[k], direction[k] = 1.0 / np.sqrt(max(w[0], 1e-12)), v[:, 0]
    return out, direction


def edge_distance(xy_mm: np.ndarray, plate_mm) -> np.ndarray:
    x, y = xy_mm[:, 0], xy_mm[:, 1]
    return np.minimum.reduce([x, plate_mm[0] - x, y, plate_mm[1] - y])


def held_out_arrays(path: str, seed: int) -> dict:
    """The held-out arrays of bench_rigs.score's train + evaluate (no calibration, no twin edge)."""
    from impactsense.data import load_session
    from impactsense.models import ForestSettings
    from impactsense.sitemap import resolve_site_map
    from impactsense.workflow import evaluate, train

    s = load_session(path)
    model, _ = train(s, None, 0.2, seed, None, ForestSettings(n_estimators=100, seed=seed),
                     site_map=resolve_site_map("auto", s.rig), choose_twin=False, choose_class=True)
    a = evaluate(s, model)["_arrays"]
    return {"name": s.name, "true_xy": a["true_xy"], "pred_xy": a["pred_xy"], "phys_xy": a["phys_xy"],
            "case": s.case_id[a["rows"]], "sensors": s.rig.sensor_xy_mm.astype(float),
            "plate": np.array([s.rig.plate_x_mm, s.rig.plate_y_mm])}


def band_rows(a: dict) -> dict:
    """Per band of line distance, dilution and edge distance: drops, physics and reported MAE per axis, share."""
    t, ph, pr = a["true_xy"], a["phys_xy"], a["pred_xy"]
    ok = np.isfinite(pr).all(1) & np.isfinite(ph).all(1)
    line = line_distance(t, a["sensors"])
    dil, worst = dilution(t, a["sensors"])
    edge = edge_distance(t, a["plate"])
    ep, er = np.abs(ph - t).mean(1), np.abs(pr - t).mean(1)
    # each drop's case mean of the reported offset: the part of the error its repetitions share (a site's bias)
    bias = np.full(len(t), np.nan)
    for c in np.unique(a["case"][ok]):
        m = ok & (a["case"] == c)
        bias[m] = np.abs((pr[m] - t[m]).mean(0)).mean()
    along = np.abs(np.sum((pr - t) * worst, 1))
    across = np.abs(np.sum((pr - t) * np.stack([-worst[:, 1], worst[:, 0]], 1), 1))
    l1, l2 = LINE_BANDS_MM
    d1, d2 = DILUTION_BANDS
    near_line = line < l2
    bands = {
        f"line < {l1:.0f}": line < l1, f"line {l1:.0f}-{l2:.0f}": (line >= l1) & (line < l2),
        f"line >= {l2:.0f}": line >= l2,
        f"dilution < {d1}": dil < d1, f"dilution {d1}-{d2}": (dil >= d1) & (dil < d2), f"dilution >= {d2}": dil >= d2,
        f"edge < {EDGE_BAND_MM:.0f}, line < {l2:.0f}": (edge < EDGE_BAND_MM) & near_line,
        f"edge < {EDGE_BAND_MM:.0f}, line >= {l2:.0f}": (edge < EDGE_BAND_MM) & ~near_line,
        f"edge >= {EDGE_BAND_MM:.0f}, line < {l2:.0f}": (edge >= EDGE_BAND_MM) & near_line,
        f"edge >= {EDGE_BAND_MM:.0f}, line >= {l2:.0f}": (edge >= EDGE_BAND_MM) & ~near_line,
    }
    total = er[ok].sum()
    out = {"all": {"n": int(ok.sum()), "physics_mm": float(ep[ok].mean()), "reported_mm": float(er[ok].mean())}}
    for k, m in bands.items():
        m = m & ok
        if m.any():
            out[k] = {"n": int(m.sum()), "physics_mm": float(ep[m].mean()), "reported_mm": float(er[m].mean()),
                      "share": float(er[m].sum() / total), "site_bias_mm": float(bias[m].mean()),
                      "along_worst_mm": float(along[m].mean()),
                      "across_worst_mm": float(across[m].mean())}
    cases = []
    for c in np.unique(a["case"][ok]):
        m = ok & (a["case"] == c)
        cases.append({"xy": [float(v) for v in t[m][0]], "drops": int(m.sum()), "reported_mm": float(er[m].mean()),
                      "physics_mm": float(ep[m].mean()), "line_mm": float(line[m][0]), "edge_mm": float(edge[m][0]),
                      "dilution": float(dil[m][0]),
                      "physics_offset": [float(v) for v in (ph[m] - t[m]).mean(0)],
                      "reported_offset": [float(v) for v in (pr[m] - t[m]).mean(0)]})
    out["worst_cases"] = sorted(cases, key=lambda r: -r["reported_mm"])[:4]
    return out


def physics_offsets(path: str, seed: int) -> dict:
    """Every case's mean physics offset (position - truth) under the localiser fitted on the seed's training cases
    (fit_localiser without the forests' band choice), its drops' scatter about their mean, and its position."""
    from impactsense.data import load_session
    from impactsense.pipeline import featurize, fit_localiser
    from impactsense.signal import SignalConfig
    from impactsense.split import case_split

    s = load_session(path)
    train_rows, _ = case_split(s.case_id, 0.2, seed, None)
    phys = featurize(s.adc, fit_localiser(s, train_rows, SignalConfig.for_rig(s.rig))).phys_xy_mm.astype(float)
    xy = np.asarray(s.xy_mm, float)
    offset, where, scatter = [], [], []
    for c in np.unique(s.case_id):
        m = (s.case_id == c) & np.isfinite(phys).all(1)
        if m.any():
            offset.append((phys[m] - xy[m]).mean(0))
            where.append(xy[m][0])
            scatter.append(np.abs(phys[m] - phys[m].mean(0)).mean())
    return {"offset": np.array(offset), "xy": np.array(where), "scatter": np.array(scatter),
            "sensors": s.rig.sensor_xy_mm.astype(float), "plate": np.array([s.rig.plate_x_mm, s.rig.plate_y_mm])}


def neighbour_rows(p: dict, k: int = NEIGHBOURS) -> dict:
    """How smooth the physics offset is over the plate: per band, the cases' mean |offset| per axis, their drops'
    scatter, and what is left of the offset after subtracting the inverse-distance mean of the k nearest other
    cases' offsets (a correction read from the neighbour sites; left >= offset: no smooth field holds it)."""
    xy, off = p["xy"], p["offset"]
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    np.fill_diagonal(d, np.inf)
    near = np.argsort(d, 1)[:, :k]
    w = 1.0 / d[np.arange(len(xy))[:, None], near]
    left = np.abs(off - (off[near] * w[..., None]).sum(1) / w.sum(1)[:, None]).mean(1)
    edge, line = edge_distance(xy, p["plate"]), line_distance(xy, p["sensors"])
    l2 = LINE_BANDS_MM[1]
    bands = {"all": np.ones(len(xy), bool), f"edge < {EDGE_BAND_MM:.0f}, line < {l2:.0f}": (edge < EDGE_BAND_MM) & (line < l2),
             f"edge < {EDGE_BAND_MM:.0f}, line >= {l2:.0f}": (edge < EDGE_BAND_MM) & (line >= l2),
             f"edge >= {EDGE_BAND_MM:.0f}, line < {l2:.0f}": (edge >= EDGE_BAND_MM) & (line < l2),
             f"edge >= {EDGE_BAND_MM:.0f}, line >= {l2:.0f}": (edge >= EDGE_BAND_MM) & (line >= l2)}
    return {b: {"cases": int(m.sum()), "offset_mm": float(np.abs(off[m]).mean()), "scatter_mm": float(p["scatter"][m].mean()),
                "left_mm": float(left[m].mean()), "nearest_mm": float(d[m].min(1).mean())}
            for b, m in bands.items() if m.any()}


def print_seed(name: str, seed: int, r: dict) -> None:
    a = r["all"]
    print(f"\n== {name} seed {seed}: {a['n']} held-out drops, MAE per axis physics {a['physics_mm']:.2f} "
          f"reported {a['reported_mm']:.2f} mm")
    print(f"  {'band':28s} {'drops':>5s} {'physics':>8s} {'reported':>8s} {'share':>6s} {'bias':>6s} {'along':>6s} {'across':>6s}")
    for k, v in r.items():
        if k in ("all", "worst_cases"):
            continue
        print(f"  {k:28s} {v['n']:5d} {v['physics_mm']:8.2f} {v['reported_mm']:8.2f} {v['share']:6.2f} {v['site_bias_mm']:6.2f} "
              f"{v['along_worst_mm']:6.2f} {v['across_worst_mm']:6.2f}")
    for c in r["worst_cases"]:
        print(f"  worst ({c['xy'][0]:.0f}, {c['xy'][1]:.0f}) x{c['drops']}: reported {c['reported_mm']:.1f} "
              f"physics {c['physics_mm']:.1f} mm; line {c['line_mm']:.0f} edge {c['edge_mm']:.0f} mm dilution "
              f"{c['dilution']:.1f}; offsets physics ({c['physics_offset'][0]:+.1f}, {c['physics_offset'][1]:+.1f}) "
              f"reported ({c['reported_offset'][0]:+.1f}, {c['reported_offset'][1]:+.1f})")


def main(argv=None) -> int:
    import argparse

    extra = argparse.ArgumentParser(add_help=False)
    extra.add_argument("--save", default=None)
    extra.add_argument("--load", default=None)
    more, rest = extra.parse_known_args(argv)
    a = rig_study_args(__doc__.splitlines()[0], rest)
    report = {}
    for path in rig_study_sessions(a):
        name = Path(path).name if path != "bundled" else "bundled"
        for seed in range(a.seeds):
            if more.load:
                saved = Path(more.load) / f"{name}_s{seed}.npz"
                if not saved.is_file():
                    print(f"{saved}: not there, skipped")
                    continue
                arrays = dict(np.load(saved))
            else:
                arrays = held_out_arrays(path, seed)
                if more.save:
                    Path(more.save).mkdir(parents=True, exist_ok=True)
                    np.savez(Path(more.save) / f"{name}_s{seed}.npz",
                             **{k: v for k, v in arrays.items() if k != "name"})
            r = band_rows(arrays)
            report.setdefault(name, []).append(r)
            print_seed(name, seed, r)
        if not more.load:
            nb = neighbour_rows(physics_offsets(path, 0))
            report.setdefault(f"{name} neighbours", nb)
            print(f"\n== {name}: every case's physics offset (seed 0's localiser) against its {NEIGHBOURS} nearest cases'")
            print(f"  {'band':28s} {'cases':>5s} {'offset':>7s} {'scatter':>7s} {'left':>6s} {'nearest':>7s}")
            for b, v in nb.items():
                print(f"  {b:28s} {v['cases']:5d} {v['offset_mm']:7.2f} {v['scatter_mm']:7.2f} {v['left_mm']:6.2f} "
                      f"{v['nearest_mm']:7.1f}")
    if a.json:
        Path(a.json).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
