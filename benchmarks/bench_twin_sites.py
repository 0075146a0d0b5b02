"""The twin against the rig at the rig's own sites (issue 15): is a zero-shot chain's loss the model's or the twin's?

    python3 benchmarks/bench_twin_sites.py DATA --model M [--cache SITES.npz] [--stiffness F] [--set FIELD=VALUE ...]
        [--jobs 1]

M is a zero-shot chain's model (`train V --out M --test-fraction 0 --site-map auto`; its card names CAL.json and
the calibration drops). One drop per case of DATA (its first repetition's position and height) is simulated with
the calibrated twin (CAL.json's sim_params, the rig's noise; --stiffness F scales E1, E2 and G12, or E, by F, and
--set FIELD=VALUE replaces a SimParams field, e.g. support=clamped: what-if twins), then, by the distance to the nearest plate edge:
- the chain's model on the measured drops (every drop but the calibration drops): reported / physics MAE per axis;
- the same model on the twin's drops at the same sites, read as it read its virtual drops (the virtual drops'
  localiser constants from the card: no rig delays, unit gains, the travel prior): reported / physics MAE. A small
  figure here and a large one on the rig says the loss is the twin's mismatch, not the model's capacity or the
  virtual set's coverage;
- the per-site arrival-time mismatch (threshold picks with the model's picker; the rig's case median less its
  calibrated channel delays, minus the twin's; each site's mean and a per-channel constant removed): its rms, its
  slope against the path's length (a slowness error common to all sites), the rms left after that slope and the
  share of channel picks left more than 15 us off (a cycle-scale offset: the picked cycles differ);
- the rig minus the twin's log arrival energy (the model's twin features; per-channel medians removed), site mean.
A diagnosis, no target: exits 0.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import chain_model_rows  # noqa: E402

BANDS = ((0, 40), (40, 60), (60, 80), (80, 120), (120, 1e9))
JUMP_US = 15.0  # a pick this far from the twin's after the slope: a cycle-scale offset, not the pick's scatter


def virtual_reading(model):
    """The model as it read its virtual drops: the card's virtual constants, no rig delays, unit gains."""
    from impactsense.signal import SignalConfig

    card, d = model.card, model.signal.to_dict()
    d.update(rig_delay_us=[0.0] * 4, channel_gain=[1.0] * 4)
    if card.get("velocity_mm_per_us_virtual_drops"):
        d["velocity_mm_per_us"] = card["velocity_mm_per_us_virtual_drops"]
    refit = card.get("travel_refit_on_calibration_drops") or {}
    for pick_set, prefix in (("threshold", "travel_metric_"), ("band", "band_metric_")):
        prior = (refit.get(pick_set) or {}).get("prior")
        if not prior:
            continue
        a, b = prior["metric_a"], prior["metric_b"]
        d.update({prefix + "xx": 1 + a, prefix + "xy": b, prefix + "yy": 1 - a})
        if pick_set == "threshold" and "alpha" in prior:
            d["dispersion_exponent"] = prior["alpha"]
        if pick_set == "band":
            d.update(band_velocity_mm_per_us=prior["velocity_mm_per_us"], band_delay_us=[0.0] * 4)
    return replace(model, signal=SignalConfig.from_dict(d))


def what_if(sets: list[str]) -> dict:
    """--set FIELD=VALUE pairs as SimParams fields (a number where it parses as one, else the text)."""
    out = {}
    for item in sets:
        field, _, value = item.partition("=")
        try:
            out[field] = float(value)
        except ValueError:
            out[field] = value
    return out


def what_if_params(p, stiffness: float, sets: dict):
    """The twin's SimParams with E1, E2 and G12 (or E) x stiffness and the --set fields replaced; an unknown field or
    a value SimParams refuses is an error naming it."""
    from impactsense.errors import ConfigError

    unknown = sorted(set(sets) - set(p.__dataclass_fields__))
    if unknown:
        raise ConfigError(f"--set: no SimParams field {', '.join(unknown)}")
    p = replace(p, **{k: getattr(p, k) * stiffness for k in ("e_pa", "e2_pa", "g12_pa") if getattr(p, k)}, **sets)
    p.validate()
    return p


