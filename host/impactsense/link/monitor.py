"""Live reports from a board (or the emulator): a transport, the C++ decoder, a table or JSON lines."""

from __future__ import annotations

import json
import math
import signal
import sys
import time
from collections import Counter

from ..stop_signals import sleep
from . import protocol
from .transport import PortClosed, read_some


class Monitor:
    """Reads frames from a transport; keeps counts of errors and sequence gaps."""

    def __init__(self, port):
        self.port = port
        self.decoder = protocol.Decoder()
        self.seq = protocol.SeqTracker()
        self.reports = 0
        self.rejected: Counter = Counter()  # reports without a position, by reason key
        self._version_said = False

    def frames(self, idle_timeout_s: float | None = None, stop=None):
        """Yields decoded frames (dicts, see `_link.Decoder.feed`) until the port closes, or, given stop
        (stop_signals.StopRequest), until stop() holds: checked before each read (a read waits at most the
        port's timeout), so a stop never cuts the handling of a frame."""
        last = time.monotonic()
        while stop is None or not stop():
            try:
                data = read_some(self.port)
            except PortClosed:
                return
            if data:
                last = time.monotonic()
                for frame in self.decoder.feed(data):
                    if frame["kind"] == "report":
                        self.reports += 1
                        self.seq.update(frame["report"]["seq"])
                        if not frame["report"]["valid"]:
                            self.rejected[frame["report"]["reason_key"]] += 1
                    yield frame
            elif idle_timeout_s is not None and time.monotonic() - last > idle_timeout_s:
                return

    def counters(self) -> dict:
        """The decoder's counts, reports, sequence gaps, and the reports not valid per reason
        (`rejected:KEY`, KEY an impactcore status key); BLE: the notifications that were not a report."""
        s = dict(self.decoder.stats)
        s.update(reports=self.reports, seq_gaps=self.seq.gaps, lost_reports=self.seq.lost,
                 rejected=sum(self.rejected.values()))
        s.update({f"rejected:{k}": n for k, n in sorted(self.rejected.items())})
        for k in ("bad_payloads", "ble_version_errors", "ble_other_version"):
            if hasattr(self.port, k):
                s[k] = getattr(self.port, k)
        return s

    def version_note(self) -> str | None:
        """A line saying that frames of another protocol version were dropped (None when none were)."""
        c = self.counters()
        n, v = c["version_errors"], c["other_version"]
        n_ble, v_ble = c.get("ble_version_errors", 0), c.get("ble_other_version", 0)
        if not (n or n_ble):
            return None
        return (f"{n + n_ble} frame(s) of protocol version {v or v_ble} dropped (not read as reports): this host "
                f"reads version {protocol.VERSION}; flash the board with the firmware of this release (README, "
                f"\"Firmware\") or use the host that matches the board's firmware")

    def say_version(self, err) -> None:
        """Prints version_note() once, when there is one."""
        note = None if self._version_said else self.version_note()
        if note:
            print(f"monitor: {note}", file=err, flush=True)
            self._version_said = True


REPORT_HEADER = (f"{'seq':>6} {'t_ms':>9} {'x_mm':>7} {'y_mm':>7} {'±mm':>6} {'E':>2} "
                 f"{'order':>5} {'acc':>3} clip dead  not reported because")


def reason_text(r: dict) -> str:
    """Why a report is not valid, as text (the core's status_name of its reason code); '' when valid."""
    return "" if r["valid"] else protocol.reason_text(r["reason"])


def report_line(r: dict, rejected: Counter | None = None) -> str:
    """One table row; a report that is not valid ends with its reason's key and text (and, given the monitor's
    per-reason counts, how many reports so far had that reason)."""
    order = "".join(str(c) for c in r["order"])
    line = (f"{r['seq']:>6} {r['timestamp_ms']:>9} {r['x_mm']:>7.1f} {r['y_mm']:>7.1f} "
            f"{r['uncertainty_mm']:>6.1f} {r['energy_class']:>2} {order:>5} "
            f"{'y' if r['accepted'] else 'n':>3} {r['clipped']:04b} {r['dead']:04b}")
    if not r["valid"]:
        n = f" #{rejected[r['reason_key']]}" if rejected is not None else ""
        line += f"  {r['reason_key']}{n}: {reason_text(r)}"
    return line


