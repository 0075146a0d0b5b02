"""Where a zero-shot chain's model loses on a rig (issue 15): the twin's physics, the localiser's constants from
the calibration drops, or the class.

    python3 benchmarks/bench_zeroshot_diagnosis.py DATA --model M [--n 80] [--seed 1]

M is the chain's model (`train V --out M --test-fraction 0 --site-map auto` on the virtual set of CAL.json; its
card names CAL.json and the calibration drops). Printed:
- the twin against the rig at the same positions: the calibration drops and n other measured drops simulated
  with CAL.json's twin, picked with the model's picker (record time, unit gains); each side's travel fit
  (velocity, elliptical metric, robust spread) and the measured minus simulated ToA, with channel delays and
  a slowness difference removed (calibration_drops.path_misfit), by the path's direction from the sensor: a
  pattern by direction means the twin's anisotropy is not the rig's. Also the elliptical slowness ratio the
  calibration's first guess reads (calibration.laminate.pick_anisotropy) from the four calibration cases and
  from all simulated cases, measured against twin, and the correlation of the per-drop site energy residual;
- the localiser refitted on the calibration drops plus k other cases (calibration_drops.refit_travel_metric;
  those cases are also scored, so it reads a little optimistic): what the constants from four positions cost;
- the error's structure on every drop but the calibration drops: per-case mean against within-case, by the
  distance to the nearest edge, and the class and log-height error from the forests' start and from the true
  position (the twin's site match started there).
A diagnosis, no target: exits 0.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from dataclasses import replace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import chain_model_rows  # noqa: E402


def per_case_dtoa(session, rows, dtoa):
    cid = session.case_id[rows]
    cases = np.unique(cid)
    med = np.stack([np.nanmedian(dtoa[cid == c], 0) for c in cases])
    xy = np.stack([session.xy_mm[rows][cid == c][0] for c in cases]).astype(float)
    return med, xy


def twin_against_rig(session, model, cal_path, n, seed):
    from impactsense.calibration.laminate import pick_anisotropy
    from impactsense.calibration_drops import _record_time, path_misfit
    from impactsense.materials import material_for_rig
    from impactsense.pipeline import featurize
    from impactsense.sim import SimParams
    from impactsense.travel import fit_travel, picks, travel_distances
    from impactsense.zeroshot import calibration_rows, calibration_twins, read_calibration

    cal = read_calibration(cal_path)
    crow = calibration_rows(session, cal)
    rng = np.random.default_rng(seed)
    rows = np.r_[crow, rng.choice(np.setdiff1d(np.arange(len(session)), crow), n, replace=False)]
    sim = calibration_twins(SimParams.from_json(cal_path), session, rows, 0)
    sig = _record_time(model.signal)
    xy, sensors = session.xy_mm[rows].astype(float), sig.sensor_xy_mm
    tm, ts = picks(session.adc[rows], sig), picks(sim, sig)
    for name, t in (("rig", tm), ("twin", ts)):
        f = fit_travel(t, xy, sensors, True)
        print(f"  {name:5s} picks: v {f.velocity_mm_per_us:.3f} mm/us, metric (Qxx, Qxy, Qyy) "
              f"{tuple(round(v, 3) for v in f.metric)}, spread {f.spread_us:.2f} us ({f.n} drops)")
    d = tm - ts
    ok = np.isfinite(d).all(1)
    path = travel_distances(xy[ok], sensors)
    delays, ds = path_misfit(d[ok], path)
    r = d[ok] - np.r_[delays][None] - path * ds
    r = r - r.mean(1, keepdims=True)
    print(f"  rig - twin ToA: delays {np.round(delays, 2).tolist()} us, slowness {ds * 1e3:+.2f} ns/mm, rest "
          f"rms {np.sqrt(np.mean(r ** 2)):.2f} us")
    dx = xy[ok][:, None, 0] - sensors[None, :, 0]
    dy = xy[ok][:, None, 1] - sensors[None, :, 1]
    ang = np.degrees(np.arctan2(np.abs(dy), np.abs(dx)))
    print("  by the path's angle from x: " + ", ".join(
        f"{lo}-{hi} deg {r[(ang >= lo) & (ang < hi)].mean():+.1f} us" for lo, hi in ((0, 20), (20, 40), (40, 60), (60, 90))))
    for label, take in (("the calibration cases", slice(0, len(crow))), (f"all {len(rows)} drops", slice(None))):
        dm, pos = per_case_dtoa(session, rows[take], tm[take][:, [0, 0, 0, 1, 1, 2]] - tm[take][:, [1, 2, 3, 2, 3, 3]])
        dt, _ = per_case_dtoa(session, rows[take], ts[take][:, [0, 0, 0, 1, 1, 2]] - ts[take][:, [1, 2, 3, 2, 3, 3]])
        axis = material_for_rig(session.rig).axis_deg
        qm = pick_anisotropy(session.rig, pos[:, 0], pos[:, 1], dm, axis)["slowness_ratio"]
        qt = pick_anisotropy(session.rig, pos[:, 0], pos[:, 1], dt, axis)["slowness_ratio"]
        print(f"  elliptical slowness ratio from {label} ({len(pos)} cases): rig {qm:.3f}, twin {qt:.3f}")
    fm, fs = featurize(session.adc[rows], sig), featurize(sim, sig)
    okE = fm.usable & fs.usable
    h = np.log10(session.height_mm[rows][okE])
    p = xy[okE]
    X = np.c_[np.ones_like(h), h, p, p ** 2, p[:, 0] * p[:, 1], p ** 3]

    def site(energy):
        y = np.log10(energy[okE].astype(float)).mean(1)
        return y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
    a, b = site(fm.energy), site(fs.energy)
    print(f"  site energy residual (log10, cubic in position and log height removed): sd rig {a.std():.3f}, twin "
          f"{b.std():.3f}, correlation {np.corrcoef(a, b)[0, 1]:.2f}")


def scored(session, model, rows, signal=None):
    from impactsense.pipeline import featurize

    m = model if signal is None else replace(model, signal=signal)
    f = featurize(session.adc[rows], m.signal)
    return f, m.predict(f)


def mae(q, xy):
    ok = np.isfinite(q).all(1)
    return float(np.abs(q[ok] - xy[ok]).mean())


def localiser_from_more_cases(session, model, crow, rows, ks, seed):
    from impactsense.calibration_drops import refit_travel_metric

    xy = session.xy_mm[rows].astype(float)
    rng = np.random.default_rng(seed)
    for k in (0, *ks):
        if k:
            cases = rng.choice(np.unique(session.case_id[rows]), k, replace=False)
            sig, _ = refit_travel_metric(session, np.r_[crow, np.flatnonzero(np.isin(session.case_id, cases))],
                                         model.signal)
        else:
            sig = None
        f, p = scored(session, model, rows, sig)
        print(f"  calibration cases + {k:2d}: reported {mae(p['xy_mm'], xy):.2f}, forests {mae(p['forest_xy_mm'], xy):.2f}, "
              f"physics {mae(f.phys_xy_mm, xy):.2f} mm")


def error_structure(session, model, rows):
    from impactsense.models import impact_energy_j, twin_match

    xy = session.xy_mm[rows].astype(float)
    f, p = scored(session, model, rows)
    e = p["xy_mm"] - xy
    ok = np.isfinite(e).all(1)
    cid = session.case_id[rows]
    means, within = [], []
    for c in np.unique(cid[ok]):
        m = ok & (cid == c)
        means.append(e[m].mean(0))
        within.append(e[m] - e[m].mean(0))
    print(f"  per-case mean error (x, y) {np.abs(means).mean(0).round(2).tolist()} mm, within a case "
          f"{np.abs(np.concatenate(within)).mean(0).round(2).tolist()} mm")
    px, py = session.rig.plate_x_mm, session.rig.plate_y_mm
    edge = np.minimum.reduce([xy[:, 0], px - xy[:, 0], xy[:, 1], py - xy[:, 1]])
    radial = np.linalg.norm(e, axis=1)
    if model.site_map is None:
        print("  (no site map: the class by the true position is not available)")
        return
    truth = (impact_energy_j(session.height_mm[rows], session.rig.ball_mass_g) >= model.energy_threshold_j).astype(int)
    for label, start in (("forests' start", p["forest_xy_mm"]), ("true position", xy)):
        t = twin_match(model.site_map, model.twin_fit, f, start, model.signal)
        est = np.asarray(t["log10_height_mm"], float)
        good = (np.asarray(t["status"]) == 0) & np.isfinite(est)
        cls = model.forest_energy.predict(est[good, None])
        err = est[good] * np.log(10) - np.log(session.height_mm[rows][good])
        print(f"  twin match from the {label}: class {np.mean(cls == truth[good]):.3f}, ln height error mean "
              f"{err.mean():+.3f} sd {err.std():.3f}")
        if label == "forests' start":
            err_all = np.full(len(rows), np.nan)
            err_all[good] = err
    bands = ((0, 40), (40, 60), (60, 80), (80, 120), (120, 1e9))
    print("  by the distance to the nearest edge: " + "; ".join(
        f"{lo:.0f}-{'' if hi > 1e8 else f'{hi:.0f}'} mm: n {int(m.sum())}, radial {np.nanmean(radial[m]):.1f} mm, "
        f"ln height {np.nanmean(err_all[m]):+.3f}" for lo, hi in bands for m in [ok & (edge >= lo) & (edge < hi)] if m.any()))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data")
    ap.add_argument("--model", required=True)
    ap.add_argument("--n", type=int, default=80, help="measured drops besides the calibration drops simulated")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--more-cases", default="8,16", help="cases added to the localiser's refit (comma list)")
    a = ap.parse_args()
    from impactsense.travel import wants_metric

    chain = chain_model_rows(a.data, a.model)
    if chain is None:
        return 2
    session, model, rows, crow = chain
    cal_path = model.card["calibration"]
    print(f"{a.data}: the twin of {cal_path} against the rig")
    twin_against_rig(session, model, cal_path, a.n, a.seed)
    if wants_metric(session.rig):
        print("the localiser's constants from the calibration drops and from more cases (those cases also scored)")
        localiser_from_more_cases(session, model, crow, rows, [int(k) for k in a.more_cases.split(",") if k], a.seed)
    print(f"the error on the {len(rows)} drops that are not calibration drops")
    error_structure(session, model, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
