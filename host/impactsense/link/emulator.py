"""A pseudo-terminal that behaves like the board.

Recorded drops (100 kHz, channels sampled together) are turned into what the SAADC would deliver: each
channel band-limited, resampled to the board rate and read `c * SCAN_STEP_US` later than channel 0 (the
scan order), rounded to counts; the frames are fed to the natively compiled firmware app
(firmware/lib/impactapp via `impactsense._link.App`, with the exported forest tables), and its serial bytes
go to the pty.
"""

from __future__ import annotations

import errno
import os
import time

import numpy as np

from .. import _link
from ..board.capture import app_config, board_frames, signal_for_board
from ..stop_signals import sleep


class Emulator:
    """The firmware app over a session's recordings, as a byte stream."""

    def __init__(self, session, models=None, fs_hz: int = 50000, signal: dict | None = None, **config):
        self.session = session
        self.fs_hz = int(fs_hz)
        self.signal = signal_for_board(session.rig, signal, fs_hz)
        self._config = app_config(session.rig, fs_hz, signal, **config)
        self.app = _link.App(self._config, models)
        self._frames = None

    @property
    def frames(self) -> np.ndarray:
        if self._frames is None:
            self._frames = board_frames(self.session.adc, self.session.rig, self.app, self.fs_hz,
                                        threshold_counts=self._config.get("threshold_counts"))
        return self._frames

    def drops(self):
        """(index, bytes) per recording: the serial output while that recording's frames were fed."""
        for i in range(self.frames.shape[0]):
            yield i, self.app.feed(self.frames[i])

    def stream(self, reading=lambda t_s: True, buffer: int = 256, drops=None):
        """The recordings back to back as the board acquires them, one DMA buffer at a time, with a host that
        reads only while reading(t) holds (t: sample-clock seconds); yields the bytes the host got per buffer.
        While the host does not read, the app's transmit queue fills and then drops whole frames (counted in
        the status frame); acquisition never waits."""
        frames = self.frames if drops is None else self.frames[drops]
        n = 0
        for rec in frames:
            for off in range(0, rec.shape[0], buffer):
                t = n / self.fs_hz
                chunk = rec[off:off + buffer]
                n += chunk.shape[0]
                yield self.app.feed(chunk, buffer, None if reading(t) else 0)

    def real_time_s(self) -> float:
        return self.frames.shape[0] * self.frames.shape[1] / self.fs_hz


def _probe_client(master: int) -> bytes | None:
    """None while no client has the pty open (reads fail with EIO); else what the client already sent."""
    try:
        return os.read(master, 4096)
    except BlockingIOError:
        return b""
    except OSError as exc:
        if exc.errno == errno.EIO:
            return None
        raise


def _open_pty(link: str | None):
    """(master fd, slave path) of a raw, non-blocking pty; with `link`, a symlink there to the slave path
    (replaced atomically, so a monitor on the link reaches a restarted emulator)."""
    import fcntl
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    os.close(slave)
    fl = fcntl.fcntl(master, fcntl.F_GETFL)
    fcntl.fcntl(master, fcntl.F_SETFL, fl | os.O_NONBLOCK)
    if link:
        tmp = f"{link}.{os.getpid()}.tmp"
        os.symlink(path, tmp)
        os.replace(tmp, link)
    return master, path


def _wait_for_client(master: int, deadline: float | None, stop=None) -> bytes | None:
    """Blocks until a client has the pty open; returns what it already sent (None: deadline passed, or stop())."""
    pending = _probe_client(master)
    while pending is None:
        if (deadline is not None and time.monotonic() > deadline) or (stop is not None and stop()):
            return None
        time.sleep(0.01)
        pending = _probe_client(master)
    time.sleep(0.05)  # let the client finish configuring the port and send its first commands
    return pending


