"""`impactsense record`'s capture journal: every capture on disk as it arrives, whatever happens next.

The journal is a folder beside the session folder being recorded, `.OUT.record-journal/`: `meta.json` (the
rig template, the board's sample rate) and `captures.bin`, append-only records

    b"ISJ1" | seq u32 | channels u32 | samples u32 | report length u32 | crc32 u32 | int16 samples | report JSON

fsync'd every BATCH captures or SYNC_S seconds. A record cut short (a kill mid-write) and anything after it
is ignored on reading. When recording stops (max events, Ctrl-C, an error, the board unplugged) the journal
becomes the session folder (`finish`) and is removed; after a kill it stays, and the next `record --out OUT`
turns it into OUT first (marked incomplete), so no capture is lost.
"""

from __future__ import annotations

import json
import os
import struct
import time
import zlib
from pathlib import Path

import numpy as np

MAGIC = b"ISJ1"
_HEAD = struct.Struct("<4sIIIII")
BATCH = 16
SYNC_S = 1.0
CAPTURES = "captures.bin"
META = "meta.json"


def journal_path(out: str | os.PathLike) -> Path:
    out = Path(out)
    return out.parent / f".{out.name}.record-journal"


class CaptureJournal:
    """Appends captures to a journal folder (created; an existing journal must be finished first)."""

    def __init__(self, path: Path, meta: dict):
        self.path = Path(path)
        self.path.mkdir(parents=True)
        self.meta = dict(meta)
        self._write_meta()
        self.fh = open(self.path / CAPTURES, "ab")
        self.count = 0
        self._unsynced = 0
        self._last_sync = time.monotonic()

    def _write_meta(self) -> None:
        from ..outputs import write_file

        write_file(self.path / META, json.dumps(self.meta, indent=1))

    def set_fs(self, fs_hz) -> None:
        if fs_hz and self.meta.get("fs_hz") != fs_hz:
            self.meta["fs_hz"] = int(fs_hz)
            self._write_meta()

    def __call__(self, capture: np.ndarray, report: dict) -> None:
        data = np.ascontiguousarray(capture, dtype="<i2")
        rep = json.dumps(report, default=_plain).encode()
        body = data.tobytes() + rep
        self.fh.write(_HEAD.pack(MAGIC, int(report.get("seq", self.count)) & 0xFFFFFFFF, data.shape[0],
                                 data.shape[1], len(rep), zlib.crc32(body)) + body)
        self.count += 1
        self._unsynced += 1
        if self._unsynced >= BATCH or time.monotonic() - self._last_sync > SYNC_S:
            self.sync()

    def sync(self) -> None:
        self.fh.flush()
        os.fsync(self.fh.fileno())
        self._unsynced = 0
        self._last_sync = time.monotonic()

    def close(self) -> None:
        if not self.fh.closed:
            self.sync()
            self.fh.close()


def _plain(v):
    return v.tolist() if hasattr(v, "tolist") else str(v)


def read_journal(path: Path) -> tuple[dict, list[tuple[np.ndarray, dict]], bool]:
    """(meta, [(capture int16 [channels, samples], report)], whether the file ended cleanly)."""
    meta = json.loads((path / META).read_text())
    raw = (path / CAPTURES).read_bytes() if (path / CAPTURES).is_file() else b""
    out, pos = [], 0
    while pos + _HEAD.size <= len(raw):
        magic, _seq, ch, n, rep_len, crc = _HEAD.unpack_from(raw, pos)
        size = ch * n * 2 + rep_len
        body = raw[pos + _HEAD.size: pos + _HEAD.size + size]
        if magic != MAGIC or ch > 64 or len(body) != size or zlib.crc32(body) != crc:
            return meta, out, False
        cap = np.frombuffer(body[:ch * n * 2], dtype="<i2").reshape(ch, n).copy()
        out.append((cap, json.loads(body[ch * n * 2:])))
        pos += _HEAD.size + size
    return meta, out, pos == len(raw)
