"""The energy class's floor on a measured session: how many class misses the hand-release scatter alone forces,
and what the linear height estimate's misses are made of (measured; nothing chosen).

    impactsense train DATA --out M                     # any model of DATA: its signal configuration is read
    python3 benchmarks/bench_class_floor.py DATA --model M [--seeds 0 1 2 3] [--splits 16]

The class label is the declared release height against the 75th percentile of the training drops' energies m g h.
A drop's true energy scatters about its declared height (the hand's release height, the ball's spin, where it
lands), so even an estimator that reads each drop's energy exactly would class a drop released at a boundary
height on the wrong side when that scatter crosses the cut. This prints:

1. The scatter. A case's repetitions share a site, a declared height and (for the product's estimate) its
   position terms; their spread about the case's mean is the drop-to-drop scatter of the release plus the
   estimate's own noise: an upper bound on the hand-release scatter in ln(m g h). Pooled within-case sd
   (dof-corrected) of ln of the core's summed arrival energy, of each channel's ln energy, and of the product's
   linear estimate (out of fold, position-grouped 5 folds over all drops).
2. The floor. Every drop's chance of crossing the cut at that scatter, Phi(-|ln h - cut| / sigma) (normal, the
   cut between the two boundary heights as height_class.class_cut places it): the class an estimator that knew
   each drop's true energy would reach, over all drops and over each split seed's held-out drops.
3. The product's misses (height_class.fit_linear_height_class on the core's LINEAR_CLASS_FEATURES, refitted here
   on each split's training drops): each held-out miss's distance from the cut in units of the scatter (a miss
   within 2 sigma of the cut is one the scatter can make), and the estimate's error split into the case's
   shared part and the drop's own.
4. The site part. The out-of-fold estimate's between-case sd and the class that a normal error of that sd (plus
   the scatter) gives on the session's heights: the bound the site offsets set for any estimator that cannot
   predict them.
5. Two ways to fit the same board form that change which site offsets the cubic follows, against the product's
   fit, on the split seeds and --splits random 80/20 case splits (paired difference +- its standard error):
   the ridge's alpha chosen by position-grouped 5-fold CV instead of leave-one-drop-out (a drop's repetitions
   at the same site are left in when it is left out, so leave-one-out rewards following the sites), and the
   position degree (0..3) chosen by the same grouped CV.
No file is written (docs/findings.md "Session 28: rigcclass").
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
from scipy.stats import norm

ALPHAS = np.logspace(-3, 3, 13)


def within_case_sd(values: np.ndarray, case: np.ndarray) -> float:
    """Pooled sd of values about their case's mean, dof-corrected (N - number of cases)."""
    values, case = np.asarray(values, float), np.asarray(case)
    ok = np.isfinite(values)
    values, case = values[ok], case[ok]
    _, inv = np.unique(case, return_inverse=True)
    means = np.bincount(inv, values) / np.bincount(inv)
    dof = len(values) - inv.max() - 1
    return float(np.sqrt(np.sum((values - means[inv]) ** 2) / dof))


def case_parts(err: np.ndarray, case: np.ndarray) -> tuple[float, float]:
    """(between-case sd of the case means of err, pooled within-case sd)."""
    _, inv = np.unique(case, return_inverse=True)
    means = np.bincount(inv, err) / np.bincount(inv)
    return float(np.std(means)), within_case_sd(err, case)


def floor_accuracy(log_e: np.ndarray, cut: float, sigma: float) -> float:
    """Expected class accuracy when each drop's ln energy scatters N(0, sigma) about its declared value."""
    return float(1.0 - np.mean(norm.cdf(-np.abs(np.asarray(log_e) - cut) / sigma)))


def design(X: np.ndarray, degree: int):
    """height_class's standardised product terms of X (energies linear, the last two columns to `degree`)."""
    from impactsense.height_class import _products, design_terms

    offset, sd = X.mean(0), X.std(0)
    scale = 1.0 / np.where(sd > 0, sd, 1.0)
    n_pos = 2 if degree > 0 else 0
    cols = X if degree > 0 else X[:, :-2]
    terms = design_terms(cols.shape[1], n_pos, degree) if degree > 0 else design_terms(cols.shape[1], 0, 0)

    def make(Xn):
        Xn = Xn if degree > 0 else Xn[:, :-2]
        return _products((Xn - offset[:Xn.shape[1]]) * scale[:Xn.shape[1]], terms)
    return make


