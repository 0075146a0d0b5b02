"""Per-drop pick error on a bond's channel: the changed session's drops against the reference's, the training
data retrain makes, and (when present) the reference's drops made again by the FEM with the session's true bond.

On a loop session folder (benchmarks/loop_sessions.py: REF "ref", the changed session, default "bond", and
optionally "ref-truebond"): diagnose, the bond sized on the recordings (loop.fit_bond), the effects put into the
reference's recordings (loop.measured_training_session), as `impactsense retrain` does. For each drop the bond
channel's onset less the travel model's time for its declared position, less the same for the mean of the other
three channels (us; the localiser fitted on the reference), is the channel's pick lag. Printed per drop set: the
median lag, its scatter over a drop's repetitions (within-case sd), its scatter about a cubic in position (what a
smooth correction cannot absorb), the channel's noise rms; and the changed session's lags against the cubic of each
other set at the session's positions (a pick bias the training data does not carry). Each under three onset
settings: the rig's, the diagnosed gain told to the core (channel_gain), and loop.onset_gains' (the gain times the
bond low-pass's gain at the others' pick frequency). No target: a measurement (docs/findings.md "A strong bond's
onset").

    python benchmarks/bench_bond_picks.py SESSIONS [--name bond] [--seed N]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from impactsense.data import load_session
from impactsense.loop import measured_training_session, onset_gains
from impactsense.pipeline import featurize, fit_localiser
from impactsense.signal import SignalConfig

from benchlib import sized_bond

PRETRIGGER = 64


def cubic(xy: np.ndarray, rig) -> np.ndarray:
    x, y = 2.0 * xy[:, 0] / rig.plate_x_mm - 1.0, 2.0 * xy[:, 1] / rig.plate_y_mm - 1.0
    return np.stack([np.ones_like(x), x, y, x * x, x * y, y * y, x ** 3, x * x * y, x * y * y, y ** 3], 1)


def pick_lag(session, cfg, channel: int) -> np.ndarray:
    """The channel's onset less the travel time, less the other channels' mean of the same (us per drop)."""
    toa = np.asarray(featurize(session.adc, cfg).toa_us, float)
    d = np.linalg.norm(session.xy_mm[:, None, :] - np.asarray(cfg.sensor_xy_mm, float)[None], axis=2)
    t = toa - d / float(cfg.velocity_mm_per_us)
    others = [c for c in range(4) if c != channel]
    return t[:, channel] - np.nanmean(t[:, others], axis=1)


def figures(session, lag: np.ndarray, channel: int) -> dict:
    ok = np.isfinite(lag)
    var = [np.var(lag[(session.case_id == c) & ok], ddof=1) for c in np.unique(session.case_id)
           if ((session.case_id == c) & ok).sum() > 1]
    A = cubic(session.xy_mm[ok], session.rig)
    coef = np.linalg.lstsq(A, lag[ok], rcond=None)[0]
    noise = np.median(np.asarray(session.adc[:, channel, :PRETRIGGER], float).std(axis=-1))
    return {"n": int(ok.sum()), "median": float(np.median(lag[ok])), "within": float(np.sqrt(np.mean(var))),
            "smooth": float(np.std(lag[ok] - A @ coef)), "noise": float(noise), "coef": coef}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sessions")
    ap.add_argument("--name", default="bond")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    folder = Path(args.sessions)
    ref, sess, det, accepted, ch = sized_bond(args.sessions, args.name, args.seed)
    if ch < 0:
        return 0
    cfg = fit_localiser(ref, np.arange(len(ref)), SignalConfig.for_rig(ref.rig))
    print(f"{args.name}: channel {ch} ({', '.join(f'{c.effect} {c.params}' for c in accepted)}); onset threshold "
          f"{cfg.onset_threshold_counts:g} counts or {cfg.onset_noise_factor:g} x the noise rms, AIC blend "
          f"{cfg.aic_blend:g}")
    with tempfile.TemporaryDirectory() as tmp:
        sets = {"reference": ref,
                "training": measured_training_session(ref, accepted, det["ref"], Path(tmp) / "t", args.seed)}
        if (folder / "ref-truebond").exists():
            sets["true bond"] = load_session(folder / "ref-truebond")
        told = [1.0] * 4
        told[ch] = next(float(c.params["gain"]) for c in accepted if c.effect == "sensor_gain" and c.sensor == ch)
        for tag, gains in (("rig's picks", [1.0] * 4), ("gain told", told),
                           ("onset_gains", onset_gains(sets["training"], accepted))):
            print(f"\n{tag} (channel_gain {gains[ch]:.3f}):")
            print("| drops | n | median lag us | within-case sd | about a cubic sd | noise rms |")
            print("|---|---|---|---|---|---|")
            got = {}
            for k, s in {**sets, args.name: sess}.items():
                c = cfg if k == "reference" else dataclasses.replace(cfg, channel_gain=gains)
                got[k] = f = figures(s, pick_lag(s, c, ch), ch)
                print(f"| {k} | {f['n']} | {f['median']:.1f} | {f['within']:.1f} | {f['smooth']:.1f} | "
                      f"{f['noise']:.2f} |")
            lag = pick_lag(sess, dataclasses.replace(cfg, channel_gain=gains), ch)
            for k in sets:
                d = lag - cubic(sess.xy_mm, sess.rig) @ got[k]["coef"]
                d = d[np.isfinite(d)]
                print(f"  {args.name} less the {k} cubic: mean {d.mean():+.1f} us, rms {np.sqrt(np.mean(d ** 2)):.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
