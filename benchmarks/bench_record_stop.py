"""How long `impactsense record` takes to stop and save after a signal, and what it saved: started as from a
terminal (SIGINT at its default) and as a shell's background job (`record ... &` in a script or a CI runner, which
starts with SIGINT ignored), stopped by SIGINT (Ctrl-C, `kill -INT`) or SIGTERM (`kill`).

    python benchmarks/bench_record_stop.py [--wait-s 30] [--captures 3]

One row per (start, signal): seconds from the signal to the exit ("did not stop" after --wait-s), exit code,
captures in the saved folder, its notes' stop reason, and whether the journal was left (a kill: the next
`record --out` saves it). The emulator plays the shipped models' session at 0.05 of
real time on a pty (as tests/test_safety.py does); the signal goes once --captures captures are in the journal."""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STARTS = {"terminal": (), "background job": ("sh", "-c", 'trap "" INT; exec "$@"', "sh")}
CAPTURE_BYTES = 8000     # a capture's journal record is a little over this (4 x 1024 int16 and the report)


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "impactsense.cli", *map(str, args)]


def one(tmp: Path, start: str, how: signal.Signals, wait_s: float, captures: int) -> dict:
    from impactsense.data import load_session

    emu = subprocess.Popen(_cli("emulate", "--pty", "--speed", "0.05", "--models", ROOT / "models", "--limit", 400),
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    out = tmp / f"rec-{start.replace(' ', '-')}-{how.name}"
    journal = tmp / f".{out.name}.record-journal" / "captures.bin"
    rec = None
    try:
        port = emu.stdout.readline().strip()
        rec = subprocess.Popen([*STARTS[start], *_cli("record", "--port", port, "--out", out)],
                               stderr=subprocess.DEVNULL)
        deadline = time.time() + 300
        while time.time() < deadline and (not journal.exists() or journal.stat().st_size < captures * CAPTURE_BYTES):
            time.sleep(0.1)
        t0 = time.monotonic()
        rec.send_signal(how)
        try:
            rc = rec.wait(wait_s)
            took = f"{time.monotonic() - t0:.1f}"
        except subprocess.TimeoutExpired:
            rc, took = None, f"did not stop in {wait_s:g}"
    finally:
        if rec is not None:
            rec.kill()
        emu.kill()
    saved, why = 0, "-"
    if out.is_dir():
        s = load_session(out)
        saved = len(s)
        notes = s.rig.raw["notes"]
        why = notes[notes.index("stopped (") + 9:].split(")")[0] if "stopped (" in notes else "complete"
    return {"start": start, "signal": how.name, "seconds": took, "rc": rc, "saved": saved, "why": why,
            "journal": "left" if journal.parent.exists() else "-"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--wait-s", type=float, default=30.0, help="how long to wait for the exit after the signal")
    ap.add_argument("--captures", type=int, default=3, help="captures in the journal before the signal")
    a = ap.parse_args()
    print(f"{'start':<15} {'signal':<7} {'s to exit':>20} {'rc':>4} {'saved':>5} {'journal':>7}  stop reason")
    with tempfile.TemporaryDirectory() as d:
        for start in STARTS:
            for how in (signal.SIGINT, signal.SIGTERM):
                r = one(Path(d), start, how, a.wait_s, a.captures)
                print(f"{r['start']:<15} {r['signal']:<7} {r['seconds']:>20} {r['rc']!s:>4} {r['saved']:>5} "
                      f"{r['journal']:>7}  {r['why']}", flush=True)


if __name__ == "__main__":
    main()