def fit_estimate(X: np.ndarray, log_e: np.ndarray, degree: int = 3, groups: np.ndarray | None = None):
    """Ridge of log_e on design(X, degree): alpha by leave-one-out (the product's RidgeCV) or, with groups, by
    position-grouped 5-fold CV. Returns X -> estimate."""
    from sklearn.linear_model import RidgeCV
    from sklearn.model_selection import GroupKFold

    make = design(X, degree)
    D = make(X)
    mu, dsd = D.mean(0), D.std(0)
    dsd = np.where(dsd > 0, dsd, 1.0)
    cv = None if groups is None else list(GroupKFold(min(5, len(np.unique(groups)))).split(D, groups=groups))
    ridge = RidgeCV(alphas=ALPHAS, cv=cv).fit((D - mu) / dsd, log_e)
    return lambda Xn: ridge.predict((make(Xn) - mu) / dsd)


def grouped_oof(X, log_e, groups, fit, n_folds: int = 5) -> np.ndarray:
    from sklearn.model_selection import GroupKFold

    out = np.full(len(log_e), np.nan)
    for a, b in GroupKFold(n_folds).split(X, groups=groups):
        out[b] = fit(X[a], log_e[a], groups[a])(X[b])
    return out


def fitters():
    """name -> fit(X, log_e, groups) -> X -> estimate."""
    def degree_by_cv(X, y, g):     # g: the drops' position groups
        best = min(range(4), key=lambda d: np.mean((grouped_oof(X, y, g, lambda a, b, c: fit_estimate(a, b, d, c))
                                                    - y) ** 2))
        return fit_estimate(X, y, best, g)
    return {
        "product (cubic, alpha by leave-one-drop-out)": lambda X, y, g: fit_estimate(X, y, 3, None),
        "cubic, alpha by position-grouped CV": lambda X, y, g: fit_estimate(X, y, 3, g),
        "degree 0-3 and alpha by position-grouped CV": degree_by_cv,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data")
    ap.add_argument("--model", help="a model of DATA (its signal configuration is read; absent: the rig's default,"
                                    " SignalConfig.for_rig, without the travel law train fits)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--splits", type=int, default=16, help="random 80/20 case splits for part 5 (0: none)")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", category=UserWarning)

    from impactsense.data import load_session
    from impactsense.height_class import LINEAR_CLASS_FEATURES, class_cut, position_groups
    from impactsense.models import ImpactModel, columns, impact_energy_j
    from impactsense.pipeline import featurize
    from impactsense.signal import SignalConfig
    from impactsense.split import case_split

    session = load_session(args.data)
    signal = ImpactModel.load(args.model).signal if args.model else SignalConfig.for_rig(session.rig)
    feats = featurize(session.adc, signal)
    X = np.asarray(feats.vector[:, columns(LINEAR_CLASS_FEATURES)], float)
    ok = np.isfinite(X).all(1)
    energy = impact_energy_j(session.height_mm, session.rig.ball_mass_g)
    log_e = np.log(energy)
    case = np.asarray(session.case_id)
    groups = position_groups(session.xy_mm)
    rows = np.flatnonzero(ok)
    print(f"{session.name}: {len(energy)} drops, {ok.sum()} with every linear-class input, {len(np.unique(case))} cases,"
          f" heights {np.unique(session.height_mm).min():g}..{np.unique(session.height_mm).max():g} mm")

    # 1. the scatter
    ln10 = np.log(10.0)
    arrival = X[:, 0] * ln10           # log10 of the summed arrival energy -> ln
    per_channel = np.log(np.maximum(np.asarray(feats.energy, float), 1e-12))
    oof = np.full(len(energy), np.nan)
    oof[rows] = grouped_oof(X[rows], log_e[rows], groups[rows], lambda a, b, c: fit_estimate(a, b, 3, None))
    sds = {"summed arrival energy": within_case_sd(arrival[ok], case[ok]),
           **{f"channel {c} energy": within_case_sd(per_channel[ok, c], case[ok]) for c in range(per_channel.shape[1])},
           "product's estimate (out of fold)": within_case_sd(oof[ok], case[ok])}
    print("1. within-case sd of ln energy (upper bound on the hand-release scatter):")
    for k, v in sds.items():
        print(f"   {k:34s} {v:.4f}")
    sigma = min(sds.values())
    print(f"   scatter used below: sigma = {sigma:.4f} ln (the smallest: {min(sds, key=sds.get)})")

    # 2. the floor
    threshold_all = float(np.percentile(energy, 75))
    cut_all = class_cut(energy, threshold_all)
    heights = np.unique(session.height_mm)
    lo = heights[impact_energy_j(heights, session.rig.ball_mass_g) < threshold_all].max()
    hi = heights[impact_energy_j(heights, session.rig.ball_mass_g) >= threshold_all].min()
    nb = int(np.isin(session.height_mm, [lo, hi]).sum())
    print(f"2. floor: boundary heights {lo:g} / {hi:g} mm ({nb} drops), each {abs(np.log(hi / lo)) / 2:.4f} ln from the cut")
    for s in (sigma, 2 * sigma):
        print(f"   sigma {s:.4f}: all drops {floor_accuracy(log_e, cut_all, s):.4f} (expected misses "
              f"{len(energy) * (1 - floor_accuracy(log_e, cut_all, s)):.1f} of {len(energy)})")

    # 3. + 4. the product's held-out misses per split seed, the site part
    err = oof - log_e
    between, within = case_parts(err[ok], case[ok])
    print(f"3./4. product's estimate out of fold (all drops): rms {np.sqrt(np.nanmean(err ** 2)):.4f}, between-case sd "
          f"{between:.4f}, within-case {within:.4f}; a normal error of sd sqrt(between^2 + sigma^2) gives class "
          f"{floor_accuracy(log_e, cut_all, float(np.hypot(between, sigma))):.3f}; misses out of fold "
          f"{int(np.sum(((oof > cut_all) != (log_e > cut_all))[ok]))} of {ok.sum()}")
    for seed in args.seeds:
        train, test = case_split(case, 0.2, seed, None)
        train, test = train[ok[train]], test[ok[test]]
        threshold = float(np.percentile(energy[train], 75))
        cut = class_cut(energy[train], threshold)
        est = fit_estimate(X[train], log_e[train], 3, None)(X[test])
        wrong = (est > cut) != (log_e[test] > cut)
        z = np.abs(log_e[test] - cut) / sigma
        print(f"   split seed {seed}: held out {len(test)}, class {1 - wrong.mean():.3f}, floor "
              f"{floor_accuracy(log_e[test], cut, sigma):.3f}; misses {wrong.sum()}: within 2 sigma of the cut "
              f"{int(np.sum(wrong & (z < 2)))}, beyond {int(np.sum(wrong & (z >= 2)))}")
        for c in np.unique(case[test][wrong]):
            m = (case[test] == c)
            e = est[m] - log_e[test][m]
            print(f"      case {c:3d} ({session.xy_mm[test][m][0, 0]:5.1f}, {session.xy_mm[test][m][0, 1]:5.1f}) "
                  f"{session.height_mm[test][m][0]:g} mm: wrong {int(wrong[m].sum())} of {m.sum()}, |ln h - cut| "
                  f"{np.abs(log_e[test][m][0] - cut):.3f} = {z[m][0]:.1f} sigma, estimate error mean {e.mean():+.3f}"
                  f" (sd {e.std():.3f})")

    # 5. the two fits
    fits = fitters()
    split_seeds = list(args.seeds) + [1000 + k for k in range(args.splits)]
    acc = {name: [] for name in fits}
    for seed in split_seeds:
        train, test = case_split(case, 0.2, seed, None)
        train, test = train[ok[train]], test[ok[test]]
        threshold = float(np.percentile(energy[train], 75))
        cut = class_cut(energy[train], threshold)
        for name, fit in fits.items():
            est = fit(X[train], log_e[train], groups[train])(X[test])
            acc[name].append(float(np.mean((est > cut) == (log_e[test] > cut))))
    print("5. held-out class, split seeds " + ", ".join(map(str, args.seeds))
          + (f"; {args.splits} random case splits: mean, paired difference to the product +- se" if args.splits else ""))
    base = np.array(acc[next(iter(fits))])
    ns = len(args.seeds)
    for name, a in acc.items():
        a = np.array(a)
        line = f"   {name:46s} " + ", ".join(f"{v:.3f}" for v in a[:ns])
        if args.splits:
            d = a[ns:] - base[ns:]
            line += (f" | {a[ns:].mean():.3f}, {d.mean():+.3f} +- {d.std(ddof=1) / np.sqrt(len(d)):.3f}, "
                     f">= 0.95 on {int(np.sum(a[ns:] >= 0.95))} / {args.splits}")
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