def twin_drops(session, model, sites, stiffness: float, sets: dict, cache: Path | None, jobs: int):
    from impactsense.sim import SimParams, simulate_drops

    key = {"sites": sites.tolist(), "stiffness": stiffness, "calibration": model.card["calibration"]}
    if sets:
        key["set"] = sets
    if cache is not None and cache.is_file():
        z = np.load(cache)
        if json.loads(str(z["key"])) == key:
            return z["adc"]
    p = what_if_params(SimParams.from_json(model.card["calibration"]), stiffness, sets)
    adc = simulate_drops(p, session.rig, session.x_mm[sites], session.y_mm[sites], session.height_mm[sites],
                         noise=True, seed=1, workers=jobs, progress=False)
    if cache is not None:
        np.savez(cache, adc=adc, key=json.dumps(key))
    return adc


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data")
    ap.add_argument("--model", required=True)
    ap.add_argument("--cache", type=Path, default=None, help="npz keeping the twin's drops between runs")
    ap.add_argument("--stiffness", type=float, default=1.0, help="scale the twin's moduli (a what-if twin)")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="replace a SimParams field of the twin (a what-if twin), e.g. support=clamped")
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args()
    from impactsense.sitemap import twin_features
    from impactsense.travel import picks

    chain = chain_model_rows(a.data, a.model)
    if chain is None:
        return 2
    session, model, rows, _ = chain
    rig, cases = session.rig, session.case_id
    sites = np.array([rows[cases[rows] == c][0] for c in np.unique(cases[rows])])
    sim = twin_drops(session, model, sites, a.stiffness, what_if(a.set), a.cache, a.jobs)
    vm = virtual_reading(model)
    xy = session.xy_mm.astype(float)
    px, py = rig.plate_x_mm, rig.plate_y_mm

    def edge(p):
        return np.minimum(np.minimum(p[:, 0], px - p[:, 0]), np.minimum(p[:, 1], py - p[:, 1]))

    fm, ft = model.featurize(session.adc[rows]), vm.featurize(sim)
    pm, pt = model.predict(fm), vm.predict(ft)
    mae = lambda p, r: np.abs(np.asarray(p, float) - xy[r]).mean(1)  # noqa: E731
    em, epm, et, ept = mae(pm["xy_mm"], rows), mae(fm.phys_xy_mm, rows), mae(pt["xy_mm"], sites), mae(ft.phys_xy_mm, sites)
    # arrival times: the rig's case medians less its calibrated delays against the twin's, the model's picker
    same = [cases[rows] == cases[s] for s in sites]
    tm = np.array([np.nanmedian(picks(session.adc[rows[m]], model.signal), 0) for m in same])
    tm -= np.asarray(model.signal.rig_delay_us, float)
    tt = picks(sim, model.signal)
    d = (tm - np.nanmean(tm, 1, keepdims=True)) - (tt - np.nanmean(tt, 1, keepdims=True))
    d -= np.nanmedian(d, 0)
    d -= np.nanmean(d, 1, keepdims=True)
    path = np.hypot(xy[sites, 0:1] - np.asarray(rig.sensor_x_mm), xy[sites, 1:2] - np.asarray(rig.sensor_y_mm))
    path = (path - path.mean(1, keepdims=True)) / 100.0
    ok = np.isfinite(d)
    slope = float(np.sum(d[ok] * path[ok]) / np.sum(path[ok] ** 2))
    left = d - slope * path
    # arrival energies (ln), the rig's case medians against the twin's, per-channel medians removed
    arr = [0, 4, 8, 12]
    fmm, _ = twin_features(fm)
    ftt, _ = twin_features(ft)
    de = np.array([np.nanmedian(fmm[m][:, arr], 0) for m in same]) - ftt[:, arr]
    de = (de - np.nanmedian(de, 0)) * np.log(10)
    dm, dt = edge(xy[rows]), edge(xy[sites])
    print(f"{a.data}: {len(rows)} measured drops, {len(sites)} twin sites (stiffness x{a.stiffness:g}{''.join(' ' + x for x in a.set)}); arrival-time "
          f"slope rig - twin {slope:+.2f} us per 100 mm of path")
    print("edge mm  | rig: n, reported / physics MAE | twin: n, reported / physics | ToA rms / after slope us "
          "| share > 15 us | ln energy rig - twin")

    def tail(x):  # the share of channel picks left more than half a cycle's scale (15 us) from the twin's
        x = np.abs(x[np.isfinite(x)])
        return float(np.mean(x > JUMP_US)) if x.size else float("nan")

    for lo, hi in BANDS:
        m1, m2 = (dm >= lo) & (dm < hi), (dt >= lo) & (dt < hi)
        if not m2.any():
            continue
        print(f"{lo:3.0f}-{'' if hi > 1e8 else f'{hi:.0f}':>4} | {m1.sum():3d}, {em[m1].mean():5.2f} / {epm[m1].mean():5.2f} "
              f"| {m2.sum():3d}, {et[m2].mean():5.2f} / {ept[m2].mean():5.2f} | {np.sqrt(np.nanmean(d[m2] ** 2)):5.2f} / "
              f"{np.sqrt(np.nanmean(left[m2] ** 2)):5.2f} | {tail(left[m2]):.3f} | {np.nanmean(de[m2]):+.3f}")
    print(f"all      | {len(rows):3d}, {em.mean():5.2f} / {epm.mean():5.2f} | {len(sites):3d}, {et.mean():5.2f} / "
          f"{ept.mean():5.2f} | {np.sqrt(np.nanmean(d ** 2)):5.2f} / {np.sqrt(np.nanmean(left ** 2)):5.2f} | {tail(left):.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
