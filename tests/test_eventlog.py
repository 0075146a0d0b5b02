"""The event log (`monitor --db`, `events`): every report once across replays, reconnects and restarts; boots,
missing reports and gaps counted from what is stored; several boards in one file."""

import subprocess
import sys
import time
from pathlib import Path

from impactsense.cli import main
from impactsense.link.eventlog import EventLog, boot_summary, connect, read_reports

ROOT = Path(__file__).resolve().parents[1]


def report(seq, ms=None, **kw):
    return dict(seq=seq, timestamp_ms=1000 + 25 * seq if ms is None else ms, x_mm=100.0 + seq, y_mm=50.0,
                uncertainty_mm=2.0, energy_class=seq % 2, accepted=True, valid=True, order=[0, 1, 2, 3], **kw)


def summary(path, board="b1"):
    return [s for s in boot_summary(connect(path)) if s["board_id"] == board]


def test_gaps_counted_and_filled_by_a_replay(tmp_path):
    db = tmp_path / "ev.sqlite"
    log = EventLog(db, "b1")
    for s in (0, 1, 2, 5, 6, 9):
        assert log.add_report(report(s))
    (b,) = summary(db)
    assert (b["reports"], b["missing"], b["gaps"], b["boot"]) == (6, 4, 2, 1)
    # the same reports again (a replay): stored once; the lost ones fill their gaps in the same boot
    for s in range(10):
        log.add_report(report(s))
    (b,) = summary(db)
    assert (b["reports"], b["missing"], b["gaps"], b["duplicates_ignored"]) == (10, 0, 0, 6)
    assert log.stored == 10 and log.duplicates == 6


def test_reboot_opens_a_new_boot_and_restart_appends(tmp_path):
    db = tmp_path / "ev.sqlite"
    log = EventLog(db, "b1")
    for s in range(5):
        log.add_report(report(s))
    log.close()
    # another monitor process later (a restart of the host): the same board rebooted, its counter and clock
    # start again; a report with an earlier seq and another board time is a new report, not a duplicate
    log = EventLog(db, "b1")
    for s in range(3):
        assert log.add_report(report(s, ms=40 + 10 * s))
    log.add_report(report(2, ms=60))  # a duplicate of the new boot's seq 2
    boots = summary(db)
    assert [(b["boot"], b["reports"], b["duplicates_ignored"]) for b in boots] == [(1, 5, 0), (2, 3, 1)]
    # the clock going back with a later seq is also a reboot
    log.add_report(report(7, ms=5))
    assert [b["boot"] for b in summary(db)] == [1, 2, 3]


def test_several_boards_and_generic_flags(tmp_path):
    db = tmp_path / "ev.sqlite"
    a, b = EventLog(db, "left"), EventLog(db, "right")
    for s in range(4):
        a.add_report(report(s, channel_health=[0, 0, 1, 0]), link={"crc_errors": s})
        b.add_report(report(s))
    rows = read_reports(connect(db))
    assert len(rows) == 8 and {r["board_id"] for r in rows} == {"left", "right"}
    left = [r for r in rows if r["board_id"] == "left"]
    assert left[-1]["flags"]["channel_health"] == [0, 0, 1, 0] and left[-1]["link"] == {"crc_errors": 3}
    assert left[0]["flags"]["order"] == [0, 1, 2, 3]
    assert [s["reports"] for s in boot_summary(connect(db))] == [4, 4]


