"""The event log: every report a monitor receives, kept in SQLite (`impactsense monitor --db FILE`).

One row per report, unique on (board id, boot, seq): a report that arrives twice (a replay, a second monitor on
the same board) is stored once. The wire carries a report counter since the board's boot (`seq`) and a clock
since boot (`timestamp_ms`), no boot identity, so the log numbers a board's boots itself, comparing each report
with the board's latest boot:
- the same seq with the same board clock: the same report (a duplicate, counted, not stored);
- a later seq at a later board time: the same boot (seqs skipped on the way are the boot's missing reports);
- a seq missing inside the boot's stored range, its board time between its stored neighbours': the same boot
  (a late copy of a lost report fills its gap);
- anything else (the counter or the clock went back): the board restarted, a new boot.
Missing reports and gaps are computed from what is stored (seq ranges per boot), so they stay right when a
replay fills a gap. Several monitors (boards) may write to one file: WAL journal, one short transaction per
report. Fields of a report other than the columns (clip/dead masks, order, channel-health flags, whatever a
later firmware adds) are kept as JSON in `flags`; the link's counters at receipt in `link`.
"""

from __future__ import annotations

import json
import math
import sqlite3
import time
from pathlib import Path

from ..errors import DataError

SCHEMA_VERSION = 1
COLUMNS = ("seq", "timestamp_ms", "x_mm", "y_mm", "uncertainty_mm", "energy_class", "accepted", "valid")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS reports (
  id INTEGER PRIMARY KEY,
  board_id TEXT NOT NULL,
  boot INTEGER NOT NULL,
  seq INTEGER NOT NULL,
  host_time REAL NOT NULL,
  board_ms INTEGER,
  x_mm REAL, y_mm REAL, uncertainty_mm REAL,
  energy_class INTEGER, accepted INTEGER, valid INTEGER,
  flags TEXT NOT NULL,
  link TEXT NOT NULL,
  UNIQUE (board_id, boot, seq)
);
CREATE INDEX IF NOT EXISTS reports_time ON reports (host_time);
CREATE TABLE IF NOT EXISTS boots (
  board_id TEXT NOT NULL, boot INTEGER NOT NULL, first_host_time REAL NOT NULL, duplicates INTEGER NOT NULL,
  PRIMARY KEY (board_id, boot)
);
CREATE TABLE IF NOT EXISTS connections (
  id INTEGER PRIMARY KEY, board_id TEXT NOT NULL, opened REAL NOT NULL, closed REAL, counters TEXT
);
CREATE TABLE IF NOT EXISTS frames (
  id INTEGER PRIMARY KEY, board_id TEXT NOT NULL, host_time REAL NOT NULL, kind TEXT NOT NULL, body TEXT NOT NULL
);
"""


def _json(d: dict) -> str:
    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        return v

    return json.dumps(clean(d), sort_keys=True, default=str)


def _num(v):
    return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v


def connect(path, create: bool = False) -> sqlite3.Connection:
    """An open event log; create=True makes the file and its tables if missing. A file that is not an event log
    is an error naming it (DataError)."""
    p = Path(path)
    if not create and not p.is_file():
        raise DataError(p, None, "event log not found")
    try:
        db = sqlite3.connect(p, timeout=30.0, isolation_level=None)
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=NORMAL")
        if create:
            db.executescript(_SCHEMA)
            db.execute("INSERT OR IGNORE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
        row = db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
    except sqlite3.DatabaseError as exc:
        raise DataError(p, None, f"not an impactsense event log ({exc})") from None
    if row is None or int(row[0]) != SCHEMA_VERSION:
        raise DataError(p, "meta.schema_version", f"{row and row[0]}: this version reads {SCHEMA_VERSION}")
    return db


class EventLog:
    """Appends one board's reports to an event log (`monitor --db`)."""

    def __init__(self, path, board_id: str, clock=time.time):
        self.db = connect(path, create=True)
        self.board_id = str(board_id)
        self.clock = clock
        self.stored = self.duplicates = 0
        self._conn_id = None

    def _boot_for(self, seq: int, ms: int | None) -> tuple[int, bool]:
        """(boot, is_duplicate) of a report of this board; may open a new boot. Inside a transaction."""
        q = self.db.execute
        cur = q("SELECT boot FROM boots WHERE board_id = ? ORDER BY boot DESC LIMIT 1", (self.board_id,)).fetchone()
        if cur is None:
            return self._new_boot(1), False
        boot = cur[0]
        same = q("SELECT board_ms FROM reports WHERE board_id = ? AND boot = ? AND seq = ?",
                 (self.board_id, boot, seq)).fetchone()
        if same is not None:
            if same[0] == ms:
                q("UPDATE boots SET duplicates = duplicates + 1 WHERE board_id = ? AND boot = ?", (self.board_id, boot))
                return boot, True
            return self._new_boot(boot + 1), False
        before = q("SELECT board_ms FROM reports WHERE board_id = ? AND boot = ? AND seq < ? ORDER BY seq DESC LIMIT 1",
                   (self.board_id, boot, seq)).fetchone()
        after = q("SELECT board_ms FROM reports WHERE board_id = ? AND boot = ? AND seq > ? ORDER BY seq LIMIT 1",
                  (self.board_id, boot, seq)).fetchone()
        t = -math.inf if ms is None else ms
        later = before is not None and (before[0] is None or before[0] <= t)
        if later and (after is None or after[0] is None or t <= after[0]):
            return boot, False   # after the boot's last report, or into one of its gaps
        return self._new_boot(boot + 1), False

    def _new_boot(self, boot: int) -> int:
        self.db.execute("INSERT INTO boots VALUES (?, ?, ?, 0)", (self.board_id, boot, self.clock()))
        return boot

    def add_report(self, report: dict, link: dict | None = None) -> bool:
        """Stores a decoded report (a `_link.Decoder` report dict); False if it was already in the log."""
        seq = int(report["seq"])
        ms = report.get("timestamp_ms")
        ms = None if ms is None else int(ms)
        flags = {k: v for k, v in report.items() if k not in COLUMNS}
        self.db.execute("BEGIN IMMEDIATE")
        try:
            boot, dup = self._boot_for(seq, ms)
            if not dup:
                self.db.execute(
                    "INSERT INTO reports (board_id, boot, seq, host_time, board_ms, x_mm, y_mm, uncertainty_mm, "
                    "energy_class, accepted, valid, flags, link) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?)",
                    (self.board_id, boot, seq, self.clock(), ms, _num(report.get("x_mm")), _num(report.get("y_mm")),
                     _num(report.get("uncertainty_mm")), report.get("energy_class"),
                     _bool(report.get("accepted")), _bool(report.get("valid", True)), _json(flags), _json(link or {})))
            self.db.execute("COMMIT")
        except BaseException:
            self.db.execute("ROLLBACK")
            raise
        self.duplicates += dup
        self.stored += not dup
        return not dup

    def add_frame(self, kind: str, body: dict) -> None:
        """Any other frame worth keeping (a status frame): its fields as JSON."""
        self.db.execute("INSERT INTO frames (board_id, host_time, kind, body) VALUES (?, ?, ?, ?)",
                        (self.board_id, self.clock(), kind, _json(body)))

    def connection_opened(self) -> None:
        cur = self.db.execute("INSERT INTO connections (board_id, opened) VALUES (?, ?)", (self.board_id, self.clock()))
        self._conn_id = cur.lastrowid

    def connection_closed(self, counters: dict) -> None:
        if self._conn_id is not None:
            self.db.execute("UPDATE connections SET closed = ?, counters = ? WHERE id = ?",
                            (self.clock(), _json(counters), self._conn_id))
            self._conn_id = None

    def close(self) -> None:
        self.db.close()


