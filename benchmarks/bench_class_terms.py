"""The linear height estimate's position terms against physical alternatives, per split (measured, nothing chosen).

    impactsense train DATA --out M                     # any model of DATA: only its signal configuration is read
    python3 benchmarks/bench_class_terms.py DATA --model M [--seeds 0 1 2 3]

height_class.py's estimate of log(m g h) reads the core's summed arrival energies, the channels' mean log energy and
a cubic in the physics position. Re-fitted here in Python the same way (ridge over standardised terms, the class cut
between the training energies either side of their 75th percentile) with other position terms:
- "arrival sum only": the summed arrival energy alone (no position term);
- "energies only": the five energy inputs, no position term;
- "+ log r_i": each sensor's log distance from the physics position (geometric spreading: the summed arrival energy
  is dominated by the nearest sensor), with and without the cubic;
- "+ image mobility L": the impact's input mobility near an edge as an image source, sum over each pair of opposite
  edges of J0(2 k d) (d the distance to the edge, k = 2 pi / L scaled per axis by the travel metric), with the cubic;
- "cubic at the declared position": the product's form at the true position (the position's share of the misses).
Per split seed (the default 20 % case split): the training drops' position-grouped 5-fold out-of-fold class accuracy
(the figure a rule would choose by), the held-out drops' accuracy and the held-out cases classed wrong.
No file is written (docs/findings.md "Session 27: rigcmt").
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np


def energy_inputs(raw: dict) -> np.ndarray:
    """LINEAR_CLASS_FEATURES' five energy inputs from the core's per-channel energies (as event.cpp sums them)."""
    window = np.asarray(raw["window_energy"], float).sum(2)
    diff = np.asarray(raw["diff_energy"], float)
    energy = np.asarray(raw["energy"], float)
    return np.column_stack([np.log10(window.sum(1) + 1)] + [np.log10(diff[:, :, k].sum(1) + 1)
                                                             for k in range(diff.shape[2])]
                           + [np.mean(np.log10(energy + 1), 1)])


def fitter(X: np.ndarray, n_position: int, degree: int, energy_j: np.ndarray, threshold_j: float):
    """height_class.fit_linear_height_class's ridge with a chosen position degree; returns X -> class."""
    from sklearn.linear_model import RidgeCV

    from impactsense.height_class import _products, class_cut, design_terms

    offset, sd = X.mean(0), X.std(0)
    scale = 1.0 / np.where(sd > 0, sd, 1.0)
    terms = design_terms(X.shape[1], n_position, degree)
    D = _products((X - offset) * scale, terms)
    mu, dsd = D.mean(0), D.std(0)
    dsd = np.where(dsd > 0, dsd, 1.0)
    ridge = RidgeCV(alphas=np.logspace(-3, 3, 13)).fit((D - mu) / dsd, np.log(energy_j))
    cut = class_cut(energy_j, threshold_j)
    return lambda Xn: ridge.predict((_products((Xn - offset) * scale, terms) - mu) / dsd) > cut


def image_mobility(xy: np.ndarray, signal, wavelength_mm: float) -> np.ndarray:
    from scipy.special import j0

    k = 2 * np.pi / wavelength_mm
    kx, ky = k * np.sqrt(signal.travel_metric_xx), k * np.sqrt(signal.travel_metric_yy)
    w, h = float(signal.plate_x_mm), float(signal.plate_y_mm)
    x, y = np.clip(xy[:, 0], 0, w), np.clip(xy[:, 1], 0, h)
    return np.column_stack([j0(2 * kx * x) + j0(2 * kx * (w - x)), j0(2 * ky * y) + j0(2 * ky * (h - y))])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data")
    ap.add_argument("--model", required=True, help="a model of DATA (its signal configuration is read)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    args = ap.parse_args()
    warnings.filterwarnings("ignore", category=UserWarning)
    from sklearn.model_selection import GroupKFold

    from impactsense.data import load_session
    from impactsense.height_class import position_groups
    from impactsense.models import ImpactModel, impact_energy_j
    from impactsense.pipeline import featurize
    from impactsense.split import case_split
    from impactsense.travel import travel_distances

    session, model = load_session(args.data), ImpactModel.load(args.model)
    signal = model.signal
    feats = featurize(session.adc, signal)
    phys = np.nan_to_num(feats.phys_xy_mm)
    base = energy_inputs(feats.raw)
    metric = (signal.travel_metric_xx, signal.travel_metric_xy, signal.travel_metric_yy)
    log_r = np.log10(np.maximum(travel_distances(phys, signal.sensor_xy_mm, metric), 5.0))
    variants = {
        "product: energies + cubic (physics position)": (np.column_stack([base, phys]), 2, 3),
        "arrival sum only": (base[:, :1], 0, 0),
        "energies only": (base, 0, 0),
        "energies + log r_i": (np.column_stack([base, log_r]), 0, 0),
        "energies + log r_i + cubic": (np.column_stack([base, log_r, phys]), 2, 3),
        **{f"energies + image mobility {w:g} mm + cubic": (np.column_stack([base, image_mobility(phys, signal, w),
                                                                             phys]), 2, 3) for w in (60.0, 100.0)},
        "cubic at the declared position": (np.column_stack([base, session.xy_mm]), 2, 3),
    }
    energy = impact_energy_j(session.height_mm, session.rig.ball_mass_g)
    groups = position_groups(session.xy_mm)
    for seed in args.seeds:
        train, test = case_split(session.case_id, 0.2, seed, None)
        threshold = float(np.percentile(energy[train], 75))
        label = energy >= threshold
        print(f"{session.name} split seed {seed}: {len(test)} held-out drops")
        for name, (X, n_position, degree) in variants.items():
            right = np.zeros(len(energy), bool)
            for a, b in GroupKFold(5).split(X[train], groups=groups[train]):
                a, b = train[a], train[b]
                cut = float(np.percentile(energy[a], 75))
                right[b] = fitter(X[a], n_position, degree, energy[a], cut)(X[b]) == (energy[b] >= cut)
            held = fitter(X[train], n_position, degree, energy[train], threshold)(X[test]) == label[test]
            wrong = sorted(set(session.case_id[test][~held].tolist()))
            print(f"  {name:46s} out of fold {right[train].mean():.3f}  held out {held.mean():.3f}  wrong cases {wrong}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
