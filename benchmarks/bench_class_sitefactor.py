"""The energy class from the calibrated twin's site factor: log(m g h) from the measured energies minus the
twin's simulated energies at the drop's position, against the linear estimate the product uses.

    python3 benchmarks/bench_class_sitefactor.py [--rigs-dir DIR] [--calibration-dir CALS] [--seeds 4]
                                                 [--json OUT.json] [--skip-bundled]

The twin's site map holds, per 5 mm grid point, the simulated log10 energies of a drop from one height at the
four channels (arrival and Delta^1..3: the site factor of each channel, with the edges, the sensors' directions
and the distance law in it). A drop's energies minus the map at its position leave log10 of its energy plus the
rig's gains. Per session folder with a site map (the bundled twin's for the bundled rig, else
CALS/<folder name>/CAL.json's, built and cached beside it as `train --calibration` does), per split seed (the
held-out 20 % of `train`; the localiser fitted on the training cases):

- candidates a product could run (the position estimated): the product's ridge (height_class.py, the physics
  position); the per-kind median over the channels of the site-corrected energies (robust to one channel) at
  the forests' position, alone and beside the summed energies; the channels' inverse-variance mean (each
  channel's weight 1 / (the map's local variance within the position error + tau^2): the near-edge channel's
  energy is the most site-dependent); the twin's own height estimate (twin.estimate) alone and beside the
  summed energies; the product's twin class (bagged stumps) for reference; and the one of the ridges the
  training drops' out-of-fold accuracy picks;
- bounds: the site-corrected median at the true position, at the true position plus a Gaussian error of
  2, 4 and 6 mm per axis, and at the true position plus the forests' own error scaled by 0.25, 0.5 and 0.75
  (what the site factor needs of the position).

Every ridge is height_class.fit_linear_height_class (log m g h on its inputs and a cubic in the position, the
boundary midway in log between the heights either side of the 75th percentile); out of fold: 5 position-grouped
folds of the training drops, each with its own threshold. A study: nothing here changes the product; exit 0.
Figures: docs/findings.md, "The twin's site factor in the class".
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import rig_study_args, rig_study_sessions  # noqa: E402

KINDS = 4
CHANNELS = 4
POSITION_ERRORS_MM = (2.0, 4.0, 6.0)
ERROR_SCALES = (0.25, 0.5, 0.75)
TAUS = (0.02, 0.05, 0.1)


# ----- the site map as a dense grid -----
def dense_grid(site, smooth_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The map's features [nx, ny, 16] with the missing points (sensor discs) filled from the nearest present
    one, and each point's local standard deviation within a Gaussian of smooth_mm (0: zeros). With smooth_mm
    the values are the Gaussian mean (the expected site factor when the position is that uncertain)."""
    from scipy.ndimage import distance_transform_edt, gaussian_filter

    v = site.values().astype(float).reshape(site.nx, site.ny, -1)
    missing = ~np.isfinite(v[..., 0])
    if missing.any():
        idx = distance_transform_edt(missing, return_distances=False, return_indices=True)
        v = v[idx[0], idx[1]]
    if smooth_mm <= 0:
        return v, np.zeros_like(v)
    s = smooth_mm / site.step_mm
    m1 = np.stack([gaussian_filter(v[..., k], s, mode="nearest") for k in range(v.shape[-1])], -1)
    m2 = np.stack([gaussian_filter(v[..., k] ** 2, s, mode="nearest") for k in range(v.shape[-1])], -1)
    return m1, np.sqrt(np.maximum(m2 - m1 ** 2, 0.0))


def grid_at(site, grid: np.ndarray, xy_mm: np.ndarray) -> np.ndarray:
    """Bilinear value of a dense_grid array at each position [n, 2] (clamped to the grid) -> [n, 16]."""
    from scipy.interpolate import RegularGridInterpolator

    xs = site.x0_mm + site.step_mm * np.arange(site.nx)
    ys = site.y0_mm + site.step_mm * np.arange(site.ny)
    p = np.asarray(xy_mm, float).reshape(-1, 2)
    p = np.c_[np.clip(p[:, 0], xs[0], xs[-1]), np.clip(p[:, 1], ys[0], ys[-1])]
    return RegularGridInterpolator((xs, ys), grid)(p)


# ----- site-corrected energies -----
def site_corrected(feats: np.ndarray, usable: np.ndarray, site_values: np.ndarray) -> np.ndarray:
    """The drops' twin features (log10 energies, channel-major: channel c, kind k at 4 c + k) minus the site
    map's at their position -> [R, channel, kind], NaN where a feature is not usable (clipped, dead)."""
    n = feats.shape[1]
    mask = ((np.asarray(usable)[:, None].astype(np.int64) >> np.arange(n)) & 1).astype(bool) & np.isfinite(feats)
    return np.where(mask, feats.astype(float) - site_values, np.nan).reshape(-1, CHANNELS, KINDS)


def _fill_columns(a: np.ndarray) -> np.ndarray:
    """NaN (a drop without a usable channel of that kind) -> the column's median."""
    col = np.nanmedian(a, 0)
    return np.where(np.isfinite(a), a, col[None, :])


