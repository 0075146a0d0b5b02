"""Event log under restarts: N reports through `impactsense emulate` -> `impactsense monitor --reconnect --db`,
the emulator killed (SIGKILL) and restarted K times; each restarted emulator replays the drops from the start
(same counter, same board clock). Target (issue 19): every report in the log exactly once, none missing.

    python benchmarks/bench_eventlog.py [--reports 10000] [--restarts 3] [--speed 0] [--keep DIR]

Prints the emulator's report count, the log's rows and distinct seqs, missing reports and gaps, duplicates
ignored, the kill points, the torn frames the monitor skipped (CRC errors, bytes) and the wall time; exits 1
when a report is missing or stored twice.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eventlog_run  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reports", type=int, default=10000, help="at least this many reports (default 10000)")
    ap.add_argument("--restarts", type=int, default=3, help="emulator kills and restarts (default 3)")
    ap.add_argument("--speed", type=float, default=0.0, help="emulator speed, x real time (default 0: flat out)")
    ap.add_argument("--drops", type=int, default=None, help="drops per pass (default: all of session-1)")
    ap.add_argument("--keep", default=None, help="run in this folder and keep the log (default: a temporary one)")
    args = ap.parse_args()
    from impactsense.data import load_session

    drops = args.drops or len(load_session())
    passes = math.ceil(args.reports / (drops * 0.99))  # a drop may give no report
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.keep or tmp)
        work.mkdir(parents=True, exist_ok=True)
        r = eventlog_run.run(work, drops=args.drops, passes=passes, restarts=args.restarts, speed=args.speed,
                             timeout_s=1800)
    n, seqs = r["emulator_reports"], r.pop("seqs")
    boots = r["boots"]
    ok = (n >= args.reports and seqs == list(range(n)) and len(boots) == 1 and boots[0]["missing"] == 0)
    print(json.dumps({k: v for k, v in r.items() if k not in ("monitor_stderr", "pid")}, indent=1))
    print(f"{n} reports sent ({drops} drops x {passes} passes), emulator killed {args.restarts} times at "
          f"{r['killed_at_stored']} stored; log: {r['stored']} rows, {r['distinct_seqs']} distinct seqs, "
          f"{sum(b['missing'] for b in boots)} missing in {sum(b['gaps'] for b in boots)} gaps, "
          f"{sum(b['duplicates_ignored'] for b in boots)} replayed duplicates ignored, {len(boots)} boot(s); "
          f"torn frames skipped: {r['crc_errors']} CRC errors, {r['bytes_skipped']} bytes; {r['wall_s']:.0f} s")
    print("target (every report exactly once, none missing):", "met" if ok else "MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
