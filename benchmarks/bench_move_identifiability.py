"""Why a moved disc reads as a constant delay: per move session of `loop_sessions.py`, how much of the true move's
timing signature is a constant, and how well the session's picks measure the rest.

    python3 benchmarks/bench_move_identifiability.py [SESSIONS_DIR ...] [--cache] [--json OUT]

(no SESSIONS_DIR: the moves of `loop_sessions.py`'s default sessions, seed 0, made in /tmp/impactsense-loop if missing)

For a disc i moved by m, the path to impact k changes by -u_ik . m (u_ik the unit vector from the disc to the
impact): its mean over the session's impacts is what a constant delay can take, its spread (sd, mm) is the move's
own signature. The channel's drop-centred contrast (its residual against the other channels' mean, as
`effects.sensor_position.direction_test` reads it) is regressed on the true path change, threshold and band picks
(`band_timing`) alike; the slope over the pick set's slowness is 1 for the move model, 0 for a delay, with its
delete-a-case jackknife standard error. Where that error is as large as the slope, no held-out figure can tell the
move from a delay on these picks. Per session also the reference's per-case scatter against the pick floor
(within-case scatter / sqrt(reps)): the part of the reference's error a move has to stand out from.
`--cache`: the reference's and each session's features are kept in SESSIONS_DIR/.identifiability-*.pkl (this
benchmark's own files) and reused.

`--unchanged` (the folder's `same-*` sessions): what the noise of new positions lets any move test reach. Per channel,
the robust sd of the unchanged sessions' case-mean contrasts (threshold and band picks: what a move's signature has to
stand out from, the reference's error at new positions included), the short-range part of that error (semivariance
of the case means by distance between positions, physics reference, the within-case share taken out: a smooth
reference, GP or twin, can only learn what is correlated at the reference's case spacing), and per move the case-level
figures at that noise (`expected_evidence`): the true move's expected log-likelihood gain over no change and over a
constant delay, and the spread of an unbiased fit of (dx, dy) with its probability of landing within --tolerance-mm.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np


def signature_slope(ref, F, sensor: int, dxy, band: bool = False) -> dict:
    """The channel's contrast regressed on the path change of the move dxy (mm): {'slope_ratio': slope / the pick
    set's slowness (1: the move model, 0: a constant), 'se': its delete-a-case jackknife standard error,
    'path_mean_mm', 'path_sd_mm'}; None without the pick set."""
    from impactsense.band_timing import band_resid

    r = band_resid(ref, F) if band else ref.toa_resid(F)
    if r is None:
        return None
    slowness = ref.band["slowness_us_per_mm"] if band else ref.slowness_us_per_mm
    _, _, ux, uy = ref.geometry(F)
    path = -(ux[:, sensor] * dxy[0] + uy[:, sensor] * dxy[1])
    others = [j for j in range(r.shape[1]) if j != sensor]
    y = r[:, sensor] - r[:, others].mean(axis=1)
    ok = np.isfinite(y)
    X = np.c_[np.ones(ok.sum()), path[ok]]
    yy, case = y[ok], np.asarray(F.case_id)[ok]
    b = np.linalg.lstsq(X, yy, rcond=None)[0]
    loo = np.array([np.linalg.lstsq(X[case != c], yy[case != c], rcond=None)[0][1] for c in np.unique(case)])
    g = len(loo)
    se = float(np.sqrt((g - 1) / g * ((loo - loo.mean()) ** 2).sum()))
    return {"slope_ratio": float(b[1] / slowness), "se": se / slowness, "path_mean_mm": float(path.mean()),
            "path_sd_mm": float(path.std())}


def case_scatter(r: np.ndarray, case_id) -> tuple[np.ndarray, np.ndarray]:
    """Per channel: the sd of the case means of r and the pick floor (the within-case sd / sqrt(drops per case))."""
    ids, inv = np.unique(case_id, return_inverse=True)
    means, floor = [], []
    for c in range(r.shape[1]):
        x = r[:, c]
        ok = np.isfinite(x)
        n = np.bincount(inv[ok], minlength=len(ids))
        m = np.bincount(inv[ok], weights=x[ok], minlength=len(ids)) / np.maximum(n, 1)
        w = x[ok] - m[inv[ok]]
        reps = float(np.mean(n[n > 0]))
        within = np.sqrt(np.sum(w ** 2) / max(ok.sum() - np.sum(n > 0), 1))
        means.append(float(np.std(m[n > 0])))
        floor.append(float(within / np.sqrt(reps)))
    return np.array(means), np.array(floor)


def expected_evidence(ref, F, sensor: int, dxy, sigma_us: float, band_sigma_us: float | None = None,
                      tolerance_mm: float = 2.0, draws: int = 20000) -> dict:
    """Case-level figures of the move dxy of disc `sensor` at F's positions, each case's contrast carrying an
    independent error of sd sigma_us (threshold picks) and band_sigma_us (band picks, None: not used): the expected
    log-likelihood gain of the true move over no change (half its noncentrality, sum_k (s p_k)^2 / (2 sigma^2), p_k
    the path change at case k), the same over the best constant delay (p_k less its mean), and the Fisher covariance
    of a fit of (dx, dy) (no constant) with its sd axes and the probability that it lands within tolerance_mm
    of the truth (Monte Carlo on that Gaussian)."""
    _, _, ux, uy = ref.geometry(F)
    _, first = np.unique(np.asarray(F.case_id), return_index=True)
    u = np.c_[ux[first, sensor], uy[first, sensor]]
    path = -(u @ np.asarray(dxy, float))
    w = ref.slowness_us_per_mm ** 2 / sigma_us ** 2
    if band_sigma_us is not None and ref.band is not None:
        w += ref.band["slowness_us_per_mm"] ** 2 / band_sigma_us ** 2
    cov = np.linalg.inv(w * u.T @ u)
    z = np.random.default_rng(0).multivariate_normal([0.0, 0.0], cov, draws)
    return {"gain_vs_none": float(w * np.sum(path ** 2) / 2),
            "gain_vs_delay": float(w * np.sum((path - path.mean()) ** 2) / 2),
            "sd_axes_mm": np.sqrt(np.linalg.eigvalsh(cov)).tolist(),
            "p_within_tolerance": float(np.mean(np.hypot(z[:, 0], z[:, 1]) <= tolerance_mm))}


def contrast_case_means(r: np.ndarray, case_id, sensor: int) -> np.ndarray:
    """The case means of channel `sensor`'s contrast (its residual less the other channels' mean): what a change on
    that channel alone moves by the whole change."""
    others = [j for j in range(r.shape[1]) if j != sensor]
    y = r[:, sensor] - r[:, others].mean(axis=1)
    ids, inv = np.unique(case_id, return_inverse=True)
    ok = np.isfinite(y)
    n = np.bincount(inv[ok], minlength=len(ids))
    m = np.bincount(inv[ok], weights=y[ok], minlength=len(ids)) / np.maximum(n, 1)
    return m[n > 0]


def robust_sd(x: np.ndarray) -> float:
    x = np.asarray(x)[np.isfinite(x)]
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def short_range(parts, bins_mm=(0.0, 3.0, 6.0, 12.0, 25.0, 50.0, 1e9)) -> list[dict]:
    """Semivariance of per-case mean residuals by the distance between the cases' positions, pooled over sessions,
    each pair's within-case share (the case means' own pick noise) taken out. parts: (xy [G, 2], means [G, C],
    within variance of each mean [G, C]) per session; pairs are formed within and across sessions. Returns per bin
    {'lo_mm', 'hi_mm', 'pairs', 'excess_us': per channel sqrt of the excess (0 where negative)}."""
    xy = np.concatenate([p[0] for p in parts])
    m = np.concatenate([p[1] for p in parts])
    v = np.concatenate([p[2] for p in parts])
    iu = np.triu_indices(len(xy), 1)
    dist = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))[iu]
    semi = 0.5 * ((m[:, None, :] - m[None, :, :]) ** 2)[iu] - 0.5 * (v[:, None, :] + v[None, :, :])[iu]
    out = []
    for lo, hi in zip(bins_mm[:-1], bins_mm[1:]):
        sel = (dist >= lo) & (dist < hi)
        exc = np.sqrt(np.maximum(semi[sel].mean(axis=0), 0.0)) if sel.any() else np.full(m.shape[1], np.nan)
        out.append({"lo_mm": lo, "hi_mm": hi, "pairs": int(sel.sum()), "excess_us": exc.tolist()})
    return out


def case_parts(r: np.ndarray, F) -> tuple:
    """(case positions [G, 2], case means [G, C], variance of each mean from its within-case scatter [G, C]) of the
    residual r, cases with >= 2 drops with all channels."""
    xy, means, var = [], [], []
    for c in np.unique(F.case_id):
        rows = np.flatnonzero(F.case_id == c)
        x = r[rows][np.all(np.isfinite(r[rows]), axis=1)]
        if len(x) < 2:
            continue
        xy.append([F.x_mm[rows[0]], F.y_mm[rows[0]]])
        means.append(x.mean(axis=0))
        var.append(x.var(axis=0, ddof=1) / len(x))
    return np.array(xy), np.array(means), np.array(var)


def noise_of_new_positions(ref, unchanged: list) -> dict:
    """Per channel from the unchanged sessions' features: the robust sd of their case-mean contrasts (threshold,
    band), the same of the physics reference alone (no site terms), and the short-range semivariance table
    (`short_range`, physics reference)."""
    from impactsense.band_timing import band_resid

    out = {"threshold_us": [], "band_us": [], "physics_threshold_us": []}
    for c in range(4):
        out["threshold_us"].append(robust_sd(np.concatenate([contrast_case_means(ref.toa_resid(F), F.case_id, c)
                                                             for F in unchanged])))
        out["physics_threshold_us"].append(robust_sd(np.concatenate(
            [contrast_case_means(ref.toa_resid(replace(F, site_toa_us=None)), F.case_id, c) for F in unchanged])))
        rb = [band_resid(ref, F) for F in unchanged]
        out["band_us"].append(robust_sd(np.concatenate([contrast_case_means(r, F.case_id, c)
                                                        for r, F in zip(rb, unchanged)]))
                              if all(r is not None for r in rb) else None)
    out["short_range"] = short_range([case_parts(ref.toa_resid(replace(F, site_toa_us=None)), F) for F in unchanged])
    return out


def _prepared(sessions: Path, cache: bool):
    """(reference as `diagnose` builds it against SESSIONS/ref, a function name -> that session's features)."""
    from impactsense import diagnose as D, residuals as R
    from impactsense.band_timing import band_picks
    from impactsense.data import load_session

    path = sessions / ".identifiability-ref.pkl"
    if cache and path.exists():
        ref, picker = pickle.loads(path.read_bytes())
    else:
        ref, _, picker, _, _ = D.prepared_reference(load_session(sessions / "ref"))
        if cache:
            path.write_bytes(pickle.dumps((ref, picker)))

    def features(name: str):
        p = sessions / f".identifiability-{name}.pkl"
        if cache and p.exists():
            return pickle.loads(p.read_bytes())
        data = load_session(sessions / name)
        F = R.extract(data, picker)
        if ref.band is not None:
            F = replace(F, toa_band_us=band_picks(data, picker, ref.band["setting"]))
        F = ref.site.attach(F)
        if cache:
            p.write_bytes(pickle.dumps(F))
        return F

    return ref, features


def study(sessions: Path, cache: bool = False, unchanged: bool = False, tolerance_mm: float = 2.0) -> list[dict]:
    from impactsense.band_timing import band_resid

    ref, features = _prepared(sessions, cache)
    manifest = json.loads((sessions / "manifest.json").read_text())["sessions"]
    noise = None
    if unchanged:
        same = [n for n, spec in manifest.items() if n.startswith("same-") and (sessions / n).exists()]
        noise = noise_of_new_positions(ref, [features(n) for n in same]) if same else None
        if noise is not None:
            noise_table(sessions.name, noise)
    rows = []
    for name, spec in manifest.items():
        truth = spec.get("truth")
        if truth is None or truth["effect"] != "sensor_position":
            continue
        F = features(name)
        s, p = truth["sensor"], truth["params"]
        dxy = (p["dx_mm"], p["dy_mm"])
        row = {"sessions": sessions.name, "session": name, "sensor": s, "move_mm": [float(v) for v in dxy],
               "threshold": signature_slope(ref, F, s, dxy), "band": signature_slope(ref, F, s, dxy, band=True)}
        sd, floor = case_scatter(ref.toa_resid(F), F.case_id)
        row["case_sd_us"], row["floor_us"] = sd.tolist(), floor.tolist()
        rb = band_resid(ref, F)
        if rb is not None:
            bsd, bfloor = case_scatter(rb, F.case_id)
            row["band_case_sd_us"], row["band_floor_us"] = bsd.tolist(), bfloor.tolist()
        if noise is not None:
            row["expected"] = expected_evidence(ref, F, s, dxy, noise["threshold_us"][s], noise["band_us"][s],
                                                tolerance_mm)
        rows.append(row)
    return rows


def _weighted(rows, key):
    v = [(r[key]["slope_ratio"], r[key]["se"]) for r in rows if r.get(key)]
    if not v:
        return float("nan"), float("nan")
    x, se = np.array(v).T
    w = 1.0 / np.maximum(se, 1e-9) ** 2
    return float(np.sum(w * x) / w.sum()), float(1.0 / np.sqrt(w.sum()))


def noise_table(name: str, noise: dict) -> None:
    physics = np.round(noise["physics_threshold_us"], 2).tolist()
    print(f"{name}: unchanged sessions' case-mean contrast sd per channel (us): threshold "
          f"{np.round(noise['threshold_us'], 2).tolist()} (physics alone {physics}), "
          f"band {[None if v is None else round(v, 2) for v in noise['band_us']]}")
    print("  short-range excess of the case means (physics reference, per channel, us): " + "; ".join(
        f"{b['lo_mm']:g}-{b['hi_mm']:g} mm ({b['pairs']}) {np.round(b['excess_us'], 2).tolist()}"
        for b in noise["short_range"]))


def expected_table(rows, tolerance_mm: float) -> None:
    print(f"\n| sessions | move | disc | expected gain over none / over a delay (nats, case level) | "
          f"fit sd axes (mm) | P(within {tolerance_mm:g} mm) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        e = r.get("expected")
        if e:
            print(f"| {r['sessions']} | {r['session']} | {r['sensor']} | {e['gain_vs_none']:.1f} / "
                  f"{e['gain_vs_delay']:.1f} | {e['sd_axes_mm'][0]:.2f} / {e['sd_axes_mm'][1]:.2f} | "
                  f"{e['p_within_tolerance']:.2f} |")


def table(rows) -> None:
    print("| sessions | move | disc | path change mean / sd (mm) | threshold slope / s (+- se) | band slope / s_band "
          "(+- se) | case sd / floor, threshold (us) | band (us) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        t, b = r["threshold"], r["band"]
        band = f"{b['slope_ratio']:+.2f} +- {b['se']:.2f}" if b else "-"
        s = r["sensor"]
        bsd = (f"{r['band_case_sd_us'][s]:.1f} / {r['band_floor_us'][s]:.1f}" if "band_case_sd_us" in r else "-")
        print(f"| {r['sessions']} | {r['session']} | {s} | {t['path_mean_mm']:+.1f} / {t['path_sd_mm']:.1f} | "
              f"{t['slope_ratio']:+.2f} +- {t['se']:.2f} | {band} | {r['case_sd_us'][s]:.1f} / {r['floor_us'][s]:.1f} "
              f"| {bsd} |")
    mt, st = _weighted(rows, "threshold")
    mb, sb = _weighted(rows, "band")
    print(f"\nweighted mean slope / slowness over {len(rows)} moves: threshold {mt:.2f} +- {st:.2f}, band {mb:.2f} +- "
          f"{sb:.2f} (1: the move model)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sessions", nargs="*", help="folders written by loop_sessions.py")
    ap.add_argument("--cache", action="store_true", help="keep and reuse the features in each folder")
    ap.add_argument("--json", default=None, help="write the rows here")
    ap.add_argument("--unchanged", action="store_true",
                    help="the noise of new positions from the folder's same-* sessions, each move's expected figures")
    ap.add_argument("--tolerance-mm", type=float, default=2.0, help="a move's size tolerance (issue 16: 2 mm)")
    args = ap.parse_args(argv)
    if not args.sessions:   # the default sessions' reference and moves
        import loop_sessions

        moves = [s["name"] for s in loop_sessions.spec_list(0) if s["name"].startswith("move-")]
        loop_sessions.generate(loop_sessions.parse(["--only", ",".join(["ref"] + moves)]))
        args.sessions = [loop_sessions.parse([]).out]
    rows = [r for s in args.sessions for r in study(Path(s), args.cache, args.unchanged, args.tolerance_mm)]
    table(rows)
    if args.unchanged:
        expected_table(rows, args.tolerance_mm)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
