"""Runs the benchmarks one after another and prints one table: each script's exit status against the target it
states (exit 0: met; non-zero: missed or failed), its wall time and its last line.

    python3 benchmarks/run_all.py [--only NAME,NAME] [--list]
    python3 -m pytest -m bench            (the same list, one test per benchmark: tests/test_benchmarks.py)

CHECKED benchmarks exit non-zero on a miss of the target they print. PRINT_ONLY ones print figures without a
target check yet (listed so that the table says so, run with --print-only). Sizes are the ones the scripts
document for a figure, reduced where a script has a size option, to keep the whole run under an hour on two
cores (the machine's other work adds to it).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

# name -> arguments; every one exits non-zero when its stated target is missed
CHECKED = {
    "bench_splits": ["--splits", "10"],               # headline figures, mean / worst over 10 case splits
    "bench_energy_class": ["--splits", "10"],         # twin class, mean over splits >= 0.95
    "bench_retrain": [],                              # session-2: retrain beats the session-1 model
    "bench_link": ["--frames", "200000"],             # emulator >= 100x real time, 0 false reports
    "bench_fuzz_loaders": ["--n", "2000", "--seed", "23"],   # 0 tracebacks
    "bench_quiet_stream": ["--minutes", "2"],         # 0 reports from a quiet, faulty lab
    "bench_faults": ["--draws", "1"],                 # lab faults within their stated factors of clean
    "bench_firmware_cost": ["--drops", "6"],          # <= 64,000 instructions an event (needs qemu)
    "bench_eventlog": ["--reports", "2000"],          # every report stored exactly once
    "bench_rigs": [],                                 # bundled rig (other rigs with --rigs-dir)
}
# figures printed without a target check (yet)
PRINT_ONLY = {
    "bench_diagnose": [],
    "bench_uncertainty": [],
    "bench_zeroshot_class": [],
    "bench_model_size": [],
}


def run(name: str, args: list[str], timeout_s: float = 3600) -> dict:
    t0 = time.perf_counter()
    try:
        p = subprocess.run([sys.executable, str(HERE / f"{name}.py"), *args], capture_output=True, text=True,
                           timeout=timeout_s)
        rc, out = p.returncode, (p.stdout + p.stderr).strip()
    except subprocess.TimeoutExpired:
        rc, out = -1, f"timed out after {timeout_s:.0f} s"
    lines = [ln for ln in out.splitlines() if ln.strip()]
    return {"name": name, "rc": rc, "seconds": time.perf_counter() - t0, "last": lines[-1] if lines else "",
            "output": out}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=None, help="comma-separated benchmark names")
    ap.add_argument("--print-only", action="store_true", help="also run the benchmarks without a target check")
    ap.add_argument("--list", action="store_true")
    args = ap.parse_args(argv)
    todo = dict(CHECKED, **(PRINT_ONLY if args.print_only else {}))
    if args.only:
        todo = {k: v for k, v in {**CHECKED, **PRINT_ONLY}.items() if k in args.only.split(",")}
    if args.list:
        for name, a in {**CHECKED, **PRINT_ONLY}.items():
            print(f"{name:22s} {'checked' if name in CHECKED else 'print only'}  {' '.join(a)}")
        return 0
    rows = []
    for name, a in todo.items():
        rows.append(run(name, a))
        r = rows[-1]
        print(f"... {name}: exit {r['rc']} in {r['seconds']:.0f} s", file=sys.stderr, flush=True)
    print(f"{'benchmark':22s} {'target':>10s} {'s':>6s}  last line")
    for r in rows:
        verdict = ("met" if r["rc"] == 0 else "MISSED" if r["rc"] > 0 else "FAILED") if r["name"] in CHECKED \
            else "no check"
        print(f"{r['name']:22s} {verdict:>10s} {r['seconds']:6.0f}  {r['last'][:110]}")
    return 0 if all(r["rc"] == 0 for r in rows if r["name"] in CHECKED) else 1


if __name__ == "__main__":
    sys.exit(main())
