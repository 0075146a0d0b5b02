"""Record raw captures from the board into a session folder (dump-raw mode of the protocol)."""

from __future__ import annotations

import json

import numpy as np

from ..data import write_session
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


def record(port, max_events: int | None = None, idle_timeout_s: float | None = None, progress=None, sink=None,
           stop=None):
    """Turns dump-raw on and collects (capture int16 [4, n], report) pairs until the port closes, max_events
    are in, stop() holds (stop_signals.StopRequest, checked between reads) or Ctrl-C. Each pair goes to
    sink(capture, report) as it arrives (journal.CaptureJournal.append) and, without a sink, into the returned
    list. Returns (pairs, fs_hz, link counters, incomplete captures, why it stopped: "max-events", "link ended"
    or "interrupted")."""
    port.write(protocol.dump_raw(True))
    mon = Monitor(port)
    asm = CaptureAssembler()
    out = []
    fs_hz = None
    n = 0
    why = "link ended"
    try:
        for frame in mon.frames(idle_timeout_s, stop):
            if frame["kind"] == "ack":
                fs_hz = frame["ack"]["fs_hz"]
                if sink is not None and hasattr(sink, "set_fs"):
                    sink.set_fs(fs_hz)
            elif frame["kind"] == "raw":
                asm.add(frame["raw"])
            elif frame["kind"] == "report":
                cap = asm.take(frame["report"]["seq"])
                if cap is not None:
                    n += 1
                    if sink is not None:
                        sink(cap, frame["report"])
                    else:
                        out.append((cap, frame["report"]))
                    if progress:
                        progress(n)
                    if max_events and n >= max_events:
                        why = "max-events"
                        break
        if why == "link ended" and stop is not None and stop():
            why = "interrupted"
    except KeyboardInterrupt:   # an in-process caller's Ctrl-C, or one at the --ask prompt
        why = "interrupted"
    return out, fs_hz, mon.counters(), asm.incomplete, why


LABELS = ("x_mm", "y_mm", "height_mm")


def read_truth_csv(path) -> list[dict]:
    """The true drops, one row per capture in recording order: x_mm, y_mm, height_mm (empty: unknown),
    optional case_id and repetition. DataError naming the file and field on anything else."""
    import csv
    from pathlib import Path

    from ..errors import DataError

    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            missing = [c for c in LABELS if c not in (reader.fieldnames or [])]
            if missing:
                raise DataError(path, missing[0], "missing column")
            rows = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DataError(path, None, f"not a readable UTF-8 CSV file ({exc})") from None
    out = []
    for line, row in enumerate(rows, start=2):
        d = {}
        for col in (*LABELS, "case_id", "repetition"):
            text = (row.get(col) or "").strip()
            try:
                d[col] = (float(text) if col in LABELS else int(text)) if text else None
            except ValueError:
                raise DataError(path, col, f"line {line}: {text[:20]!r} is not a number") from None
        out.append(d)
    return out


def ask_truth(n: int, read=input) -> dict:
    """One drop's truth typed by the user: 'x_mm y_mm height_mm' (Enter: unknown)."""
    while True:
        text = read(f"drop {n}: true x_mm y_mm height_mm (Enter: unknown): ").strip()
        if not text:
            return {}
        try:
            x, y, h = (float(v) for v in text.replace(",", " ").split())
            return {"x_mm": x, "y_mm": y, "height_mm": h}
        except ValueError:
            print("  three numbers, e.g. 160 150 100", flush=True)


def label_arrays(n: int, rows: list[dict], fixed: dict) -> dict:
    """x_mm, y_mm, height_mm (NaN: unknown), case_id, repetition of n drops: rows[i] (truth CSV or typed),
    else the values given once on the command line (fixed), else unknown. Never the board's estimate."""
    out = {c: np.full(n, np.nan) for c in LABELS}
    out["case_id"] = np.arange(n)
    out["repetition"] = np.zeros(n, int)
    for i in range(n):
        row = rows[i] if i < len(rows) else {}
        for c in LABELS:
            v = row.get(c, fixed.get(c))
            out[c][i] = np.nan if v is None else float(v)
        for c in ("case_id", "repetition"):
            if row.get(c) is not None:
                out[c][i] = int(row[c])
    return out


def finish_session(out, journal, labels_from: str, rows: list[dict], fixed: dict, why: str,
                   force: bool = False) -> tuple[int, bool]:
    """The journal as the session folder OUT (outputs.output_folder), then the journal removed. rig.json's
    notes say where the labels came from and, unless max-events were recorded, that the session is
    incomplete and why. Returns (captures written, complete)."""
    import csv
    import io
    import shutil

    from ..data import rig_from_dict
    from .journal import read_journal

    meta, events, clean = read_journal(journal)
    if not events:
        shutil.rmtree(journal, ignore_errors=True)
        return 0, False
    lengths = [c.shape for c, _ in events]
    shape = max(set(lengths), key=lengths.count)
    events = [(c, r) for c, r in events if c.shape == shape]
    rig = dict(meta["rig"])
    rig["fs_hz"] = int(meta.get("fs_hz") or rig["fs_hz"])
    complete = why == "max-events" and clean
    rig["notes"] = (f"Recorded by `impactsense record` from the board's raw captures (SAADC scan order: channel "
                    f"c sampled c*5 us after channel 0). Labels (x_mm, y_mm, height_mm): {labels_from}; an empty "
                    f"cell is unknown. The board's own estimates are in board_reports.csv, not in impacts.csv."
                    + ("" if complete else f" INCOMPLETE: recording stopped ({why}"
                       + ("" if clean else ", the journal's last capture was cut short") + ")."))
    rig_from_dict(rig)
    n = len(events)
    lab = label_arrays(n, rows, fixed)
    adc = np.stack([np.clip(c, 0, None).astype(np.uint16) for c, _ in events])
    buf = io.StringIO()
    keys = sorted({k for _, r in events for k in r})
    w = csv.DictWriter(buf, fieldnames=["recording_id", *keys])
    w.writeheader()
    for i, (_, r) in enumerate(events):
        w.writerow({"recording_id": i, **{k: json.dumps(v) if isinstance(v, (list, dict)) else v
                                          for k, v in r.items()}})
    write_session(out, rig, lab["x_mm"], lab["y_mm"], lab["height_mm"], adc, lab["case_id"], lab["repetition"],
                  force=force, extra_files={"board_reports.csv": buf.getvalue()})
    shutil.rmtree(journal, ignore_errors=True)
    return n, complete
