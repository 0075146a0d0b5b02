"""The calibrated twin's energy per channel against the rig's, by the path's direction to the fibres: where the
zero-shot class's height estimate is wrong on a laminate, and whether the twin's in-plane shear modulus is why
(measured; nothing chosen).

    impactsense calibrate DATA --out CAL.json
    python3 benchmarks/bench_twin_directivity.py DATA --calibration CAL.json [--g12-gpa 4.5 3] [--cache DIR]

One drop per case of DATA is simulated with the twin of CAL.json (its sim_params; no noise, the rig's logger) at
the case's declared position and height, and each twin feature (log10 of a channel's arrival and difference
energies, the twin's fingerprint: sitemap.TWIN_FEATURE_NAMES) compared with the rig's (the mean over the case's
drops): misfit = rig - twin, less each feature's median over the calibration drops (the channel gains and the
spectral tilt the calibration's offsets hold). Printed per twin variant (CAL's own, then CAL's with g12 set to each
--g12-gpa value, every other parameter kept):

1. the misfit's spread: per feature, the part shared by a case's four channels (the site: what the ball puts in)
   and each channel's own (the path: spreading, attenuation, direction);
2. the misfit by the path's angle to the material's first axis and by its length (case x channel means), per kind
   of energy (its slope per decade of the path's length; along / across the fibres), and by site band (40-60 mm from the edges along / across the fibres, nearer, the interior);
3. the arrival-time misfit: rms over cases of each sensor pair's DToA, rig - twin, less the pair's median (the
   channel delays), us: what calibrate's laminate stage fits E1, E2, G12 by;
4. the zero-shot class as the twin's estimate would give it at the declared position: each drop's log10 h error
   = the mean over its 16 features of (rig - twin - the calibration drops' offsets) (slope 1, equal weights; the
   product weights per kind and matches at the reported position), the class against the cut between the two
   heights either side of the 75th percentile, on the cases every variant simulates; then with one more term per
   channel, b exp(-(sin theta / 0.1)^2) (theta the path's angle to the fibres: energy beamed along them), b fitted
   on the calibration drops alone.
5. (--draws K, the first variant only) the same two rows over K draws of four calibration cases, one per plate
   quadrant, among the usable ones: b's spread, the class with b fitted on the draw and with b fitted on every drop
   (the direction law known, not zero-shot), paired to the twin without the lobe.
6. (first variant) the same estimate from a subset of the kinds of energy: all four, the arrival energy alone,
   arrival + Delta^1, all four weighted 1 / each kind's residual variance on the calibration drops (fit_twin's
   default weights from those drops), with CAL's calibration cases and over the --draws draws (paired to all four kinds): a loss
   growing with frequency that the twin lacks weighs on the difference energies (part 2's per-kind slopes).
The calibration drops are CAL.json's (drops.case_ids); their cases are left out of part 4's figure.
Simulations are cached under --cache (one .npz per variant). docs/findings.md "Session 28: rigcclass".
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np

FULL = (1 << 16) - 1
LOBE_WIDTH = 0.1          # sin theta: ~6 degrees either side of the fibre axis


def simulate_cases(session, cal: dict, cache: Path | None, tag: str) -> dict:
    """Twin and rig features (16 twin features, usable masks, arrival times) of one drop per case."""
    from impactsense.pipeline import featurize
    from impactsense.signal import SignalConfig
    from impactsense.sim import SimParams
    from impactsense.sim.simulate import batch_solver, simulate_drops
    from impactsense.sitemap import twin_features

    path = None if cache is None else cache / f"twin-cases-{tag}.npz"
    if path is not None and path.is_file():
        with np.load(path) as z:
            return dict(z)
    params = SimParams.from_dict(cal["sim_params"])
    cases, first = np.unique(session.case_id, return_index=True)
    x, y, h = session.x_mm[first], session.y_mm[first], session.height_mm[first]
    signal = SignalConfig.for_rig(session.rig)
    solver = "modal" if params.loss_factor > 0 else batch_solver(params, session.rig, "auto", x, y, h)
    adc = simulate_drops(params, session.rig, x, y, h, noise=False, workers=1, progress=False, solver=solver)
    twin, rig = featurize(adc, signal), featurize(session.adc, signal)
    (ft, ut), (fm, um) = twin_features(twin), twin_features(rig)
    out = dict(cases=cases, x=x, y=y, h=h, ft=ft, ut=ut, fm=fm, um=um, toa_t=twin.toa_us, toa_m=rig.toa_us)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **out)
    return out


def path_geometry(xy: np.ndarray, sensors: np.ndarray, axis_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Each (drop, channel) path's length (mm) and angle to the material's first axis (rad, 0..pi/2)."""
    d = xy[:, None, :] - sensors[None]
    c, s = np.cos(np.radians(axis_deg)), np.sin(np.radians(axis_deg))
    along, across = d[..., 0] * c + d[..., 1] * s, -d[..., 0] * s + d[..., 1] * c
    return np.hypot(along, across), np.arctan2(np.abs(across), np.abs(along))