def _bool(v):
    return None if v is None else int(bool(v))


def boot_summary(db: sqlite3.Connection, since: float | None = None) -> list[dict]:
    """Per board and boot: reports stored, seq range, missing reports and gaps inside it, duplicates ignored."""
    rows = db.execute(
        "SELECT r.board_id, r.boot, COUNT(*), MIN(r.seq), MAX(r.seq), MIN(r.host_time), MAX(r.host_time), "
        "b.duplicates FROM reports r JOIN boots b ON b.board_id = r.board_id AND b.boot = r.boot "
        "WHERE r.host_time >= ? GROUP BY r.board_id, r.boot ORDER BY r.board_id, r.boot",
        (since if since is not None else -math.inf,)).fetchall()
    out = []
    for board, boot, n, lo, hi, t0, t1, dup in rows:
        gaps = db.execute(
            "SELECT COUNT(*) FROM reports r WHERE r.board_id = ? AND r.boot = ? AND r.seq > ? AND NOT EXISTS "
            "(SELECT 1 FROM reports p WHERE p.board_id = r.board_id AND p.boot = r.boot AND p.seq = r.seq - 1)",
            (board, boot, lo)).fetchone()[0]
        out.append({"board_id": board, "boot": boot, "reports": n, "first_seq": lo, "last_seq": hi,
                    "missing": hi - lo + 1 - n, "gaps": gaps, "duplicates_ignored": dup,
                    "first_host_time": t0, "last_host_time": t1})
    return out


def report_reason(r: dict) -> str:
    """A stored report's reason for not being valid: its key and text (`reason`, an impactcore status code, in its
    flags; a report logged from a board older than the reason byte has none: 'no reason (older firmware)')."""
    from .protocol import reason_text

    code = (r.get("flags") or {}).get("reason")
    if code is None:
        return "no reason (older firmware)"
    return f"{(r['flags'].get('reason_key') or code)}: {reason_text(code)}"


def reason_counts(reports: list[dict]) -> dict[tuple[str, int], dict[str, int]]:
    """Per (board, boot): how many of the reports were not valid, per reason key (most first)."""
    from collections import Counter

    out: dict[tuple[str, int], Counter] = {}
    for r in reports:
        if r["valid"] or r["valid"] is None:
            continue
        key = (r.get("flags") or {}).get("reason_key") or "no reason (older firmware)"
        out.setdefault((r["board_id"], r["boot"]), Counter())[key] += 1
    return {b: dict(c.most_common()) for b, c in out.items()}


def read_reports(db: sqlite3.Connection, since: float | None = None, board: str | None = None) -> list[dict]:
    """The stored reports (oldest first) as dicts: the columns, `flags` and `link` decoded."""
    q = ("SELECT board_id, boot, seq, host_time, board_ms, x_mm, y_mm, uncertainty_mm, energy_class, accepted, "
         "valid, flags, link FROM reports WHERE host_time >= ?")
    args: list = [since if since is not None else -math.inf]
    if board is not None:
        q += " AND board_id = ?"
        args.append(board)
    keys = ("board_id", "boot", "seq", "host_time", "board_ms", "x_mm", "y_mm", "uncertainty_mm", "energy_class",
            "accepted", "valid", "flags", "link")
    out = []
    for row in db.execute(q + " ORDER BY host_time, id", args):
        d = dict(zip(keys, row))
        d["flags"], d["link"] = json.loads(d["flags"]), json.loads(d["link"])
        out.append(d)
    return out
