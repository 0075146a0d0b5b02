"""How `impactsense monitor --db` stops after a signal while the emulator streams, and what its event log holds:
started as from a terminal and as a shell's background job (`monitor ... &` in a script or a CI runner, which
starts with SIGINT ignored), stopped by SIGINT (Ctrl-C, `kill -INT`), SIGTERM (`kill`) or SIGHUP (the terminal
closed).

    python benchmarks/bench_monitor_stop.py [--wait-s 30] [--reports 3] [--repeat 1]

One row per (start, signal): over --repeat runs, the slowest seconds from the signal to the exit ("did not stop"
after --wait-s, then killed), the exit codes seen, the runs whose log is not intact (a report printed but not
stored or stored twice, or the connection row not closed with its counters: what a kill, or an exception in the
log's transaction, loses) and the runs that printed a traceback. The emulator serves 3 drops with no models as
fast as the monitor reads; the signal goes once --reports reports were printed."""

from __future__ import annotations

import argparse
import json
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
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        printed = [mon.stdout.readline() for _ in range(reports)]
        t0 = time.monotonic()
        mon.send_signal(how)
        try:
            rc, took = mon.wait(wait_s), time.monotonic() - t0
        except subprocess.TimeoutExpired:
            rc, took = "-", None
    finally:
        for p in (mon, emu):
            if p is not None:
                p.kill()
                p.wait()
    out, err = mon.stdout.read(), mon.stderr.read()
    seqs = {json.loads(line)["seq"] for line in printed + out.splitlines() if line.startswith("{")}
    c = sqlite3.connect(db)
    stored = [r[0] for r in c.execute("SELECT seq FROM reports")]
    closed = c.execute("SELECT COUNT(*) FROM connections WHERE closed IS NOT NULL AND counters IS NOT NULL"
                       ).fetchone()[0]
    c.close()
    intact = bool(closed) and len(stored) == len(set(stored)) and seqs <= set(stored)
    return {"s_to_exit": took, "rc": rc, "intact": intact, "traceback": "Traceback" in err}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--wait-s", type=float, default=30.0)
    ap.add_argument("--reports", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=1)
    a = ap.parse_args()
    print("| start | signal | runs | slowest s to exit | exit codes | log not intact | traceback |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as d:
        for start in STARTS:
            for how in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                rows = []
                for k in range(a.repeat):
                    (Path(d) / str(k)).mkdir(exist_ok=True)
                    rows.append(one(Path(d) / str(k), start, how, a.wait_s, a.reports))
                took = [r["s_to_exit"] for r in rows]
                slowest = (f"did not stop in {a.wait_s:g} s ({took.count(None)} runs)" if None in took
                           else f"{max(took):.1f}")
                codes = ", ".join(sorted({str(r["rc"]) for r in rows}))
                print(f"| {start} | {how.name} | {len(rows)} | {slowest} | {codes} | "
                      f"{sum(not r['intact'] for r in rows)} | {sum(r['traceback'] for r in rows)} |", flush=True)


if __name__ == "__main__":
    main()