def report(name: str, sim: dict, session, cal_cases: np.ndarray, common: np.ndarray, axis_deg: float) -> None:
    cases, x, y = sim["cases"], sim["x"], sim["y"]
    W, H = session.rig.plate_x_mm, session.rig.plate_y_mm
    sensors = np.asarray(session.rig.sensor_xy_mm, float)
    idx = np.searchsorted(cases, session.case_id)
    usable = (sim["ut"] == FULL)[idx] & (sim["um"] == FULL)
    R = (sim["fm"] - sim["ft"][idx]).reshape(-1, 4, 4)          # drop, channel, kind; log10 rig - twin
    is_cal = np.isin(session.case_id, cal_cases) & usable
    off = np.median(R[is_cal], 0)
    Rc = R - off
    # case means
    M = np.full((len(cases), 4, 4), np.nan)
    for i in range(len(cases)):
        rows = (idx == i) & usable
        if rows.any():
            M[i] = Rc[rows].mean(0)
    shared = np.nanmean(M, (1, 2))
    per_channel = np.nanmean(M, 2)
    own = per_channel - shared[:, None]
    print(f"{name}: cases simulated and usable {int(np.isfinite(shared).sum())} of {len(cases)}")
    print(f"  1. misfit sd (log10): per feature {np.nanstd(M):.3f}, shared by the channels {np.nanstd(shared):.3f}, "
          f"each channel's own {np.nanstd(own):.3f}")
    r, theta = path_geometry(np.c_[x, y], sensors, axis_deg)
    deg = np.degrees(theta)
    line = "  2. by the path's angle to the fibres (deg: mean, n):"
    for lo, hi in ((0, 10), (10, 20), (20, 35), (35, 55), (55, 90.1)):
        m = (deg >= lo) & (deg < hi) & np.isfinite(per_channel)
        line += f"  {lo:g}-{hi:g}: {per_channel[m].mean():+.3f} ({m.sum()})"
    print(line)
    line = "     by its length (mm):"
    for lo, hi in ((0, 50), (50, 100), (100, 200), (200, 300), (300, 1e9)):
        m = (r >= lo) & (r < hi) & np.isfinite(per_channel)
        line += f"  {lo:g}-{hi:g}: {per_channel[m].mean():+.3f} ({m.sum()})"
    print(line)
    # per kind (arrival, Delta^1..3: the higher, the more the high frequencies weigh): a loss growing with frequency
    # makes the difference energies' misfit fall with the path's length faster than the arrival energy's
    rl, dl = r[idx], deg[idx]
    ok = usable[:, None] & np.ones_like(rl, bool)
    slopes = [np.polyfit(np.log10(rl[ok]), Rc[..., k][ok], 1)[0] for k in range(4)]
    along = [Rc[..., k][ok & (dl < 10) & (rl >= 100) & (rl < 300)].mean() for k in range(4)]
    across = [Rc[..., k][ok & (dl > 55) & (rl >= 100) & (rl < 300)].mean() for k in range(4)]
    print("     per kind (arrival, Delta^1, Delta^2, Delta^3), every drop: slope per decade of path length "
          + " ".join(f"{v:+.3f}" for v in slopes) + "; paths 100-300 mm within 10 deg of the fibres "
          + " ".join(f"{v:+.3f}" for v in along) + ", beyond 55 deg " + " ".join(f"{v:+.3f}" for v in across))
    dx, dy = np.minimum(x, W - x), np.minimum(y, H - y)
    bands = {"40-60 mm from an edge along the fibres": (dy >= 40) & (dy < 60) & (dx >= 40),
             "40-60 mm from an edge across the fibres": (dx >= 40) & (dx < 60) & (dy >= 40),
             "within 40 mm of an edge": np.minimum(dx, dy) < 40,
             ">= 80 mm from every edge": np.minimum(dx, dy) >= 80}
    print("     by site (shared; per channel): " + "; ".join(
        f"{k} ({int((m & np.isfinite(shared)).sum())}) {np.nanmean(shared[m]):+.3f} ("
        + " ".join(f"{v:+.2f}" for v in np.nanmean(per_channel[m], 0)) + ")" for k, m in bands.items()))
    # 3. timing
    pairs = [(i, j) for i in range(4) for j in range(i + 1, 4)]
    tm = np.full((len(cases), 4), np.nan)
    for i in range(len(cases)):
        rows = idx == i
        tm[i] = np.nanmean(sim["toa_m"][rows], 0) if rows.any() else np.nan
    dd = np.stack([(tm[:, i] - tm[:, j]) - (sim["toa_t"][:, i] - sim["toa_t"][:, j]) for i, j in pairs], 1)
    dd -= np.nanmedian(dd, 0)
    print(f"  3. DToA rig - twin, rms over cases and pairs (pair medians removed): {np.sqrt(np.nanmean(dd ** 2)):.1f} us")
    # 4. the class as the twin's estimate would give it
    cut = 0.5 * np.log10(class_heights(session))
    lab = np.log10(session.height_mm) >= cut
    test = usable & ~np.isin(session.case_id, cal_cases) & np.isin(session.case_id, common)
    lobe = np.exp(-(np.sin(theta) / LOBE_WIDTH) ** 2)[idx]      # drop, channel
    g = lobe[is_cal] - lobe[is_cal].mean(0)
    yv = (R[is_cal] - np.median(R[is_cal], 0)).mean(2)
    b = float(np.sum(g * yv) / np.sum(g * g))
    for label, corr in (("the twin", 0.0), (f"+ fibre-axis lobe, b {b:+.3f} from the calibration drops",
                                             b * lobe[:, :, None])):
        Rk = R - corr
        err = (Rk - np.median(Rk[is_cal], 0)).mean((1, 2))
        wrong = ((np.log10(session.height_mm) + err) >= cut) != lab
        per_case = [err[test & (session.case_id == c)].mean() for c in np.unique(session.case_id[test])]
        print(f"  4. {label:58s} class {1 - wrong[test].mean():.3f} ({int(wrong[test].sum())} of {int(test.sum())} "
              f"wrong), estimate error per-case sd {np.std(per_case):.3f} log10")


