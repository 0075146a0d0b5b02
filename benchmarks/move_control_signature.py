"""How much of each true move the reference's threshold picks show, and how much the same positions show with no
move (the move's control): the direction test (`effects.sensor_position.direction_test`) on the moved disc for
the session and for its control, its (dx, dy) as the fraction of the true move along and across it, and the
session-minus-control contrast's slope on the move's predicted signature -s u . d (1: the picks carry the whole
move; the per-drop residual sd is the two draws' pick noise); and the move's fit (`sensor_position.fit`, both pick
sets) on the session and on its control: its error against the truth and the control's apparent move (mm). The
reference is diagnose's (`diagnose_names.prepare`).

    python3 benchmarks/move_control_signature.py FOLDER [--prep PKL] [--cache DIR] [--only move-14,move-284]

FOLDER: a `loop_sessions.py --controls` folder (its manifest's sensor_position sessions and their -control);
--prep: a pickled `prepare(FOLDER)` (made and saved there when missing); --cache: features per session."""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_names as DN  # noqa: E402


def contrast(ref, F, s: int) -> np.ndarray:
    r = ref.toa_resid(F)
    return r[:, s] - r[:, [j for j in range(4) if j != s]].mean(axis=1)


def along_across(d: dict, tv: np.ndarray) -> tuple[float, float]:
    b = np.array([d["dx_mm"], d["dy_mm"]])
    n2 = float(tv @ tv)
    return float(b @ tv) / n2, float(b[0] * tv[1] - b[1] * tv[0]) / n2


def signature_slope(ref, Fm, Fc, s: int, tv: np.ndarray) -> dict | None:
    """The session-minus-control contrast regressed on the move's signature (same drops: None otherwise)."""
    if len(Fm) != len(Fc) or not np.allclose(np.c_[Fm.x_mm, Fm.y_mm], np.c_[Fc.x_mm, Fc.y_mm]):
        return None
    dy = contrast(ref, Fm, s) - contrast(ref, Fc, s)
    _, _, ux, uy = ref.geometry(Fm)
    pred = -ref.slowness_us_per_mm * (ux[:, s] * tv[0] + uy[:, s] * tv[1])
    ok = np.isfinite(dy) & np.isfinite(pred)
    X = np.c_[np.ones(ok.sum()), pred[ok] - pred[ok].mean()]
    coef = np.linalg.lstsq(X, dy[ok], rcond=None)[0]
    return {"slope": float(coef[1]), "signature_sd_us": float(pred[ok].std()),
            "residual_sd_us": float(np.std(dy[ok] - X @ coef))}


def main(argv=None) -> int:
    from impactsense.effects import EFFECTS
    from impactsense.effects.sensor_position import direction_test

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--prep", type=Path)
    ap.add_argument("--cache", type=Path)
    ap.add_argument("--only", default="")
    a = ap.parse_args(argv)
    sessions = json.loads((a.folder / "manifest.json").read_text())["sessions"]
    moves = [k for k, v in sessions.items() if (v.get("truth") or {}).get("effect") == "sensor_position"
             and not k.endswith("-control") and (a.folder / f"{k}-control").is_dir()]
    if a.only:
        moves = [m for m in moves if m in a.only.split(",")]
    if a.prep and a.prep.exists():
        P = pickle.loads(a.prep.read_bytes())
    else:
        P = DN.prepare(a.folder)
        if a.prep:
            a.prep.write_bytes(pickle.dumps(P))
    if a.cache:
        a.cache.mkdir(parents=True, exist_ok=True)

    def feats(name):
        pk = a.cache / f"F_{name}.pkl" if a.cache else None
        if pk is not None and pk.exists():
            return pickle.loads(pk.read_bytes())
        F = DN.features(P, a.folder, name)
        if pk is not None:
            pk.write_bytes(pickle.dumps(F))
        return F

    ref = P["ref"]
    print(f"picker {json.dumps(P['picker'])}")
    print("| move | disc | truth (dx, dy) mm | session: direction p; along, across | control: p; along, across "
          "| move - control: slope; residual sd us | fit error; control's fit mm |")
    print("|---|---|---|---|---|---|---|")
    rows = []
    for name in moves:
        t = sessions[name]["truth"]
        s, tv = t["sensor"], np.array([t["params"]["dx_mm"], t["params"]["dy_mm"]])
        Fm, Fc = feats(name), feats(f"{name}-control")
        dm, dc = direction_test(ref, Fm, s), direction_test(ref, Fc, s)
        am, ac = along_across(dm, tv), along_across(dc, tv)
        sig = signature_slope(ref, Fm, Fc, s, tv)
        fit = {k: EFFECTS["sensor_position"].fit(ref, F, s) for k, F in (("m", Fm), ("c", Fc))}
        fm, fc = (np.array([fit[k]["dx_mm"], fit[k]["dy_mm"]]) for k in ("m", "c"))
        fe = (float(np.hypot(*(fm - tv))), float(np.hypot(*fc)))
        rows.append((ac, sig, fe))
        sig_txt = "-" if sig is None else f"{sig['slope']:.2f}; {sig['residual_sd_us']:.2f}"
        print(f"| {name} | S{s + 1} | ({tv[0]:+.1f}, {tv[1]:+.1f}) | {dm['p_value']:.3f}; {am[0]:+.2f}, {am[1]:+.2f} "
              f"| {dc['p_value']:.3f}; {ac[0]:+.2f}, {ac[1]:+.2f} | {sig_txt} | {fe[0]:.2f}; {fe[1]:.2f} |", flush=True)
    if rows:
        app = np.array([r[0] for r in rows])
        sl = [r[1] for r in rows if r[1] is not None]
        print(f"controls' apparent move, rms (fraction of the true move): along {np.sqrt(np.mean(app[:, 0] ** 2)):.2f}, "
              f"across {np.sqrt(np.mean(app[:, 1] ** 2)):.2f}, both {np.sqrt(np.mean(np.sum(app ** 2, axis=1))):.2f}")
        fe = np.array([r[2] for r in rows])
        print(f"move fit: mean error {fe[:, 0].mean():.2f} mm, {int(np.sum(fe[:, 0] <= 2.0))} of {len(fe)} within 2 mm; "
              f"controls' fitted apparent move, mean {fe[:, 1].mean():.2f} mm")
        if sl:
            print(f"move - control: mean slope {np.mean([r['slope'] for r in sl]):.2f}, "
                  f"mean residual sd {np.mean([r['residual_sd_us'] for r in sl]):.2f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main())
