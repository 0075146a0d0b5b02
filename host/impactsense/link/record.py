"""Record raw captures from the board into a session folder (dump-raw mode of the protocol)."""

from __future__ import annotations

import numpy as np

from . import protocol
from .monitor import Monitor


class CaptureAssembler:
    """Collects raw chunks per event; a capture is complete when all 4 channels are filled."""

    def __init__(self):
        self.pending: dict[int, dict] = {}
        self.incomplete = 0

    def add(self, raw: dict):
        ev = self.pending.setdefault(raw["event_seq"], {"total": raw["total"], "data": None, "filled": None})
        if ev["data"] is None or ev["total"] != raw["total"]:
            ev["total"] = raw["total"]
            ev["data"] = np.zeros((4, raw["total"]), dtype=np.int16)
            ev["filled"] = np.zeros((4, raw["total"]), dtype=bool)
        s = raw["samples"]
        ev["data"][raw["channel"], raw["offset"]:raw["offset"] + s.size] = s
        ev["filled"][raw["channel"], raw["offset"]:raw["offset"] + s.size] = True

    def take(self, seq: int):
        ev = self.pending.pop(seq, None)
        for old in [k for k in self.pending if k < seq]:
            self.pending.pop(old)
            self.incomplete += 1
        if ev is None or not ev["filled"].all():
            self.incomplete += ev is not None
            return None
        return ev["data"]


def record(port, max_events: int | None = None, idle_timeout_s: float | None = None, progress=None):
    """Turns dump-raw on and collects (capture int16 [4, n], report) pairs until the port closes."""
    port.write(protocol.dump_raw(True))
    mon = Monitor(port)
    asm = CaptureAssembler()
    out = []
    fs_hz = None
    for frame in mon.frames(idle_timeout_s):
        if frame["kind"] == "ack":
            fs_hz = frame["ack"]["fs_hz"]
        elif frame["kind"] == "raw":
            asm.add(frame["raw"])
        elif frame["kind"] == "report":
            cap = asm.take(frame["report"]["seq"])
            if cap is not None:
                out.append((cap, frame["report"]))
                if progress:
                    progress(len(out))
                if max_events and len(out) >= max_events:
                    break
    return out, fs_hz, mon.counters(), asm.incomplete


def write_recorded_session(path, events, fs_hz: int, rig_template, height_mm: float = 100.0) -> None:
    """A session folder from recorded captures. The positions are the board's estimates (labelled so in
    rig.json notes): replace impacts.csv with the true positions before training on it."""
    from ..data import write_session

    rig = rig_template.to_dict()
    rig["fs_hz"] = int(fs_hz)
    rig["notes"] = ("Recorded by `impactsense record` from the board's raw captures (SAADC scan order: channel "
                    "c sampled c*5 us after channel 0). impacts.csv holds the BOARD'S ESTIMATES of x, y and "
                    "the --height-mm given to record: replace them with the true drop positions and heights before training.")
    adc = np.stack([np.clip(c, 0, None).astype(np.uint16) for c, _ in events])
    x = np.clip([r["x_mm"] for _, r in events], 0, rig["plate_x_mm"])
    y = np.clip([r["y_mm"] for _, r in events], 0, rig["plate_y_mm"])
    write_session(path, rig, x, y, np.full(len(events), float(height_mm)), adc)