def serve_pty(emulator: Emulator, speed: float = 1.0, announce=print, connect_timeout_s: float | None = 600.0,
              once: bool = True, passes: int = 1, link: str | None = None, log=None, stop=None) -> int:
    """Opens a pty, announces its path and plays the drops to whoever has it open. Returns the bytes written.

    once: one client, one pass through the drops, then close (the first client's timeout: connect_timeout_s).
    Otherwise clients are served one after another, as a board on a USB port is: the app (its report
    counter and clock) runs on across clients; while no client is connected the drops wait; after `passes`
    passes through the drops (0: forever, until interrupted) the emulator waits until the last client has
    read everything and returns. log(str): one line per client connect/disconnect. stop
    (stop_signals.StopRequest): once stop() holds, it returns between drops (and from any wait) as at the end."""
    log = log or (lambda _msg: None)
    frames = emulator.frames  # resample before announcing, so the client never waits on it
    written, n_drops = 0, frames.shape[0]
    per_drop_s = frames.shape[1] / emulator.fs_hz
    total = n_drops * passes if passes > 0 else None
    k = 0  # drops played so far, over all passes
    master, path = _open_pty(link)
    try:  # from the link's creation on: a signal raised at any point below still closes the pty and removes it
        announce(path)
        while (total is None or k < total) and not (stop is not None and stop()):
            pending = _wait_for_client(master, time.monotonic() + connect_timeout_s
                                       if connect_timeout_s is not None and k == 0 else None, stop)
            if pending is None:
                break
            log(f"client connected (drop {k % n_drops} of pass {k // n_drops + 1})")
            t0, k0 = time.monotonic(), k
            try:
                while (total is None or k < total) and not (stop is not None and stop()):
                    more = _probe_client(master)
                    if more is None:
                        raise OSError(errno.EIO, "client went away")
                    cmd = pending + more
                    pending = b""
                    out = emulator.app.rx(cmd) if cmd else b""
                    out += emulator.app.feed(frames[k % n_drops])
                    k += 1
                    _write_all(master, out, stop)
                    written += len(out)
                    if speed and speed > 0:
                        lag = t0 + (k - k0) * per_drop_s / speed - time.monotonic()
                        if lag > 0:
                            sleep(lag, stop)
                _drain(master, path, stop=stop)
            except OSError as exc:
                if exc.errno != errno.EIO:  # EIO: the client went away
                    raise
                log(f"client disconnected after drop {k}")
            if once:
                break
    finally:
        os.close(master)
        if link and os.path.islink(link) and os.readlink(link) == path:
            os.unlink(link)
    return written


def _write_all(fd: int, data: bytes, stop=None) -> None:
    """Writes data to the pty while a client is there (until stop() holds: the rest is not written)."""
    import select

    view = memoryview(data)
    while view and not (stop is not None and stop()):
        try:
            n = os.write(fd, view)
            view = view[n:]
        except BlockingIOError:
            if not select.select([], [fd], [], 0.1)[1] and _probe_client(fd) is None:
                raise OSError(errno.EIO, "client went away") from None


def _unread(slave_path: str) -> int | None:
    """Bytes the client has not read yet: the slave's input queue, read through a second, short-lived descriptor
    of the slave (the master's own output queue reads 0 on Linux ptys). None when the slave cannot be opened."""
    import fcntl
    import struct
    import termios

    try:
        fd = os.open(slave_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, struct.pack("i", 0)))[0]
    finally:
        os.close(fd)


def _drain(master: int, slave_path: str, settle_s: float = 0.2, stop=None) -> None:
    """Waits until the client has read everything written (closing the master drops what the client has not
    read), however long it takes; returns early only when the client goes away (then nothing can be
    delivered) or stop() holds. The kernel moves what is still in the pty's buffers into the slave's input queue as the
    client reads, so the queue must stay empty for settle_s."""
    empty_since = None
    while stop is None or not stop():
        if _probe_client(master) is None:   # no client (probed while this process holds no slave descriptor)
            return
        n = _unread(slave_path)
        if n is None:
            return
        now = time.monotonic()
        if n:
            empty_since = None
        elif empty_since is None:
            empty_since = now
        elif now - empty_since >= settle_s:
            return
        time.sleep(0.01)