def robust_height(corrected: np.ndarray) -> np.ndarray:
    """Per kind, the median over the channels of the site-corrected log10 energy -> [R, kind]: with four
    channels the mean of the middle two, so one channel's wrong site factor moves it at most half as far."""
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return _fill_columns(np.nanmedian(corrected, 1))


def weighted_height(corrected: np.ndarray, local_sd: np.ndarray, tau: float) -> np.ndarray:
    """Per kind, the channels' mean weighted by 1 / (local_sd^2 + tau^2) (local_sd [R, 16]: the map's spread
    within the position's error, so a channel whose site factor changes fast there counts less) -> [R, kind]."""
    w = 1.0 / (local_sd.reshape(-1, CHANNELS, KINDS) ** 2 + tau ** 2)
    w = np.where(np.isfinite(corrected), w, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.nansum(np.nan_to_num(corrected) * w, 1) / w.sum(1)
    return _fill_columns(out)


# ----- scores -----
def ridge_scores(X: np.ndarray, energy_j: np.ndarray, xy_mm: np.ndarray, train: np.ndarray,
                 test: np.ndarray) -> dict:
    """height_class's ridge on X (positions last): out-of-fold class accuracy and rms log error on the training
    drops (5 position-grouped folds, each its own threshold), and the held-out ones fitted on all of them."""
    from sklearn.model_selection import GroupKFold

    from impactsense.height_class import fit_linear_height_class, position_groups

    Xtr, Etr = X[train], energy_j[train]
    groups = position_groups(xy_mm[train])
    right = np.zeros(len(train), bool)
    err = np.zeros(len(train))
    for a, b in GroupKFold(min(5, int(groups.max()) + 1)).split(Xtr, groups=groups):
        t = float(np.percentile(Etr[a], 75))
        m = fit_linear_height_class(Xtr[a], Etr[a], t)
        right[b] = m.predict(Xtr[b]) == (Etr[b] >= t)
        err[b] = m.log_energy(Xtr[b]) - np.log(Etr[b])
    t = float(np.percentile(Etr, 75))
    m = fit_linear_height_class(Xtr, Etr, t)
    return {"oof_class": float(right.mean()), "oof_rms_log": float(np.sqrt(np.mean(err ** 2))),
            "class": float(np.mean(m.predict(X[test]) == (energy_j[test] >= t))),
            "rms_log": float(np.sqrt(np.mean((m.log_energy(X[test]) - np.log(energy_j[test])) ** 2)))}


def forests_positions(X_loc, phys, xy, train, test, seed: int) -> np.ndarray:
    """The forests' position (physics + correction, one pair on LOCATION_FEATURES): out of fold on the
    training drops (5 position-grouped folds), fitted on all of them for the held-out ones."""
    from sklearn.model_selection import GroupKFold

    from impactsense.height_class import position_groups
    from impactsense.models import ForestSettings

    settings = ForestSettings(seed=seed)
    out = np.full_like(phys, np.nan)
    resid = xy - phys
    groups = position_groups(xy[train])
    for a, b in GroupKFold(min(5, int(groups.max()) + 1)).split(train, groups=groups):
        for k in range(2):
            out[train[b], k] = phys[train[b], k] + settings.regressor().fit(
                X_loc[train[a]], resid[train[a], k]).predict(X_loc[train[b]])
    for k in range(2):
        out[test, k] = phys[test, k] + settings.regressor().fit(X_loc[train], resid[train, k]).predict(X_loc[test])
    return out


def site_map_for(session, calibration_dir):
    """The bundled twin's map for the bundled rig, else CALS/<folder>/CAL.json's (cached beside it), else None."""
    from impactsense.sitemap import resolve_site_map

    site = resolve_site_map("auto", session.rig)
    if site is not None or not calibration_dir:
        return site
    cal = Path(calibration_dir) / Path(session.path).name / "CAL.json"
    if not cal.is_file():
        return None
    from impactsense.chain import measured_site_map

    return measured_site_map(session, cal, progress=False)


def seed_study(session, site, seed: int) -> dict:
    from impactsense.height_class import LINEAR_CLASS_FEATURES
    from impactsense.models import LOCATION_FEATURES, TWIN_CLASSIFIER, columns, impact_energy_j
    from impactsense.pipeline import featurize, fit_localiser
    from impactsense.signal import SignalConfig
    from impactsense.sitemap import twin_features
    from impactsense.split import case_split
    from impactsense.twin import estimate as twin_estimate
    from impactsense.twin import fit_twin

    train_rows, test_rows = case_split(session.case_id, 0.2, seed, None)
    cfg = fit_localiser(session, train_rows, SignalConfig.for_rig(session.rig))
    f = featurize(session.adc, cfg)
    use = f.usable
    train, test = np.intersect1d(train_rows, np.flatnonzero(use)), np.intersect1d(test_rows, np.flatnonzero(use))
    xy, phys = session.xy_mm.astype(float), f.phys_xy_mm.astype(float)
    energy = impact_energy_j(session.height_mm, session.rig.ball_mass_g)
    X = f.vector
    base = X[:, columns(LINEAR_CLASS_FEATURES)]
    sums = base[:, :-2]
    feats, usable = twin_features(f)
    fpos = forests_positions(X[:, columns(LOCATION_FEATURES)], phys, xy, train, test, seed)
    fpos = np.where(np.isfinite(fpos), fpos, phys)
    raw, _ = dense_grid(site)

    def median_at(pos):
        return robust_height(site_corrected(feats, usable, grid_at(site, raw, pos)))

    out = {"n_train": int(len(train)), "n_test": int(len(test)),
           "forests_mae_mm": float(np.mean(np.abs(fpos[test] - xy[test])))}
    cands = {"linear (product, physics position)": base}
    med = median_at(fpos)
    cands["site-corrected median"] = np.c_[med, fpos]
    cands["summed energies + site-corrected median"] = np.c_[sums, med, fpos]
    # the map's mean and spread within the forests' error (their out-of-fold rms per axis on the training drops)
    err_mm = float(np.sqrt(np.mean((fpos[train] - xy[train]) ** 2)))
    mean_g, sd_g = dense_grid(site, err_mm)
    corr = site_corrected(feats, usable, grid_at(site, mean_g, fpos))
    sd = grid_at(site, sd_g, fpos)
    for tau in TAUS:
        cands[f"weighted mean, tau {tau}"] = np.c_[weighted_height(corr, sd, tau), fpos]
    fit = fit_twin(feats[train], usable[train], site, xy[train], session.height_mm[train])
    est = np.asarray(twin_estimate(site, fit, feats, usable, fpos)["log10_height_mm"], float)
    est_phys = np.asarray(twin_estimate(site, fit, feats, usable, phys)["log10_height_mm"], float)
    est = np.where(np.isfinite(est), est, np.nanmedian(est))
    cands["twin height"] = np.c_[est, fpos]
    cands["summed energies + twin height"] = np.c_[sums, est, fpos]
    rows = {name: ridge_scores(V, energy, xy, train, test) for name, V in cands.items()}
    best = max(rows, key=lambda k: rows[k]["oof_class"])
    rows["chosen out of fold"] = {**rows[best], "chosen": best}
    # the product's twin class: stumps on the training drops' estimate at the physics position
    t = float(np.percentile(energy[train], 75))
    ok = np.isfinite(est_phys[train])
    stumps = TWIN_CLASSIFIER.classifier().fit(est_phys[train][ok, None], (energy[train] >= t)[ok].astype(int))
    rows["twin class (stumps, product with a site map)"] = {
        "class": float(np.mean(stumps.predict(est[test, None]) == (energy[test] >= t)))}
    # bounds: the site factor at the true position, and with a known position error
    rows["bound: site-corrected median, true position"] = ridge_scores(np.c_[median_at(xy), xy], energy, xy, train,
                                                                       test)
    rng = np.random.default_rng(seed)
    for e in POSITION_ERRORS_MM:
        noisy = xy + rng.normal(0.0, e, xy.shape)
        rows[f"bound: true position + {e:g} mm"] = ridge_scores(np.c_[median_at(noisy), noisy], energy, xy, train, test)
    # the forests' own errors (where they are: near the edges, per case) scaled down
    for k in ERROR_SCALES:
        pos = xy + k * (fpos - xy)
        rows[f"bound: forests' error x {k:g}"] = ridge_scores(np.c_[median_at(pos), pos], energy, xy, train, test)
    out["rows"] = rows
    return out


def main(argv=None) -> int:
    import argparse

    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--calibration-dir", default=None)
    known, rest = pre.parse_known_args(argv)
    args = rig_study_args(__doc__.splitlines()[0], rest)
    report = {}
    from impactsense.data import load_session

    for path in rig_study_sessions(args):
        session = load_session(path)
        site = site_map_for(session, known.calibration_dir)
        if site is None:
            print(f"{session.name}: no site map (give --calibration-dir with CALS/{Path(session.path).name}/CAL.json)")
            continue
        seeds = [seed_study(session, site, s) for s in range(args.seeds)]
        report[session.name] = seeds
        print(f"\n{session.name}: held-out class per seed (mean) | out-of-fold class (mean) | rms log m g h "
              f"held out; forests' MAE per axis {', '.join('%.2f' % s['forests_mae_mm'] for s in seeds)} mm")
        for name in seeds[0]["rows"]:
            r = [s["rows"][name] for s in seeds]
            cls = [x["class"] for x in r]
            line = f"  {name:48s} {' '.join(f'{c:.3f}' for c in cls)} ({np.mean(cls):.3f})"
            if "oof_class" in r[0]:
                oof = [x["oof_class"] for x in r]
                line += f" | {np.mean(oof):.3f} | {np.mean([x['rms_log'] for x in r]):.3f}"
            if "chosen" in r[0]:
                line += " | " + "; ".join(x["chosen"] for x in r)
            print(line)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
