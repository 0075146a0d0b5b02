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


def _prepared(sessions: Path, cache: bool):
    """(reference as `diagnose` builds it against SESSIONS/ref, a function name -> that session's features)."""
    from impactsense import diagnose as D, residuals as R
    from impactsense.band_timing import band_picks
    from impactsense.data import load_session
    from impactsense.site_reference import choose_picker, noise_floor_reference

    path = sessions / ".identifiability-ref.pkl"
    if cache and path.exists():
        ref, picker = pickle.loads(path.read_bytes())
    else:
        baseline = load_session(sessions / "ref")
        Fb = R.extract(baseline)
        picker, _ = choose_picker(baseline, Fb)
        if picker is not None:
            Fb = R.repick(baseline, Fb, picker)
        ref = R.fit_reference(Fb, "calibrated")
        Fb, _ = D._with_band_picks(ref, baseline, Fb, baseline, Fb, picker)
        site, sigma = noise_floor_reference(ref, Fb)
        ref.sigma.update(sigma)
        ref.site = site
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


def study(sessions: Path, cache: bool = False) -> list[dict]:
    from impactsense.band_timing import band_resid

    ref, features = _prepared(sessions, cache)
    manifest = json.loads((sessions / "manifest.json").read_text())["sessions"]
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
        rows.append(row)
    return rows


def _weighted(rows, key):
    v = [(r[key]["slope_ratio"], r[key]["se"]) for r in rows if r.get(key)]
    if not v:
        return float("nan"), float("nan")
    x, se = np.array(v).T
    w = 1.0 / np.maximum(se, 1e-9) ** 2
    return float(np.sum(w * x) / w.sum()), float(1.0 / np.sqrt(w.sum()))


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
    args = ap.parse_args(argv)
    if not args.sessions:   # the default sessions' reference and moves
        import loop_sessions

        moves = [s["name"] for s in loop_sessions.spec_list(0) if s["name"].startswith("move-")]
        loop_sessions.generate(loop_sessions.parse(["--only", ",".join(["ref"] + moves)]))
        args.sessions = [loop_sessions.parse([]).out]
    rows = [r for s in args.sessions for r in study(Path(s), args.cache)]
    table(rows)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
