"""`impactsense events EVENTS.sqlite`: the reports an event log keeps (`impactsense monitor --db`).

Lists the reports (oldest first; one that is not valid with the reason the board gave) and, per board and boot,
how many were stored, the seq range, the reports missing inside it (gaps), the duplicates ignored and the reports
not valid per reason. --html writes one self-contained page: the plate with its
sensors and the impacts, a heat map, the energy classes over time and the link's health."""

from __future__ import annotations

ORDER = 63


def register(sub):
    p = sub.add_parser("events", help="list the event log of `monitor --db`; --html draws it", description=__doc__)
    p.add_argument("db", metavar="EVENTS.sqlite", help="event log written by `impactsense monitor --db`")
    p.add_argument("--since", default=None, metavar="WHEN",
                   help="only reports received since WHEN: an ISO date/time (2026-11-25, 2026-11-25T18:00, local "
                        "time) or an age (30m, 2h, 7d)")
    p.add_argument("--board", default=None, help="only this board id")
    p.add_argument("--html", default=None, metavar="OUT.html", help="write the page there")
    p.add_argument("--rig", default=None,
                   help="rig.json or session folder for the page's plate and sensors (default: bundled session-1)")
    p.add_argument("--json-lines", action="store_true", help="list the reports as JSON lines")
    p.add_argument("--quiet", action="store_true", help="no list, only the per-boot summary")
    p.set_defaults(func=run)


def parse_since(text: str | None, now: float | None = None) -> float | None:
    """Unix time of --since: an ISO date/time (local time) or an age like 30m, 2h, 7d, 45s."""
    import datetime as dt
    import re
    import time

    from ..errors import ConfigError

    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([smhd])\s*", text)
    if m:
        unit = {"s": 1, "m": 60, "h": 3600, "d": 86400}[m.group(2)]
        return (time.time() if now is None else now) - float(m.group(1)) * unit
    try:
        return dt.datetime.fromisoformat(text.strip()).timestamp()
    except ValueError:
        raise ConfigError(f"--since {text!r}: neither an ISO date/time nor an age like 30m, 2h, 7d") from None


def run(args) -> int:
    import json
    import sys
    import time

    from ..link.eventlog import boot_summary, connect, read_reports, reason_counts, report_reason

    since = parse_since(args.since)
    db = connect(args.db)
    reports = read_reports(db, since, args.board)
    summary = [s for s in boot_summary(db, since) if args.board is None or s["board_id"] == args.board]
    if not args.quiet:
        if args.json_lines:
            for r in reports:
                print(json.dumps(r, sort_keys=True))
        else:
            print(f"{'host time':19} {'board':>12} {'boot':>4} {'seq':>6} {'x_mm':>6} {'y_mm':>6} {'±mm':>5} "
                  f"{'E':>2} {'acc':>3} {'ok':>2}  not reported because")
            for r in reports:
                t = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(r["host_time"]))
                print(f"{t:19} {r['board_id'][-12:]:>12} {r['boot']:>4} {r['seq']:>6} {_f(r['x_mm'])} {_f(r['y_mm'])} "
                      f"{_f(r['uncertainty_mm'], 5)} {_i(r['energy_class'])} {_yn(r['accepted'], 3)} {_yn(r['valid'], 2)}"
                      + ("" if r["valid"] or r["valid"] is None else f"  {report_reason(r)}"))
    for s in summary:
        print(f"board {s['board_id']} boot {s['boot']}: {s['reports']} reports, seq {s['first_seq']}..{s['last_seq']}, "
              f"{s['missing']} missing in {s['gaps']} gaps, {s['duplicates_ignored']} duplicates ignored",
              file=sys.stderr)
    for (board, boot), counts in reason_counts(reports).items():
        print(f"board {board} boot {boot}: not reported: " + ", ".join(f"{n} {k}" for k, n in counts.items()),
              file=sys.stderr)
    if args.html:
        _write_page(args, db, reports, summary)
    db.close()
    return 0


def _write_page(args, db, reports, summary) -> None:
    import json
    import sys

    from ..data import load_rig, load_session
    from ..link.eventpage import page

    rig = load_rig(args.rig) if args.rig else load_session(None).rig
    conns = [{"board_id": b, "opened": o, "closed": c, "counters": json.loads(k) if k else {}}
             for b, o, c, k in db.execute("SELECT board_id, opened, closed, counters FROM connections")]
    text = page(reports, summary, conns, rig, str(args.db))
    from ..outputs import write_file

    out = write_file(args.html, text.encode("utf-8"))  # whole or not at all
    print(f"wrote {out} ({len(reports)} reports)", file=sys.stderr)


def _f(v, w: int = 6) -> str:
    return f"{v:>{w}.1f}" if v is not None else " " * (w - 1) + "-"


def _i(v) -> str:
    return f"{v:>2}" if v is not None else " -"


def _yn(v, w: int) -> str:
    return f"{'-' if v is None else 'y' if v else 'n':>{w}}"
