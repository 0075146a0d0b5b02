"""Runs the benchmarks one after another and prints one table: each script's exit status against the target it
states (exit 0: met; non-zero: missed or failed), its wall and CPU time and its last line.

    python3 benchmarks/run_all.py [--only NAME,NAME] [--list]
    python3 -m pytest -m bench            (the same list, one test per benchmark: tests/test_benchmarks.py)

CHECKED benchmarks exit non-zero on a miss of the target they print. PRINT_ONLY ones are studies that print
figures without a target (run with --print-only). Sizes are the ones the scripts
document for a figure, reduced where a script has a size option, to keep the whole run under an hour on two
cores (the machine's other work adds to it).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from benchlib import children_cpu_s  # noqa: E402

# name -> arguments; every one exits non-zero when its stated target is missed
CHECKED = {
    "bench_splits": ["--splits", "10"],               # headline figures, mean / worst over 10 case splits
    "bench_energy_class": ["--splits", "10"],         # twin class, mean over splits >= 0.95
    "bench_retrain": [],                              # session-2: retrain beats the session-1 model
    "bench_diagnose": [],                             # the README's diagnosis of session-1 and session-2
    "bench_uncertainty": ["--splits", "10"],          # u reads as a 1-sigma on held-out cases
    "bench_zeroshot_class": ["--no-measured", "--no-session2"],   # zero-shot MAE / class on 4 seeds (issue 4)
    "bench_board_accuracy": [],                       # board / host MAE <= 1.5x
    "bench_model_size": ["--quick"],                  # smallest forest within 0.2 mm of the best <= 256 KB
    "bench_link": ["--frames", "200000"],             # emulator >= 100x real time, 0 false reports
    "bench_fuzz_loaders": ["--n", "2000", "--seed", "23"],   # 0 tracebacks
    "bench_quiet_stream": ["--minutes", "2"],         # 0 reports from a quiet, faulty lab
    "bench_faults": ["--draws", "1"],                 # lab faults within their stated factors of clean
    "bench_debond_retrain": ["--draws", "2"],         # a debonded channel after retrain <= 1.5x clean, flagged
    "bench_arrival_glitch": ["--draws", "1"],         # a spike inside an arrival: MAE <= 1.3x clean, class >= 0.95
    "bench_firmware_cost": ["--drops", "6"],          # <= 64,000 instructions an event (needs qemu)
    "bench_board_rigs": ["--drops", "6"],             # each rig's export: flash <= 256 KB, <= 64,000 an event
    "bench_board_left_out": [],                       # a channel left out: the board's answers are the host's
    "bench_eventlog": ["--reports", "2000"],          # every report stored exactly once
    "bench_rigs": [],                                 # bundled rig (other rigs with --rigs-dir)
    "bench_sim": ["--quick"],                         # FEM drop <= 2 s, >= 20x sparse, 490 drops <= 60 s
    "bench_modal": [],                                # modal solver against the FEM, site map / set times
    "bench_anyrig": ["--no-chain"],                   # orthotropic FEM against analytic frequencies
    "bench_calibrate": [],                            # full calibration <= 10 min on 2 cores
    "bench_loop": [],                                 # issue 16's closed loop on FEM sessions
    "bench_reference_floor": [],                      # the residual reference's DToA near the repeated drops' floor
}
# studies that print figures without a target (nothing to miss): run with --print-only
PRINT_ONLY = {
    "bench_support": [],
    "bench_edge_energy": [],
    "bench_surrogates": [],
    "bench_class_cues": ["--seeds", "1"],             # height cues besides the energy; the class's bound
    "bench_move_energy": [],                          # a moved disc's energy against the distance law (issue 16)
    "bench_move_identifiability": [],                 # how much of a move's timing signature is a delay's (issue 16)
    "bench_class_field": ["--seeds", "1"],            # late energy, a learnt position field, the heights
    "bench_class_sitefactor": ["--seeds", "1"],       # the class from the twin's site factor (rigs with a CAL.json)
    "bench_class_residual": ["--seeds", "1", "--splits", "4"],   # the class without a site map: 8 more reads, edge offset
    "bench_sensor_lines": ["--seeds", "1"],           # position error by sensor line, dilution, edge; physics vs forests
}


def run(name: str, args: list[str], timeout_s: float = 3600) -> dict:
    t0, c0 = time.perf_counter(), children_cpu_s()
    # one BLAS / OpenMP thread, as the tests run (tests/conftest.py): on 2 shared cores a second one spins
    env = {**{k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}, **os.environ}
    try:
        p = subprocess.run([sys.executable, str(HERE / f"{name}.py"), *args], capture_output=True, text=True,
                           timeout=timeout_s, env=env)
        rc, out = p.returncode, (p.stdout + p.stderr).strip()
        # the verdict is the script's last printed line, not a library's warning on stderr after it
        lines = [ln for ln in p.stdout.splitlines() if ln.strip()] or [ln for ln in out.splitlines() if ln.strip()]
    except subprocess.TimeoutExpired:
        rc, out = -1, f"timed out after {timeout_s:.0f} s"
        lines = [out]
    return {"name": name, "rc": rc, "seconds": time.perf_counter() - t0, "cpu_seconds": children_cpu_s() - c0,
            "last": lines[-1] if lines else "", "output": out}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=None, help="comma-separated benchmark names")
    ap.add_argument("--print-only", action="store_true", help="also run the benchmarks without a target check")
    ap.add_argument("--list", action="store_true")
    ap.add_argument("--log", default=None, help="folder for each benchmark's whole output (NAME.log)")
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
        if args.log:
            Path(args.log).mkdir(parents=True, exist_ok=True)
            (Path(args.log) / f"{name}.log").write_text(r["output"] + f"\nexit {r['rc']} in {r['seconds']:.0f} s\n")
        print(f"... {name}: exit {r['rc']} in {r['seconds']:.0f} s ({r['cpu_seconds']:.0f} s CPU)", file=sys.stderr,
              flush=True)
    print(f"{'benchmark':22s} {'target':>10s} {'s':>6s} {'CPU s':>6s}  last line")
    for r in rows:
        verdict = ("met" if r["rc"] == 0 else "MISSED" if r["rc"] > 0 else "FAILED") if r["name"] in CHECKED \
            else "no check"
        print(f"{r['name']:22s} {verdict:>10s} {r['seconds']:6.0f} {r['cpu_seconds']:6.0f}  {r['last'][:110]}")
    print(f"total {sum(r['seconds'] for r in rows) / 60:.1f} min wall, {sum(r['cpu_seconds'] for r in rows) / 60:.1f} "
          f"min CPU; load average {os.getloadavg()[0]:.1f} at the end")
    return 0 if all(r["rc"] == 0 for r in rows if r["name"] in CHECKED) else 1


if __name__ == "__main__":
    sys.exit(main())
