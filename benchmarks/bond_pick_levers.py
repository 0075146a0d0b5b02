"""Three pick-side levers on the bond row, measured without a model (docs/findings.md "Session 28: bondloop2").

On a loop session folder (`benchmarks/loop_sessions.py`; REF "ref", the bond session "bond") with
`bench_bond_inverse.py`'s scratch file of diagnose + fit_bond (`--cache`, made by a bench_bond_inverse run): the
measured training drops and the picks' settings as `impactsense retrain` makes them (loop.measured_training_session,
loop.pick_settings, the localiser fitted on the training drops), then per lever:

- physics: the physics position's MAE per axis (mm) on the training drops and the bond session, the core's and
  moved by `bench_bond_inverse.weighted_phys` with the bonded channel's pick weighted as 1.5 / 2 / 3 x as
  scattered as the others' (a per-channel weight in the localiser);
- factor: per onset_noise_factor 5 / 4 / 3.5 / 3 (the absolute threshold and AIC blend refitted as train does), the
  training drops' physics MAE and each channel's pick lag rms about the training drops' cubic in position (training
  / session; us);
- blend: the same lag rms for the threshold crossing, the AIC onset, and blends of the two (the core's aic_blend).

    python benchmarks/bond_pick_levers.py SESSIONS --cache FILE [--levers physics,factor,blend]
"""

from __future__ import annotations

import argparse
import dataclasses
import pickle
import tempfile
import warnings
from pathlib import Path

import numpy as np

from impactsense.data import load_session
from impactsense.loop import measured_training_session, pick_settings
from impactsense.pipeline import featurize, fit_localiser, physics_mae

from bench_bond_inverse import weighted_phys
from bench_bond_picks import cubic


def lags(session, toa_us: np.ndarray, cfg) -> np.ndarray:
    """(n, 4): each channel's onset less its travel time less the other channels' mean of the same (us)."""
    s = np.asarray(cfg.sensor_xy_mm, float)
    t = toa_us - np.linalg.norm(session.xy_mm[:, None, :] - s[None], axis=2) / float(cfg.velocity_mm_per_us)
    return np.stack([t[:, k] - np.nanmean(np.delete(t, k, axis=1), axis=1) for k in range(4)], 1)


def rms_about_cubic(train_s, a: np.ndarray, sess, b: np.ndarray) -> list[tuple[float, float]]:
    """Per channel: the training lags' and the session's rms about the training drops' cubic in position (us)."""
    out = []
    for k in range(4):
        ok = np.isfinite(a[:, k])
        coef = np.linalg.lstsq(cubic(train_s.xy_mm[ok], train_s.rig), a[ok, k], rcond=None)[0]
        ea = a[ok, k] - cubic(train_s.xy_mm[ok], train_s.rig) @ coef
        eb = b[:, k] - cubic(sess.xy_mm, sess.rig) @ coef
        eb = eb[np.isfinite(eb)]
        out.append((float(np.sqrt(np.mean(ea ** 2))), float(np.sqrt(np.mean(eb ** 2)))))
    return out


def fmt(rows, ch: int) -> str:
    return ", ".join(f"ch{k}{'*' if k == ch else ''} {a:.1f}/{b:.1f}" for k, (a, b) in enumerate(rows))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sessions")
    ap.add_argument("--cache", required=True, help="bench_bond_inverse.py's scratch file of diagnose + fit_bond")
    ap.add_argument("--levers", default="physics,factor,blend")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", message=".*sklearn.utils.parallel.delayed.*")
    folder = Path(args.sessions)
    det_ref, accepted, ch = pickle.loads(Path(args.cache).read_bytes())
    ref, sess = load_session(folder / "ref"), load_session(folder / "bond")
    levers = args.levers.split(",")
    with tempfile.TemporaryDirectory() as tmp:
        train_s = measured_training_session(ref, accepted, det_ref, Path(tmp) / "fit", 0)
        signal = pick_settings(train_s, accepted, ref)
        cfg = fit_localiser(train_s, np.arange(len(train_s)), signal)
        ft, fs = featurize(train_s.adc, cfg), featurize(sess.adc, cfg)
        print(f"{folder.name}: bonded channel {ch}; onset threshold {float(cfg.onset_threshold_counts):.0f} counts, "
              f"noise factor {float(cfg.onset_noise_factor):.1f}, AIC blend {float(cfg.aic_blend):.2f}; the bonded "
              f"channel's noise rms {np.median(fs.raw['noise_rms'][:, ch]):.2f} counts (median)", flush=True)
        if "physics" in levers:
            for name, s, f in (("training", train_s, ft), ("bond", sess, fs)):
                ok = f.usable
                row = [f"core {np.abs(f.phys_xy_mm[ok] - s.xy_mm[ok]).mean():.2f}"]
                for x in (1.5, 2.0, 3.0):
                    g = weighted_phys(f, cfg, [x if k == ch else 1.0 for k in range(4)])
                    row.append(f"x{x:g} {np.abs(g.phys_xy_mm[ok] - s.xy_mm[ok]).mean():.2f}")
                print(f"  physics MAE per axis (mm), {name} drops: " + ", ".join(row), flush=True)
        if "factor" in levers:
            for factor in (5.0, 4.0, 3.5, 3.0):
                c = fit_localiser(train_s, np.arange(len(train_s)), dataclasses.replace(signal, onset_noise_factor=factor))
                a, b = featurize(train_s.adc, c), featurize(sess.adc, c)
                rows = rms_about_cubic(train_s, lags(train_s, np.asarray(a.toa_us, float), c),
                                       sess, lags(sess, np.asarray(b.toa_us, float), c))
                print(f"  noise factor {factor:g} (threshold {float(c.onset_threshold_counts):.0f}, blend "
                      f"{float(c.aic_blend):.2f}): training physics MAE {physics_mae(train_s, np.arange(len(train_s)), c):.2f} "
                      f"mm; lag rms training/session (us): {fmt(rows, ch)}", flush=True)
        if "blend" in levers:
            us = 1e6 / float(cfg.fs_hz)
            for blend in (0.0, 0.2, 0.35, 0.5, 0.7, 1.0):
                def toa(f):
                    return ((1 - blend) * np.asarray(f.raw["toa_threshold"], float)
                            + blend * np.asarray(f.raw["toa_aic"], float)) * us
                rows = rms_about_cubic(train_s, lags(train_s, toa(ft), cfg), sess, lags(sess, toa(fs), cfg))
                print(f"  AIC blend {blend:g}: lag rms training/session (us): {fmt(rows, ch)}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