def _json_safe(d: dict) -> dict:
    return {k: (None if isinstance(v, float) and math.isnan(v) else
                [None if isinstance(x, float) and math.isnan(x) else x for x in v] if isinstance(v, list) else v)
            for k, v in d.items()}


def report_json(r: dict) -> str:
    d = dict(r)
    if not d.get("valid", True):
        d["reason_text"] = reason_text(d)
    if isinstance(d.get("uncertainty_mm"), float) and math.isnan(d["uncertainty_mm"]):
        d["uncertainty_mm"] = None
    for k in ("x_mm", "y_mm", "uncertainty_mm"):
        if d.get(k) is not None:
            d[k] = round(float(d[k]), 1)
    return json.dumps(d, sort_keys=True)


_HEALTH = ((1, "dead"), (2, "clipped"), (4, "no-onset"), (8, "hum"), (16, "glitch"),
           (32, "inconsistent"))  # impactlink.h ChannelHealth


def status_line(s: dict) -> str:
    """The board's once-a-second status frame as one line."""
    load = "?" if math.isnan(s["idle_load"]) else f"{100 * s['idle_load']:.1f}%"
    cyc = (f"event {s['event_cycles_last']:,}/{s['event_cycles_max']:,} cyc, idle buffer "
           f"{s['buffer_cycles_max']:,} cyc ({load})" if s["cycle_counter"] else "no cycle counter")
    noise = " ".join("?" if math.isnan(n) else f"{n:.1f}" for n in s["noise_counts"])
    health = " ".join("+".join(n for b, n in _HEALTH if h & b) or "ok" for h in s["health"])
    return (f"status t={s['uptime_ms'] / 1000:.0f}s events={s['events']} overruns={s['overruns']} "
            f"dropped_reports={s['dropped_reports']} {cyc} threshold={s['threshold_counts']} "
            f"noise=[{noise}] health=[{health}]" + (f" raw_dropped={s['raw_dropped']}" if s["raw_dropped"] else ""))


_END = object()


def read_in_thread(frames, tick, tick_s: float = 0.05):
    """Yields what the `frames` iterator yields, read in a thread of its own; calls tick() at least every
    tick_s seconds meanwhile (and between frames), so a slow consumer (a plot redraw) never stalls the reads
    and the consumer stays responsive while the port is quiet. Exceptions of the reader are re-raised."""
    import queue
    import threading

    q: queue.Queue = queue.Queue()

    def reader():
        try:
            for f in frames:
                q.put(f)
        except BaseException as exc:  # noqa: BLE001  (handed to the consumer)
            q.put(exc)
        finally:
            q.put(_END)

    threading.Thread(target=reader, name="impactsense-monitor-reader", daemon=True).start()
    due = time.monotonic() + tick_s
    while True:
        try:
            item = q.get(timeout=max(0.0, due - time.monotonic()))
        except queue.Empty:
            item = None
        if item is None or time.monotonic() >= due:
            tick()
            due = time.monotonic() + tick_s
        if item is None:
            continue
        if item is _END:
            return
        if isinstance(item, BaseException):
            raise item
        yield item


def _connection_frames(mon, idle_timeout_s, plot, state: dict, err, stop):
    """One connection's frames; with a plot they are read in a thread of their own while the window refreshes
    (state["plot"] is None once the window is closed)."""
    frames = mon.frames(idle_timeout_s, stop)
    if plot is None:
        return frames

    def tick():
        if state["plot"] is not None and not state["plot"].refresh():
            print("monitor: plot window closed; still monitoring", file=err)
            state["plot"] = None

    return read_in_thread(frames, tick)


