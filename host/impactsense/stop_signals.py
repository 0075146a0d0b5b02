"""How a long-running command (record, monitor, emulate: anything reading a port or a stream until told to stop)
is stopped by a signal: `stopped_by_signals()`, one context manager they all use.

Inside it Ctrl-C (SIGINT) raises KeyboardInterrupt and SIGTERM / SIGHUP raise `Stopped` (a KeyboardInterrupt
that names its signal), whatever dispositions the process inherited: a shell without job control starts a
background job (`cmd &`, a script, a CI runner) with SIGINT ignored, and Python then never raises
KeyboardInterrupt, so such a command could only be killed, losing its closing work (record's save, monitor's
event-log close, emulate's pty cleanup). A command takes KeyboardInterrupt as "stopped" and, where the exit code
must say why, `Stopped.signum` (128 + signum, what a shell reports for a process killed by that signal).
SIGHUP inherited as ignored (`nohup cmd &`) stays ignored: the user asked for the command to outlive the
terminal. The previous handlers come back on leaving; outside the main thread (where handlers cannot be set) it
does nothing."""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager


class Stopped(KeyboardInterrupt):
    """Raised by SIGTERM or SIGHUP inside stopped_by_signals(): signum and name say which."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum, self.name = int(signum), signal.Signals(signum).name


def _raise_stopped(signum, _frame):
    raise Stopped(signum)


def _hooked() -> dict:
    """The signals to take and their handlers: SIGINT always, SIGTERM always, SIGHUP unless inherited ignored."""
    hooks = {signal.SIGINT: signal.default_int_handler, signal.SIGTERM: _raise_stopped}
    if hasattr(signal, "SIGHUP") and signal.getsignal(signal.SIGHUP) is not signal.SIG_IGN:
        hooks[signal.SIGHUP] = _raise_stopped
    return hooks


@contextmanager
def stopped_by_signals():
    """Inside: SIGINT raises KeyboardInterrupt, SIGTERM and SIGHUP raise Stopped (module docstring)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {}
    try:
        for s, handler in _hooked().items():
            old[s] = signal.signal(s, handler)
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
