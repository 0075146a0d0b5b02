"""The board export on every rig: flash and per-event instructions of what `impactsense export` makes for it.

    python3 benchmarks/bench_board_rigs.py --core ArduinoCore-mbed-DIR --ble ArduinoBLE-DIR [--rigs-dir DIR]
                                           [--skip-bundled] [--drops 20] [--work DIR] [--json OUT.json]

Per rig (the bundled rig and the session folders under --rigs-dir, found as bench_rigs.py finds them): the
user's commands `impactsense train DATA --out W/model` (default split) and `impactsense export W/model --out
W/export` (the board's refit at 4 x 50 kHz, the trees within the flash and event budgets), then
- flash: `scripts/board-build.sh --models W/export --env nano33ble --no-framework` (our code + the models,
  text+data; the core and ArduinoBLE trees as given, or IMPACTSENSE_ARDUINO_CORE / IMPACTSENSE_ARDUINO_BLE);
- instructions: `benchmarks/bench_firmware_cost.py --data DATA --export W/export --drops N` (the firmware app
  on N of that rig's drops under qemu -icount, the slowest event);
- the export's own figures: the estimated per-event cost (board.cost) and the held-out drops' MAE per axis
  and class accuracy on the emulated board.
Targets (issues 15/17): code + models <= 256 KB, <= 64,000 instructions an event; exits 1 on a miss.
W is --work/<rig> (default build/bench-board-rigs/; the board's site map of a twin model is cached there).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from bench_rigs import rig_folders
from benchlib import distinct_sessions, misses_exit_code, run_logged

ROOT = Path(__file__).resolve().parents[1]
FLASH_TARGET = 256 * 1024
INSTRUCTIONS_TARGET = 64000


def measure(data: str, work: Path, core: Path | None, ble: Path | None, drops: int) -> dict:
    work.mkdir(parents=True, exist_ok=True)
    log = work / "log.txt"
    log.write_text("")
    cli = [sys.executable, "-c", "import sys; from impactsense.cli import main; sys.exit(main())"]
    t0 = time.perf_counter()
    run_logged([*cli, "train", data, "--out", str(work / "model"), "--force"], log)
    run_logged([*cli, "export", str(work / "model"), "--out", str(work / "export"), "--force"], log)
    done = json.loads((work / "export" / "export.json").read_text())
    row = {"rig": Path(data).name, "trees": done["trees"], "table_bytes": done["table_bytes_total"],
           "estimate": (done.get("event_instructions_estimate") or {}).get("total"),
           "board_held_out": done.get("board_held_out"), "export_s": time.perf_counter() - t0}
    if core and ble:
        run_logged([str(ROOT / "scripts" / "board-build.sh"), "--core", str(core), "--ble", str(ble), "--out",
                    str(work / "board-build"), "--env", "nano33ble", "--no-framework", "--models",
                    str(work / "export"), "--json", str(work / "board-build.json")], log)
        flash = json.loads((work / "board-build.json").read_text())["nano33ble"]["flash"]
        row["flash_code_bytes"], row["flash_models_bytes"] = flash["project"], flash["models"]
        row["flash_bytes"] = flash["project"] + flash["models"]
    cost = work / "cost.json"
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_firmware_cost.py"), "--data", data,
                        "--export", str(work / "export"), "--drops", str(drops), "--json", str(cost)],
                       capture_output=True, text=True)
    with open(log, "a") as fh:
        fh.write(p.stdout + p.stderr)
    if not cost.is_file():
        raise RuntimeError(f"bench_firmware_cost.py failed ({p.returncode}); see {log}")
    ins = json.loads(cost.read_text())["instructions"]
    row["instructions_max"] = max(ins["event_max_over_drops"], ins["app_event_max"])
    row["drops_timed"] = len(json.loads(cost.read_text())["rows"])
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--core", type=Path, default=os.environ.get("IMPACTSENSE_ARDUINO_CORE"),
                    help="ArduinoCore-mbed tree (with cores/arduino/api) for board-build.sh")
    ap.add_argument("--ble", type=Path, default=os.environ.get("IMPACTSENSE_ARDUINO_BLE"), help="ArduinoBLE tree")
    ap.add_argument("--rigs-dir", default=None, help="folder of other rigs' session folders")
    ap.add_argument("--skip-bundled", action="store_true", help="only the other rigs")
    ap.add_argument("--drops", type=int, default=20, help="each rig's drops timed under qemu (evenly spaced)")
    ap.add_argument("--work", type=Path, default=ROOT / "build" / "bench-board-rigs")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    folders, why = rig_folders(args.rigs_dir)
    if why:
        print(f"other rigs skipped: {why}")
    paths = ([] if args.skip_bundled else ["bundled"]) + [str(p) for p in folders]
    misses, rows = [], []
    print(f"{'rig':12s} {'trees x/y/e':>12s} {'flash B (code + models)':>26s} {'instr. max':>10s} {'estimate':>9s} "
          f"{'board MAE':>9s} {'class':>6s}  targets: flash <= {FLASH_TARGET:,} B, <= {INSTRUCTIONS_TARGET:,} an event")
    for data in distinct_sessions(paths):
        r = measure(data, args.work / Path(data).name, args.core, args.ble, args.drops)
        rows.append(r)
        t = r["trees"]
        flash = r.get("flash_bytes")
        acc = r["board_held_out"] or {}
        if flash is None:
            misses.append(f"{r['rig']}: flash not measured (no --core/--ble)")
        elif flash > FLASH_TARGET:
            misses.append(f"{r['rig']}: flash {flash:,} B > {FLASH_TARGET:,} B")
        if r["instructions_max"] > INSTRUCTIONS_TARGET:
            misses.append(f"{r['rig']}: {r['instructions_max']:,} instructions > {INSTRUCTIONS_TARGET:,}")
        fl = f"{flash:,} ({r['flash_code_bytes']:,} + {r['flash_models_bytes']:,})" if flash else "-"
        print(f"{r['rig']:12s} {t['x']:>4}/{t['y']}/{t['energy']:<4} {fl:>26s} {r['instructions_max']:>10,} "
              f"{format(r['estimate'], ',') if r['estimate'] else '- (twin)':>9} "
              f"{acc.get('all', {}).get('mae_mm', float('nan')):9.2f} "
              f"{acc.get('energy_class_accuracy', float('nan')):6.3f}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return misses_exit_code(misses)


if __name__ == "__main__":
    sys.exit(main())