def _open(open_port, reconnect: bool, retry_s: float, max_retries: int, err, stop):
    """The port, or None: it cannot be opened (said, after max_retries tries a retry_s apart with reconnect) or a
    stop came while retrying."""
    for retry in range(max_retries + 1 if reconnect else 1):
        if retry and sleep(retry_s, stop):
            return None
        try:
            return open_port()
        except Exception as exc:  # noqa: BLE001  (any open failure: retry or give up)
            failure = exc
    print(f"monitor: cannot open the port: {failure}", file=err)
    return None


def _stop_name(stop) -> str:
    return "Ctrl-C" if stop.signum == signal.SIGINT else stop.name


def run(open_port, json_lines: bool = False, reconnect: bool = False, out=sys.stdout, err=sys.stderr,
        idle_timeout_s: float | None = None, retry_s: float = 1.0, max_retries: int = 30, plot=None,
        log=None, stop=None) -> dict:
    """Prints reports until the port closes (and, with reconnect, re-opens it). Returns the counters.

    plot (link.plot.LivePlot): also draws the reports; the port is then read in a thread of its own.
    log (link.eventlog.EventLog): also keeps every report (and any other frame but raw data) in the event log.
    stop (stop_signals.StopRequest): once stop() holds, the connection ends as on a closed port (between frames,
    its close logged) and no other is opened."""
    totals: dict = {}
    header_done = False
    state = {"plot": plot}  # None once the window is closed
    while True:
        port = _open(open_port, reconnect, retry_s, max_retries, err, stop)
        if port is None:
            if stop is None or not stop():
                totals["open_failed"] = 1
            break
        mon = Monitor(port)
        if log is not None:
            log.connection_opened()
        try:
            for frame in _connection_frames(mon, idle_timeout_s, plot, state, err, stop):
                if log is not None and frame["kind"] not in ("report", "raw"):
                    log.add_frame(frame["kind"], frame)
                mon.say_version(err)  # once a connection, with the next frame after one of another version
                if frame["kind"] == "status":  # the board's health, once a second: beside the reports (stderr)
                    st = frame["status"]
                    print(json.dumps({"status": _json_safe(st)}, sort_keys=True) if json_lines else status_line(st),
                          file=err, flush=True)
                    continue
                if frame["kind"] != "report":
                    continue
                r = frame["report"]
                if log is not None:
                    log.add_report(r, mon.counters())
                if plot is not None and state["plot"] is not None:
                    state["plot"].add(r)
                if not json_lines and not header_done:
                    print(REPORT_HEADER, file=out)
                    header_done = True
                print(report_json(r) if json_lines else report_line(r, mon.rejected), file=out, flush=True)
        except KeyboardInterrupt:  # an in-process caller's Ctrl-C (the command sets `stop` instead)
            reconnect = False
            print("monitor: stopped (Ctrl-C)", file=err)
        else:
            if stop is not None and stop():
                reconnect = False
                print(f"monitor: stopped ({_stop_name(stop)})", file=err)
            else:
                print("monitor: the link ended (port closed or board unplugged)", file=err)
        finally:
            try:
                port.close()
            except Exception:  # noqa: BLE001
                pass
        if plot is not None and state["plot"] is not None:
            state["plot"].refresh()
        mon.say_version(err)  # nothing but frames of another version came
        for k, v in mon.counters().items():
            totals[k] = max(totals.get(k, 0), v) if k.endswith("other_version") else totals.get(k, 0) + v
        if log is not None:
            log.connection_closed(mon.counters())
            totals.update(stored=log.stored, duplicates_ignored=log.duplicates)
        if not reconnect:
            break
        print("monitor: port closed; reconnecting", file=err)
        if sleep(retry_s, stop):
            break
    print("monitor: " + ", ".join(f"{k}={v}" for k, v in totals.items()), file=err)
    return totals
