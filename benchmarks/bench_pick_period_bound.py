"""Which of the core's pick periods another core reads differently: every drop of each session, the rig's signal
configuration at the onset thresholds the host tries (the rig's threshold x 0.4, 0.6 (the board's refit), 1, 1.5,
2, 3 (the timing picker and its mean levels), 5, 8 (train's threshold search)); the period does not depend on the
AIC blend.

    python benchmarks/bench_pick_period_bound.py DATA [DATA ...] --save A.npz      (with one core, e.g. main's venv)
    python benchmarks/bench_pick_period_bound.py DATA [DATA ...] --against A.npz   (with another)

--board: the drops as the board captures them (board/capture.board_view at 50 kHz: resampled, the SAADC scan
delays, the app's trigger and window) with the board's signal configuration, as `export` trains the board's models.

Per session and threshold factor: channels with a pick, the fraction read (a finite period), and --against: how
many reads differ from A's (NaN <-> a period, or the value by more than 1e-4 sample), how many of them are new
reads (NaN in A), lost reads, and the new reads' period against the session's median at that threshold.
Nothing is tuned (docs/findings.md "Session 29: period3").
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

FACTORS = (0.4, 0.6, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0)


def periods(path: str, board: bool = False) -> dict[str, np.ndarray]:
    from impactsense.board.capture import board_view, signal_for_board
    from impactsense.data import load_session
    from impactsense.signal import SignalConfig
    from impactsense.travel import picks

    s = load_session(path)
    cfg = SignalConfig.for_rig(s.rig)
    if board:
        s, cfg = board_view(s, 50000), signal_for_board(s.rig, None, 50000)
    out = {}
    for f in FACTORS:
        toa, period = picks(s.adc, cfg, with_period=True, onset_threshold_counts=cfg.onset_threshold_counts * f)
        period = np.where(np.isfinite(toa), period, np.nan)
        out[f"{path}|{f:g}"] = period.astype(np.float32)
        out[f"{path}|{f:g}|picked"] = np.isfinite(toa)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="+")
    ap.add_argument("--save", help="write this core's periods here")
    ap.add_argument("--against", help="periods another core wrote (--save)")
    ap.add_argument("--board", action="store_true", help="the drops as the board captures them, at 50 kHz")
    a = ap.parse_args(argv)
    ref = dict(np.load(a.against)) if a.against else None
    saved, total = {}, 0
    for path in a.data:
        got = periods(path, a.board)
        saved.update(got)
        for f in FACTORS:
            p, picked = got[f"{path}|{f:g}"].astype(float), got[f"{path}|{f:g}|picked"]
            line = f"{path:40s} x{f:<4g} picks {int(picked.sum()):6d} read {np.isfinite(p[picked]).mean():.3f}"
            if ref is not None:
                q = ref[f"{path}|{f:g}"].astype(float)
                both = np.isfinite(p) & np.isfinite(q)
                differ = (np.isfinite(p) != np.isfinite(q)) | (both & (np.abs(p - np.where(both, q, 0)) > 1e-4))
                new = np.isfinite(p) & ~np.isfinite(q)
                med = np.median(q[np.isfinite(q)]) if np.isfinite(q).any() else np.nan
                ratio = np.round(np.quantile(p[new] / med, [0, 0.5, 1]), 2) if new.any() else "-"
                line += (f" | differ {int(differ.sum()):4d}: new {int(new.sum()):4d} (period / median {ratio}),"
                         f" lost {int((~np.isfinite(p) & np.isfinite(q)).sum())}")
                total += int(differ.sum())
            print(line, flush=True)
    if a.save:
        np.savez_compressed(a.save, **saved)
    if ref is not None:
        print(f"reads that differ, all sessions and thresholds: {total}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
