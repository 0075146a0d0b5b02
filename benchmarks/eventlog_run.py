"""emulate -> monitor --db with the emulator killed (SIGKILL) and restarted: the run that
benchmarks/bench_eventlog.py measures and tests/test_eventlog.py checks on a small scale.

The monitor runs throughout with --reconnect on a stable symlink (`emulate --link`); each emulator is killed
once the log has grown by a share of the total, and a last one runs to the end (`--passes`). A restarted
emulator replays the same drops from the start with the same report counter and board clock, as a board
re-sending its reports would: the log must keep each report once."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "impactsense.cli", *map(str, args)]


def _count(db: Path) -> int:
    if not db.is_file():
        return 0
    try:
        with sqlite3.connect(db, timeout=5) as c:
            return c.execute("SELECT COUNT(*) FROM reports").fetchone()[0]
    except sqlite3.OperationalError:  # tables not made yet
        return 0


def _wait(pred, timeout_s: float, what: str) -> None:
    t_end = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > t_end:
            raise TimeoutError(what)
        time.sleep(0.05)


def run(workdir, drops: int | None, passes: int, restarts: int, models: str | None = None,
        speed: float = 0.0, timeout_s: float = 600.0) -> dict:
    """Runs it in workdir (events.sqlite, board link, logs); returns the emulator's report count, the log's
    boot summary, the monitor's totals line and the wall time."""
    from impactsense.link.eventlog import boot_summary, connect

    work = Path(workdir)
    db, link = work / "events.sqlite", work / "board"
    emu_args = ["emulate", "--pty", "--speed", speed, "--passes", passes, "--link", link]
    emu_args += ["--limit", drops] if drops else []
    emu_args += ["--models", models] if models else []
    t0 = time.monotonic()
    mon_err = open(work / "monitor.err", "w")
    mon = subprocess.Popen(_cli("monitor", "--port", link, "--reconnect", "--db", db, "--board-id", "bench"),
                           stdout=subprocess.DEVNULL, stderr=mon_err)
    killed_at = []
    try:
        expected_total = None
        for k in range(restarts + 1):
            err = open(work / f"emulate-{k}.err", "w")
            emu = subprocess.Popen(_cli(*emu_args), stdout=subprocess.DEVNULL, stderr=err)
            if k < restarts:
                goal = _count(db) + max(1, expected_share(drops, passes, restarts))
                try:
                    _wait(lambda: _count(db) >= goal or emu.poll() is not None, timeout_s, "log did not grow")
                finally:
                    emu.send_signal(signal.SIGKILL)
                    emu.wait()
                    # the dead pty's name may be reused by another process: never leave the link pointing at it
                    if link.is_symlink():
                        link.unlink()
                killed_at.append(_count(db))
            else:
                emu.wait(timeout_s)
            err.close()
        expected_total = _closing_count(work / f"emulate-{restarts}.err", emu.returncode)
        _wait(lambda: _count(db) >= expected_total, 60, "the monitor did not store every report")
        time.sleep(0.5)
    finally:
        mon.send_signal(signal.SIGINT)
        try:
            mon.wait(30)
        except subprocess.TimeoutExpired:
            mon.kill()
        mon_err.close()
    wall = time.monotonic() - t0
    c = connect(db)
    summary = boot_summary(c)
    seqs = [r[0] for r in c.execute("SELECT seq FROM reports ORDER BY seq")]
    conns = [json.loads(r[0]) for r in c.execute("SELECT counters FROM connections WHERE counters IS NOT NULL")]
    c.close()
    return {"emulator_reports": expected_total, "stored": len(seqs), "distinct_seqs": len(set(seqs)),
            "seqs": seqs, "boots": summary, "killed_at_stored": killed_at, "connections": len(conns),
            "crc_errors": sum(x.get("crc_errors", 0) for x in conns),
            "bytes_skipped": sum(x.get("bytes_skipped", 0) for x in conns), "wall_s": wall,
            "monitor_stderr": (work / "monitor.err").read_text()[-2000:], "pid": os.getpid()}


def _closing_count(err_path: Path, returncode: int) -> int:
    """N from the emulator's closing line "emulate: N reports"; a clear error with its exit code and stderr
    when the line is missing (the emulator did not end normally)."""
    text = err_path.read_text()
    lines = text.strip().splitlines()
    words = lines[-1].split() if lines else []
    if returncode != 0 or len(words) != 3 or words[0] != "emulate:" or words[2] != "reports" \
            or not words[1].isdigit():
        raise RuntimeError(f"the last emulator (exit code {returncode}) did not end with 'emulate: N reports'; "
                           f"its stderr ({err_path}):\n{text[-4000:]}")
    return int(words[1])


def expected_share(drops: int | None, passes: int, restarts: int) -> int:
    """Reports to wait for before each kill: spread the kills over the run."""
    n = (drops or 771) * passes
    return n // (restarts + 2)
