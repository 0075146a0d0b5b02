"""How a long-running command (record, monitor, emulate: anything reading a port or a stream until told to stop)
is stopped by a signal: `stopped_by_signals()`, one context manager they all use.

Inside it SIGINT (Ctrl-C, `kill -INT`), SIGTERM (`kill`, a service stop) and SIGHUP (the terminal closed) only
record which signal came, in the `StopRequest` it yields; the handler does nothing else. The command's loops call
the request between reads (every read has a timeout, so a loop sees it within that timeout) and then stop as they
do at the end of the stream: record saves its captures as "interrupted", monitor closes its connection in the
event log, emulate closes the pty. A signal can therefore never land as an exception in the middle of a write (a
journal append, an event-log transaction). The one place a command may still be interrupted by an exception is a
wait on the user (`StopRequest.interruptible()`, record's `--ask` prompt).

The handlers are installed whatever dispositions the process inherited: a shell without job control starts a
background job (`cmd &`, a script, a CI runner) with SIGINT ignored, so Python's Ctrl-C would never stop it.
SIGHUP inherited as ignored (`nohup cmd &`) stays ignored: the user asked for the command to outlive the terminal.
The previous handlers come back on leaving. Outside the main thread (where handlers cannot be set) the request is
never set and the loops run as without it."""

from __future__ import annotations

import signal
import threading
import time
from contextlib import contextmanager


class StopRequest:
    """Which stop signal came (signum, name; None before one); calling it says whether one came."""

    def __init__(self):
        self.signum: int | None = None
        self._raise = False

    def __call__(self) -> bool:
        return self.signum is not None

    @property
    def name(self) -> str | None:
        return None if self.signum is None else signal.Signals(self.signum).name

    def handle(self, signum, _frame=None) -> None:
        """The signal handler: notes the first signal (inside interruptible(): also raises KeyboardInterrupt)."""
        if self.signum is None:
            self.signum = int(signum)
        if self._raise:
            self._raise = False
            raise KeyboardInterrupt

    @contextmanager
    def interruptible(self):
        """Inside, a stop signal also raises KeyboardInterrupt (and one already noted raises it on entry): for a
        wait on the user that no flag can wake (input()); never around a write."""
        self._raise = True
        try:
            if self():
                raise KeyboardInterrupt
            yield
        finally:
            self._raise = False


def sleep(seconds: float, stop=None, step_s: float = 0.05) -> bool:
    """Sleeps `seconds`, or until stop() holds (checked every step_s); returns whether it stopped early."""
    end = time.monotonic() + seconds
    while stop is None or not stop():
        left = end - time.monotonic()
        if left <= 0:
            return False
        time.sleep(min(step_s, left) if stop is not None else left)
    return True


def _signals() -> list:
    """SIGINT and SIGTERM always; SIGHUP unless inherited ignored (nohup)."""
    out = [signal.SIGINT, signal.SIGTERM]
    if hasattr(signal, "SIGHUP") and signal.getsignal(signal.SIGHUP) is not signal.SIG_IGN:
        out.append(signal.SIGHUP)
    return out


@contextmanager
def stopped_by_signals():
    """Yields a StopRequest the stop signals set while inside (module docstring)."""
    stop = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    old = {}
    try:
        for s in _signals():
            old[s] = signal.signal(s, stop.handle)
        yield stop
    finally:
        for s, handler in old.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
