"""Benchmark: the full calibration of the bundled session-1 on this machine; prints each stage's wall time.

    python benchmarks/bench_calibrate.py [--budget 64] [--out DIR] [--workers 2]

Target (issue 4): full calibration <= 10 minutes on 2 cores. Runs from scratch (a fresh output folder, so
no stage is read from a cache) unless --out names a folder with an earlier run.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from importlib import resources

from impactsense.calibration.pipeline import CalibrateOptions, calibrate
from impactsense.commands.calibrate import summary

TARGET_S = 600.0
FINDINGS_DELAYS_US = [0.0, -0.6, -5.7, -6.5]   # docs/findings.md (session-1, AIC)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=int, default=64)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=None, help="output folder (default: a fresh temporary one)")
    args = ap.parse_args()
    out_dir = args.out or tempfile.mkdtemp(prefix="bench-calibrate-")
    data = str(resources.files("impactsense") / "data" / "session-1")
    opts = CalibrateOptions(budget=args.budget, workers=args.workers, channel_delay_us=FINDINGS_DELAYS_US)
    t0 = time.perf_counter()
    cal = calibrate(data, f"{out_dir}/CAL.json", opts)
    total = time.perf_counter() - t0
    print()
    print(summary(cal))
    print()
    print(f"{'stage':20s} {'wall s':>9s}")
    for stage, sec in cal["wall_time_s"].items():
        print(f"{stage:20s} {sec:9.1f}")
    verdict = "meets" if total <= TARGET_S else "MISSES"
    print(f"total {total:.1f} s on {args.workers} workers: {verdict} the {TARGET_S:.0f} s target; output in {out_dir}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
