"""How the core's picks scatter under the loop's signal-level noise changes (a study for issue 16, no target):
a session's own drops picked clean and again with mains hum or extra white noise put in, as
benchmarks/loop_sessions.py puts them into its `hum` and `noise` sessions (`loop_sessions.signal_change`),
several draws each.

    python3 benchmarks/bench_noise_picks.py SESSION [--hum 26.2] [--white 5,9.77] [--draws 2]
        [--set FIELD=VALUE ...] [--same]

--set changes a core configuration field (SignalConfig) for the changed drops' picks, e.g. --set aic_blend=1
--set onset_noise_factor=4; the clean picks are the rig's configuration (the yardstick), or with --same the same
settings as the changed picks (how well the changed drops repeat their own clean picks: what a model trained on
those settings with the change in its training drops sees).

Prints per change: each channel's ToA shift (median) and its robust spread (1.4826 MAD, us) against the clean
pick of the same drop, the DToA's robust spread per pair and its mean over the pairs (what the localiser and the
forests see), the share of DToAs more than 50 us off, and the core's onset threshold (median, counts).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import loop_sessions  # noqa: E402

FAR_US = 50.0


def changed_adc(session, truth: dict, seed: int) -> np.ndarray:
    """The session's recordings with the change put in (loop_sessions' signal model, on the recorded counts)."""
    rig = session.rig
    a = loop_sessions.signal_change(np.asarray(session.adc, float) - rig.bias_counts, truth, rig, seed)
    return np.clip(np.rint(a + rig.bias_counts), 0, rig.adc_max).astype(np.uint16)


def dtoa(toa: np.ndarray) -> np.ndarray:
    from impactsense._core import PAIR_I, PAIR_J
    return toa[:, list(PAIR_I)] - toa[:, list(PAIR_J)]


def robust_sd(d: np.ndarray) -> np.ndarray:
    return 1.4826 * np.nanmedian(np.abs(d - np.nanmedian(d, 0)), 0)


def scatter(session, truth: dict, draws: int, overrides: dict, same: bool = False) -> dict:
    """The picks' shift and spread under `truth`'s change against the clean picks of the same drops (the rig's
    settings, or with `same` the changed picks' own)."""
    from impactsense.pipeline import featurize
    from impactsense.signal import SignalConfig

    cfg = SignalConfig.for_rig(session.rig, **overrides)
    clean = np.asarray(featurize(session.adc, cfg if same else SignalConfig.for_rig(session.rig)).toa_us, float)
    shift, dd, thr = [], [], []
    for j in range(draws):
        f = featurize(changed_adc(session, truth, 1000 + j), cfg)
        toa = np.asarray(f.toa_us, float)
        shift.append(toa - clean)
        dd.append(dtoa(toa) - dtoa(clean))
        thr.append(np.maximum(float(cfg.onset_threshold_counts),
                              float(cfg.onset_noise_factor) * np.asarray(f.raw["noise_rms"], float)))
    shift, dd = np.concatenate(shift), np.concatenate(dd)
    return {"shift_us": np.nanmedian(shift, 0), "shift_sd_us": robust_sd(shift), "dtoa_sd_us": robust_sd(dd),
            "far": float(np.mean(~(np.abs(dd) <= FAR_US))), "threshold_counts": float(np.median(np.concatenate(thr)))}


def main(argv=None) -> int:
    from impactsense.data import load_session

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("session")
    ap.add_argument("--hum", type=float, default=26.2, help="50 Hz hum amplitude (counts; 0: none)")
    ap.add_argument("--white", default="5,9.77", help="extra white noise levels (counts rms)")
    ap.add_argument("--draws", type=int, default=2)
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    ap.add_argument("--same", action="store_true", help="clean picks with the --set settings too")
    args = ap.parse_args(argv)
    overrides = {k: (int(v) if v.lstrip("-").isdigit() else float(v)) for k, v in (s.split("=", 1) for s in args.set)}
    session = load_session(args.session)
    changes = ([("hum %.1f" % args.hum, {"params": {"hum_hz": 50.0, "hum_counts": args.hum}})] if args.hum else [])
    changes += [("white %s" % w, {"params": {"noise_counts_rms": float(w)}}) for w in args.white.split(",") if w]
    print(f"{args.session}: {len(session)} drops, {args.draws} draws; changed picks with {overrides or 'the rig config'}"
          f"{' against clean picks with the same settings' if args.same else ''}")
    for name, truth in changes:
        r = scatter(session, {"effect": "noise", "sensor": None, **truth}, args.draws, overrides, args.same)
        fmt = lambda v: " ".join(f"{x:6.1f}" for x in v)   # noqa: E731
        print(f"{name:>11}: ToA shift {fmt(r['shift_us'])} us, spread {fmt(r['shift_sd_us'])} us; DToA spread "
              f"{fmt(r['dtoa_sd_us'])} (mean {np.mean(r['dtoa_sd_us']):.1f}) us, > {FAR_US:.0f} us {r['far']:.3f}; "
              f"threshold {r['threshold_counts']:.1f} counts", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
