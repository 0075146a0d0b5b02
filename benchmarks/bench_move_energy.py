"""Does a moved disc's energy tell a move from a constant delay? (issue 16). A study: prints figures, no target.

    python3 benchmarks/bench_move_energy.py [--sessions /tmp/impactsense-loop] [--seed 0] [any loop_sessions.py
        option, e.g. --rig RIG --calibration rig]   (the reference and the eight moves are built when missing)

The reference is built as `impactsense.diagnose` builds it (the chosen picks, the calibrated physics reference
and its site terms). For each amplitude observable of the core (the whole capture's energy, the first and
largest peak, the energy of the first of the five windows after the onset) the reference learns it as the
diagnosis learns its log energy: a distance law a d + b ln d + a per-channel gain, plus one Gaussian process
per channel of the drop-centred residual over (x, y, height). A disc moved by m changes channel i's distance
to each impact by -u . m (u the unit vector to the impact), so the law predicts the log-amplitude change
(a + b / d) (-u . m): the move's energy signature. A constant delay changes no amplitude.

For each `move-*` session (the truth known) it regresses channel i's amplitude residual against the others'
mean (the drop-centred contrast, e_k gone) on the true move's signature: slope 1 is what the law predicts,
0 what a delay predicts. Standard errors are delete-a-case jackknifes (a case's drops share their landing and
site error). The same for the timing (the move's ToA signature -s u . m) as the yardstick. Also printed: the
signature's rms over the drops against the contrast's residual rms.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import loop_sessions  # noqa: E402

MOVES = [f"move-{deg}" for deg in range(0, 360, 45)]
OBSERVABLES = ("energy", "first_peak", "peak", "window0")


def amplitudes(session, picker) -> dict:
    """Log amplitude observables [R, 4] of the core's features at the diagnosis's picks."""
    from impactsense import _core
    from impactsense import residuals as R
    from impactsense.signal import core_config, core_samples

    cfg = core_config(session.rig, **R.timing_picker(picker))
    f = _core.extract_batch(core_samples(session.adc, cfg), cfg)
    log = lambda v: np.log(np.maximum(np.asarray(v, float), 1.0))  # noqa: E731
    return {"energy": log(f["energy"]), "first_peak": log(f["first_peak"]), "peak": log(f["peak"]),
            "window0": log(np.asarray(f["window_energy"], float)[:, :, 0])}


def distances(F, sxy) -> np.ndarray:
    return np.hypot(F.x_mm[:, None] - sxy[None, :, 0], F.y_mm[:, None] - sxy[None, :, 1])


def learn(F, v: np.ndarray):
    """The law's (a, b, gains) and the per-channel GPs of the residual, fitted on the reference's drops."""
    from impactsense import residuals as R
    from impactsense.site_reference import _case_means, _gp

    d = distances(F, F.sensor_xy_mm)
    cols = [R.centre(d).ravel(), R.centre(np.log(d)).ravel()]
    for i in range(1, 4):
        e = np.zeros_like(d)
        e[:, i] = 1.0
        cols.append(R.centre(e).ravel())
    sol, _ = R._robust_lstsq(np.stack(cols, 1), R.centre(v).ravel())
    law = (float(sol[0]), float(sol[1]), np.r_[0.0, sol[2:5]])
    r = R.centre(v - (law[0] * d + law[1] * np.log(d) + law[2]))
    X, means, _ = _case_means(F, r, np.ones_like(r, bool))
    return law, [_gp(X, means[:, c]) for c in range(4)]


def contrast_slope(y: np.ndarray, sig: np.ndarray, case_id: np.ndarray) -> tuple[float, float, float]:
    """(slope, its delete-a-case jackknife standard error, residual rms) of y on [1, sig]."""
    X = np.c_[np.ones(len(y)), sig]
    b = np.linalg.lstsq(X, y, rcond=None)[0]
    _, inv = np.unique(case_id, return_inverse=True)
    G = int(inv.max()) + 1
    loo = np.array([np.linalg.lstsq(X[inv != g], y[inv != g], rcond=None)[0][1] for g in range(G)])
    se = float(np.sqrt((G - 1) / G * np.sum((loo - loo.mean()) ** 2)))
    return float(b[1]), se, float(np.std(y - X @ b))


def study(sessions: Path) -> list[dict]:
    from impactsense import residuals as R
    from impactsense.data import load_session
    from impactsense.site_reference import _inputs, choose_picker, noise_floor_reference

    base = load_session(sessions / "ref")
    Fb = R.extract(base)
    picker, _ = choose_picker(base, Fb)
    Fb = R.repick(base, Fb, picker) if picker is not None else Fb
    ref = R.fit_reference(Fb, "calibrated")
    site, sigma = noise_floor_reference(ref, Fb)
    ref.sigma.update(sigma)
    amp_ref = amplitudes(base, picker)
    learned = {k: learn(Fb, amp_ref[k]) for k in OBSERVABLES}
    manifest = json.loads((sessions / "manifest.json").read_text())["sessions"]
    rows = []
    for name in [n for n in MOVES if n in manifest]:
        truth = manifest[name]["truth"]
        i, m = truth["sensor"], np.array([truth["params"]["dx_mm"], truth["params"]["dy_mm"]])
        sess = load_session(sessions / name)
        F = site.attach(R.extract(sess, picker))
        d, _, ux, uy = ref.geometry(F)
        dd = -(ux[:, i] * m[0] + uy[:, i] * m[1])   # the moved disc's change of distance to each impact
        ok = np.all(np.isfinite(F.toa_us), axis=1) & ~F.clipped.any(axis=1)
        others = [j for j in range(4) if j != i]
        row = {"session": name, "sensor": i, "move_mm": m.tolist()}
        rt = ref.toa_resid(F)
        tsig = ref.slowness_us_per_mm * dd
        row["timing"] = (*contrast_slope((rt[:, i] - rt[:, others].mean(1))[ok], tsig[ok], F.case_id[ok]),
                         float(np.std(tsig[ok])))
        amp = amplitudes(sess, picker)
        for k, ((a, b, g), gps) in learned.items():
            pred = a * d + b * np.log(d) + g + np.stack([gp.predict(_inputs(F)) for gp in gps], axis=1)
            r = R.centre(amp[k] - pred)
            sig = (a + b / d[:, i]) * dd
            row[k] = (*contrast_slope((r[:, i] - r[:, others].mean(1))[ok], sig[ok], F.case_id[ok]),
                      float(np.std(sig[ok])))
        rows.append(row)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", default="/tmp/impactsense-loop")
    ap.add_argument("--seed", type=int, default=0)
    args, gen = ap.parse_known_args(argv)
    only = ",".join(["ref"] + MOVES)
    loop_sessions.generate(loop_sessions.parse(["--out", args.sessions, "--seed", str(args.seed), "--only", only]
                                               + gen))
    rows = study(Path(args.sessions))
    keys = ("timing",) + OBSERVABLES
    print("| move | sensor | " + " | ".join(f"{k}: slope +- se (signature / residual rms)" for k in keys) + " |")
    print("|---|---|" + "---|" * len(keys))
    for r in rows:
        cells = [f"{r[k][0]:+.2f} +- {r[k][1]:.2f} ({r[k][3]:.3g} / {r[k][2]:.3g})" for k in keys]
        print(f"| {r['session']} ({r['move_mm'][0]:+.1f}, {r['move_mm'][1]:+.1f}) | {r['sensor']} | "
              + " | ".join(cells) + " |")
    z = {k: [r[k][0] / r[k][1] for r in rows] for k in keys}
    print("slope / se (1 / se expected for a move, 0 for a delay): "
          + "; ".join(f"{k} {', '.join(f'{v:+.1f}' for v in z[k])}" for k in keys))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