def lobe_class(R, lobe, is_cal, test, log_h, cut, lab, b=None) -> tuple[float, float, float, float]:
    """(b, the lobe's leverage sum g^2 on the calibration drops, class without the lobe, class with it); b fitted
    on the calibration drops' channel misfits unless given."""
    g = lobe[is_cal] - lobe[is_cal].mean(0)
    lev = float(np.sum(g * g))
    if b is None:
        yv = (R[is_cal] - np.median(R[is_cal], 0)).mean(2)
        b = float(np.sum(g * yv) / lev) if lev > 1e-9 else 0.0
    acc = []
    for corr in (0.0, b * lobe[:, :, None]):
        Rk = R - corr
        err = (Rk - np.median(Rk[is_cal], 0)).mean((1, 2))
        acc.append(float(np.mean(((log_h + err) >= cut)[test] == lab[test])))
    return b, lev, acc[0], acc[1]


def draws(sim: dict, session, axis_deg: float, k: int) -> None:
    """Part 5: the fibre-axis lobe's b and class over k draws of four calibration cases (one per quadrant)."""
    cases, x, y = sim["cases"], sim["x"], sim["y"]
    idx = np.searchsorted(cases, session.case_id)
    usable = (sim["ut"] == FULL)[idx] & (sim["um"] == FULL)
    R = (sim["fm"] - sim["ft"][idx]).reshape(-1, 4, 4)
    _, theta = path_geometry(np.c_[x, y], np.asarray(session.rig.sensor_xy_mm, float), axis_deg)
    lobe = np.exp(-(np.sin(theta) / LOBE_WIDTH) ** 2)[idx]
    log_h = np.log10(session.height_mm)
    cut = 0.5 * np.log10(class_heights(session))
    lab = log_h >= cut
    good = cases[sim["ut"] == FULL]
    quadrant = ((x > session.rig.plate_x_mm / 2).astype(int) + 2 * (y > session.rig.plate_y_mm / 2))[
        np.searchsorted(cases, good)]
    b_all = lobe_class(R, lobe, usable, usable, log_h, cut, lab)[0]
    rng = np.random.default_rng(0)
    rows = []
    for _ in range(k):
        cal = np.array([rng.choice(good[quadrant == q]) for q in range(4) if np.any(quadrant == q)])
        is_cal = np.isin(session.case_id, cal) & usable
        test = usable & ~np.isin(session.case_id, cal)
        b, lev, without, fitted = lobe_class(R, lobe, is_cal, test, log_h, cut, lab)
        known = lobe_class(R, lobe, is_cal, test, log_h, cut, lab, b_all)[3]
        rows.append((b, lev, without, fitted, known))
    a = np.array(rows)
    se = lambda d: d.std(ddof=1) / np.sqrt(len(d))  # noqa: E731
    strong = a[:, 1] > np.median(a[:, 1])
    print(f"  5. {k} draws of four calibration cases: b median {np.median(a[:, 0]):+.3f} (10-90 % "
          f"{np.percentile(a[:, 0], 10):+.3f}..{np.percentile(a[:, 0], 90):+.3f}; every drop's {b_all:+.3f}); class "
          f"without {a[:, 2].mean():.3f}; + lobe, b from the draw {a[:, 3].mean():.3f} ({(a[:, 3] - a[:, 2]).mean():+.3f} "
          f"+- {se(a[:, 3] - a[:, 2]):.3f}; the half with more leverage {(a[strong, 3] - a[strong, 2]).mean():+.3f}); "
          f"b every drop's {a[:, 4].mean():.3f} ({(a[:, 4] - a[:, 2]).mean():+.3f} +- {se(a[:, 4] - a[:, 2]):.3f})")


