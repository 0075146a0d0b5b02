"""How `impactsense monitor --db` stops after a signal while the emulator streams, and what its event log holds:
started as from a terminal and as a shell's background job (`monitor ... &` in a script or a CI runner, which
starts with SIGINT ignored), stopped by SIGINT (Ctrl-C, `kill -INT`), SIGTERM (`kill`) or SIGHUP (the terminal
closed).

    python benchmarks/bench_monitor_stop.py [--wait-s 30] [--reports 3]

One row per (start, signal): seconds from the signal to the exit ("did not stop" after --wait-s, then killed),
exit code, reports stored, and whether the log's connection row was closed with its counters (what a kill loses).
The emulator serves 3 drops with no models as fast as the monitor reads; the signal goes once --reports reports
were printed."""

from __future__ import annotations

import argparse
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

STARTS = {"terminal": (), "background job": ("sh", "-c", 'trap "" INT; exec "$@"', "sh")}


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "impactsense.cli", *map(str, args)]


def one(tmp: Path, start: str, how: signal.Signals, wait_s: float, reports: int) -> dict:
    name = f"{start.replace(' ', '-')}-{how.name}"
    db, link = tmp / f"{name}.sqlite", tmp / f"board-{name}"
    emu = subprocess.Popen(_cli("emulate", "--pty", "--speed", 0, "--limit", 3, "--models", "none", "--link", link),
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    mon = None
    try:
        emu.stdout.readline()
        mon = subprocess.Popen([*STARTS[start], *_cli("monitor", "--port", link, "--json-lines", "--db", db)],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        for _ in range(reports):
            mon.stdout.readline()
        t0 = time.monotonic()
        mon.send_signal(how)
        try:
            rc, took = mon.wait(wait_s), f"{time.monotonic() - t0:.1f}"
        except subprocess.TimeoutExpired:
            rc, took = "-", f"did not stop in {wait_s:g} s"
    finally:
        for p in (mon, emu):
            if p is not None:
                p.kill()
                p.wait()
    with sqlite3.connect(db) as c:
        stored = c.execute("SELECT COUNT(*) FROM reports").fetchone()[0]
        closed = c.execute("SELECT COUNT(*) FROM connections WHERE closed IS NOT NULL AND counters IS NOT NULL"
                           ).fetchone()[0]
    return {"start": start, "signal": how.name, "s_to_exit": took, "rc": rc, "stored": stored,
            "connection_closed": bool(closed)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--wait-s", type=float, default=30.0)
    ap.add_argument("--reports", type=int, default=3)
    a = ap.parse_args()
    print("| start | signal | s to exit | exit code | reports stored | connection closed in the log |")
    print("| --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as d:
        for start in STARTS:
            for how in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                r = one(Path(d), start, how, a.wait_s, a.reports)
                print(f"| {r['start']} | {r['signal']} | {r['s_to_exit']} | {r['rc']} | {r['stored']} | "
                      f"{'yes' if r['connection_closed'] else 'no'} |", flush=True)


if __name__ == "__main__":
    main()
