"""One way to stop a long-running command by a signal (stop_signals): the handler only notes the signal, the loops
(record, monitor, emulate) read it between reads and stop as at the end of the stream, never with an exception in
the middle of a write. The commands' own stop tests (a background-started process, SIGINT ignored from the shell):
tests/test_safety.py (record) and tests/test_eventlog.py (monitor, emulate)."""

import io
import os
import signal
import threading
import time

import pytest

from impactsense.link import monitor, protocol
from impactsense.link.eventlog import EventLog, connect
from impactsense.stop_signals import sleep, stopped_by_signals

STOPS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@pytest.fixture
def handlers():
    """The test's stop signals' handlers, put back afterwards whatever the test did."""
    before = {s: signal.getsignal(s) for s in STOPS}
    yield
    for s, h in before.items():
        signal.signal(s, h)


def wait_for(cond, timeout_s=5.0):
    end = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < end:
        time.sleep(0.001)
    return cond()


def test_a_stop_signal_only_notes_itself_whatever_was_inherited_and_nohup_stays(handlers):
    """SIGINT inherited ignored (a background job) is taken; SIGHUP inherited ignored (nohup) stays ignored; the
    first signal is the one kept; no exception; the inherited handlers come back."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    term = signal.getsignal(signal.SIGTERM)
    with stopped_by_signals() as stop:
        assert not stop() and signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
        os.kill(os.getpid(), signal.SIGINT)
        assert wait_for(stop) and stop.name == "SIGINT"
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)
        assert stop.signum == signal.SIGINT
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN and signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    assert signal.getsignal(signal.SIGTERM) is term
    with stopped_by_signals() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        assert wait_for(stop) and stop.name == "SIGTERM"


def test_a_signal_inside_each_event_log_transaction_raises_nothing_and_loses_nothing(tmp_path, handlers):
    """The failure of a handler that raises (last session: "cannot rollback - no transaction is active", exit 1):
    a SIGTERM sent from inside every write of the log (its clock, read within each report's transaction)."""
    def clock_that_signals():
        os.kill(os.getpid(), signal.SIGTERM)   # Python runs the handler at the next bytecode: still inside
        return time.time()

    log = EventLog(tmp_path / "ev.sqlite", "b1", clock=clock_that_signals)
    with stopped_by_signals() as stop:
        try:
            log.connection_opened()
            for seq in range(50):
                log.add_report(dict(seq=seq, timestamp_ms=25 * seq, x_mm=1.0, y_mm=2.0, uncertainty_mm=1.0,
                                    energy_class=0, accepted=True, valid=True, order=[0, 1, 2, 3]))
            log.connection_closed({"reports": 50})
        except KeyboardInterrupt as exc:
            pytest.fail(f"a stop signal raised inside the event log's write: {exc!r}")
    log.close()
    c = connect(tmp_path / "ev.sqlite")
    assert c.execute("SELECT COUNT(DISTINCT seq), COUNT(*) FROM reports").fetchone() == (50, 50)
    assert c.execute("SELECT COUNT(*) FROM connections WHERE closed IS NOT NULL").fetchone()[0] == 1
    assert stop.name == "SIGTERM"


def test_interruptible_raises_only_inside_for_a_wait_no_flag_wakes(handlers):
    with stopped_by_signals() as stop:
        with pytest.raises(KeyboardInterrupt), stop.interruptible():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)                       # input() at record's --ask prompt: woken by the raise
        assert stop()
        with pytest.raises(KeyboardInterrupt), stop.interruptible():   # a stop already noted: raised on entry
            pass
        os.kill(os.getpid(), signal.SIGINT)     # outside: noted only
        time.sleep(0.05)


def test_sleep_wakes_on_a_stop():
    with stopped_by_signals() as stop:
        threading.Timer(0.2, stop.handle, (signal.SIGTERM,)).start()
        t0 = time.monotonic()
        assert sleep(10, stop) and time.monotonic() - t0 < 2
    assert not sleep(0.01, stop=None)


class QuietPort:
    """A port that sends one report, then nothing (a board with no drops); it never closes."""

    timeout, is_open = 0.2, True

    def __init__(self):
        self.data = protocol.encode_report(dict(seq=0, timestamp_ms=25, x_mm=10.0, y_mm=20.0, uncertainty_mm=1.0,
                                                energy_class=0, accepted=True, valid=True, order=[0, 1, 2, 3], clipped=0,
                                                dead=0))

    def read(self, n):
        out, self.data = self.data[:n], self.data[n:]
        if not out:
            time.sleep(self.timeout)
        return out

    def close(self):
        self.is_open = False


def test_monitor_ends_its_connection_on_a_stop_logs_its_close_and_does_not_reconnect(tmp_path, handlers):
    log = EventLog(tmp_path / "ev.sqlite", "b1")
    err = io.StringIO()
    with stopped_by_signals() as stop:
        threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGTERM)).start()
        t0 = time.monotonic()
        totals = monitor.run(QuietPort, reconnect=True, out=io.StringIO(), err=err, log=log, stop=stop)
        took = time.monotonic() - t0
    log.close()
    assert took < 5 and "monitor: stopped (SIGTERM)" in err.getvalue() and "reconnecting" not in err.getvalue()
    assert totals["reports"] == 1 and "open_failed" not in totals
    (closed,) = connect(tmp_path / "ev.sqlite").execute("SELECT closed FROM connections").fetchall()
    assert closed[0] is not None


def test_monitor_retrying_a_port_that_will_not_open_stops_within_a_retry(handlers):
    def never():
        raise OSError("no such port")

    err = io.StringIO()
    with stopped_by_signals() as stop:
        threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT)).start()
        t0 = time.monotonic()
        totals = monitor.run(never, reconnect=True, retry_s=5.0, out=io.StringIO(), err=err, stop=stop)
        took = time.monotonic() - t0
    assert took < 3 and "open_failed" not in totals and "cannot open" not in err.getvalue()