KIND_SUBSETS = {"all four kinds": [0, 1, 2, 3], "arrival energy alone": [0], "arrival + Delta^1": [0, 1],
                "all four, weighted 1 / the kind's variance on the calibration drops": "weighted"}


def kinds(sim: dict, session, cal_cases: np.ndarray, k: int) -> None:
    """Part 6: the emulated class from subsets of the kinds, CAL's calibration cases and k quadrant draws."""
    cases, x, y = sim["cases"], sim["x"], sim["y"]
    idx = np.searchsorted(cases, session.case_id)
    usable = (sim["ut"] == FULL)[idx] & (sim["um"] == FULL)
    R = (sim["fm"] - sim["ft"][idx]).reshape(-1, 4, 4)
    log_h = np.log10(session.height_mm)
    cut = 0.5 * np.log10(class_heights(session))
    lab = log_h >= cut

    def score(cal):
        is_cal = np.isin(session.case_id, cal) & usable
        test = usable & ~np.isin(session.case_id, cal)
        out = []
        for ks in KIND_SUBSETS.values():
            if isinstance(ks, str):     # twin.fit_twin's default weights, from the four calibration cases' drops
                dev = R - np.median(R[is_cal], 0)
                w = 1.0 / np.maximum(dev[is_cal].reshape(-1, 4).var(0), 1e-6)      # per kind, pooled channels
                err = (dev * w[None, None, :]).sum((1, 2)) / (4 * w.sum())
            else:
                Rk = R[:, :, ks]
                err = (Rk - np.median(Rk[is_cal], 0)).mean((1, 2))
            out.append(float(np.mean(((log_h + err) >= cut)[test] == lab[test])))
        return out
    own = score(cal_cases)
    print("  6. class by the kinds read, CAL's calibration cases: "
          + ", ".join(f"{n} {v:.3f}" for n, v in zip(KIND_SUBSETS, own)))
    if not k:
        return
    good = cases[sim["ut"] == FULL]
    quadrant = ((x > session.rig.plate_x_mm / 2).astype(int) + 2 * (y > session.rig.plate_y_mm / 2))[
        np.searchsorted(cases, good)]
    rng = np.random.default_rng(0)
    a = np.array([score(np.array([rng.choice(good[quadrant == q]) for q in range(4) if np.any(quadrant == q)]))
                  for _ in range(k)])
    line = f"     {k} draws: "
    for j, n in enumerate(KIND_SUBSETS):
        d = a[:, j] - a[:, 0]
        line += f"{n} {a[:, j].mean():.3f}" + ("" if j == 0 else f" ({d.mean():+.3f} +- {d.std(ddof=1) / np.sqrt(k):.3f}, "
                                                           f"better on {int(np.sum(d > 0))}, worse on {int(np.sum(d < 0))})") + "; "
    print(line.rstrip("; "))