def test_events_cli_lists_filters_and_draws(tmp_path, capsys):
    db = tmp_path / "ev.sqlite"
    t = [1000.0]
    log = EventLog(db, "b1", clock=lambda: t[0])
    for s in range(30):
        t[0] += 60.0
        log.add_report(report(s))
    log.close()
    out = tmp_path / "page" / "events.html"
    assert main(["events", str(db), "--since", "1970-01-01T00:20:00+00:00", "--html", str(out)]) == 0
    listed = capsys.readouterr()
    rows = [ln for ln in listed.out.splitlines()[1:] if ln.strip()]
    assert len(rows) == sum(1000 + 60 * (k + 1) >= 1200 for k in range(30))  # received 1060..2800 s; since 1200
    text = out.read_text()
    assert text.count("<svg") == 4 and "src=" not in text  # four inline figures, nothing to fetch
    assert main(["events", str(tmp_path / "missing.sqlite")]) == 2
    (tmp_path / "bad.sqlite").write_text("not a database")
    assert main(["events", str(tmp_path / "bad.sqlite")]) == 2
    assert main(["events", str(db), "--since", "yesterday-ish"]) == 2


def test_emulator_killed_and_restarted_every_report_once(tmp_path):
    """emulate -> monitor --db, the emulator SIGKILLed twice and restarted (it replays the same drops): every
    report in the log exactly once (benchmarks/bench_eventlog.py runs it with 10,000 reports)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import eventlog_run

    r = eventlog_run.run(tmp_path, drops=25, passes=2, restarts=2, speed=1.0, timeout_s=180)
    n = r["emulator_reports"]
    assert n >= 45  # 25 drops x 2 passes, one report each (a drop may give none)
    assert r["seqs"] == list(range(n)), r["monitor_stderr"]  # each once, none missing
    (boot,) = r["boots"]
    assert boot["missing"] == 0 and boot["gaps"] == 0
    assert boot["duplicates_ignored"] > 0  # the restarts replayed reports already stored
    assert r["connections"] >= 3


def test_emulate_serves_clients_in_turn_with_the_shipped_model(tmp_path):
    """Outside the repository (another cwd), without --models: the shipped board model reports valid positions;
    a second client continues the first's report counter."""
    from impactsense.link import monitor as mon
    from impactsense.link.transport import open_serial

    proc = subprocess.Popen([sys.executable, "-m", "impactsense.cli", "emulate", "--pty", "--speed", "1",
                             "--limit", "20", "--passes", "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=tmp_path)
    path = proc.stdout.readline().strip()
    assert path.startswith("/dev/pts/"), proc.stderr.read()
    seen = []
    for stop in (3, None):
        port = open_serial(path, timeout=0.5)
        m = mon.Monitor(port)
        for f in m.frames(idle_timeout_s=5 if stop is None else 30):
            if f["kind"] == "report":
                seen.append((f["report"]["seq"], f["report"]["valid"]))
                if stop is not None and len(seen) == stop:
                    break
        port.close()
    assert proc.wait(60) == 0
    seqs = [s for s, _ in seen]
    assert seqs[:3] == [0, 1, 2] and seqs[3] >= 3 and seqs == sorted(seqs)  # counted on, not restarted
    assert len(seqs) >= 15 and all(v for _, v in seen[:3])


# A shell without job control starts a background job (`cmd &`, a script, a CI runner) with SIGINT ignored.
AS_A_BACKGROUND_JOB = ("sh", "-c", 'trap "" INT; exec "$@"', "sh")


def test_emulate_stopped_by_a_signal_closes_like_ctrl_c(tmp_path):
    """SIGTERM (a service stop, a stray kill) or SIGINT to a background-started emulator waiting for a client: the
    --link symlink is removed and the closing line printed; the exit code says a SIGTERM (128 + 15), so a harness
    never reads a log without its closing line as a normal end; SIGINT is Ctrl-C's clean end (0)."""
    import signal

    for how, code in ((signal.SIGTERM, 128 + signal.SIGTERM), (signal.SIGINT, 0)):
        link = tmp_path / f"board-{how.name}"
        proc = subprocess.Popen([*AS_A_BACKGROUND_JOB, sys.executable, "-m", "impactsense.cli", "emulate", "--pty",
                                 "--limit", "3", "--models", "none", "--link", str(link)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        try:
            path = proc.stdout.readline().strip()
            assert path.startswith("/dev/pts/") and link.is_symlink(), proc.stderr.read()
            proc.send_signal(how)
            assert proc.wait(30) == code, proc.stderr.read()
        finally:
            proc.kill()
        err = proc.stderr.read()
        assert ("emulate: stopped by SIGTERM" in err) == (how == signal.SIGTERM), err
        assert err.strip().splitlines()[-1] == "emulate: 0 reports", err
        assert not link.is_symlink()


def test_emulate_stops_on_sigterm_while_its_client_reads_nothing(tmp_path):
    """A client that opened the pty and stopped reading (its buffers full, the emulator's write waits on it):
    SIGTERM still ends the emulator within seconds, the link removed."""
    import signal

    from impactsense.link.transport import open_serial

    link = tmp_path / "board"
    proc = subprocess.Popen([sys.executable, "-m", "impactsense.cli", "emulate", "--pty", "--speed", "0", "--limit",
                             "3", "--models", "none", "--link", str(link)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    port = None
    try:
        assert proc.stdout.readline().startswith("/dev/pts/")
        port = open_serial(str(link), timeout=0.5)
        assert port.read(64)               # served; from now on nothing is read: the pty's buffers fill
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 128 + signal.SIGTERM, proc.stderr.read()
    finally:
        proc.kill()
        if port is not None:
            port.close()
    assert not link.is_symlink() and "emulate: stopped by SIGTERM" in proc.stderr.read()


def test_background_monitor_stops_on_sigint_or_sigterm_with_its_log_intact(tmp_path):
    """`monitor --db ... &` (SIGINT ignored from the shell) stopped by `kill -INT` or `kill` (SIGTERM) while the
    emulator streams: it exits within seconds (0 on SIGINT, 128 + 15 on SIGTERM, as a shell reports a process that
    SIGTERM ended), says why, and its log holds each report it printed, once, with the connection closed and its
    counters written (the close a kill would lose). The signal only marks the stop (stop_signals): it can never
    land inside the log's transaction."""
    import json
    import signal

    for how, code in ((signal.SIGINT, 0), (signal.SIGTERM, 128 + signal.SIGTERM)):
        db, link = tmp_path / f"{how.name}.sqlite", tmp_path / f"board-{how.name}"
        emu = subprocess.Popen([sys.executable, "-m", "impactsense.cli", "emulate", "--pty", "--speed", "0",
                                "--limit", "3", "--models", "none", "--link", str(link)],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        mon = None
        try:
            assert emu.stdout.readline().startswith("/dev/pts/")
            mon = subprocess.Popen([*AS_A_BACKGROUND_JOB, sys.executable, "-m", "impactsense.cli", "monitor",
                                    "--port", str(link), "--json-lines", "--db", str(db)], stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE, text=True)
            printed = [mon.stdout.readline() for _ in range(3)]   # three reports seen: the log is being written
            assert all(line.startswith("{") for line in printed), printed
            mon.send_signal(how)
            rc = mon.wait(30)   # (its pipes hold far more than it can print meanwhile)
            out, err = mon.stdout.read(), mon.stderr.read()
            assert rc == code, (how.name, rc, err)
        finally:
            for p in (mon, emu):
                if p is not None:
                    p.kill()
                    p.wait()
        said = "Ctrl-C" if how == signal.SIGINT else how.name
        assert f"monitor: stopped ({said})" in err and "Traceback" not in err, err
        seqs = [json.loads(line)["seq"] for line in printed + out.splitlines() if line.startswith("{")]
        c = connect(db)
        stored = [r[0] for r in c.execute("SELECT seq FROM reports ORDER BY id")]
        conns = c.execute("SELECT closed, counters FROM connections").fetchall()
        c.close()
        # every printed report is stored, once (a report is logged before it is printed: none stored unprinted)
        assert len(stored) == len(set(stored)) and set(seqs) == set(stored)
        assert len(conns) == 1 and conns[0][0] is not None and json.loads(conns[0][1])["reports"] == len(seqs)