def class_heights(session) -> float:
    """The product of the two heights either side of the session's 75th-percentile energy (mm^2)."""
    h = np.asarray(session.height_mm, float)
    t = np.percentile(h, 75)
    return float(h[h < t].max() * h[h >= t].min())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data")
    ap.add_argument("--calibration", required=True, help="CAL.json of DATA (impactsense calibrate)")
    ap.add_argument("--g12-gpa", type=float, nargs="*", default=[], help="twin variants: CAL's with this g12")
    ap.add_argument("--variant", action="append", default=[],
                    help="a twin variant: CAL's sim_params with KEY=VALUE[,KEY=VALUE] set (e.g. loss_factor=0.015; "
                         "a loss factor simulates with the modal solver)")
    ap.add_argument("--cache", type=Path, default=None, help="folder for the simulated cases (reused)")
    ap.add_argument("--draws", type=int, default=40, help="part 5's draws of calibration cases (0: none)")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", category=RuntimeWarning)     # a case without a usable twin drop: NaN means
    from impactsense.data import load_session

    session = load_session(args.data)
    cal = json.loads(Path(args.calibration).read_text())
    cal_cases = np.asarray(cal.get("drops", {}).get("case_ids", []), int)
    if not np.isin(cal_cases, session.case_id).any():
        raise SystemExit(f"{args.calibration}: drops.case_ids names no case of {session.name}")
    axis = float(cal["sim_params"].get("material_axes_deg") or 0.0)
    g12 = cal["sim_params"].get("g12_pa")
    variants = {f"CAL (g12 {g12 / 1e9:.1f} GPa)" if g12 else "CAL": cal}
    for g in args.g12_gpa:
        c = json.loads(json.dumps(cal))
        c["sim_params"]["g12_pa"] = g * 1e9
        variants[f"CAL with g12 {g:g} GPa"] = c
    for v in args.variant:
        c = json.loads(json.dumps(cal))
        for item in v.split(","):
            key, value = item.split("=")
            c["sim_params"][key.strip()] = float(value)
        variants[f"CAL with {v}"] = c
    tags = {name: f"g12-{(c['sim_params'].get('g12_pa') or 0) / 1e9:.2f}" + "".join(
        f"-{k}{c['sim_params'][k]:g}" for k in ("loss_factor", "damping_per_s")
        if c["sim_params"].get(k) != cal["sim_params"].get(k)) for name, c in variants.items()}
    sims = {name: simulate_cases(session, c, args.cache, tags[name]) for name, c in variants.items()}
    common = _common([s["cases"][s["ut"] == FULL] for s in sims.values()])
    print(f"{session.name}: {len(np.unique(session.case_id))} cases; calibration cases {cal_cases.tolist()}; "
          f"part 4 on the {len(common)} cases every variant simulates (less the calibration cases)")
    for name, sim in sims.items():
        report(name, sim, session, cal_cases, common, axis)
    if args.draws:
        draws(next(iter(sims.values())), session, axis, args.draws)
    kinds(next(iter(sims.values())), session, cal_cases, args.draws)
    return 0


def _common(sets: list[np.ndarray]) -> np.ndarray:
    out = sets[0]
    for s in sets[1:]:
        out = np.intersect1d(out, s)
    return out


if __name__ == "__main__":
    raise SystemExit(main())
