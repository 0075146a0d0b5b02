"""`impactsense record --port PORT --out DIR`: raw captures from the board into a session folder.

Every capture is on disk as it arrives (a journal beside DIR, fsync'd in batches); on max events, Ctrl-C or
`kill` (SIGINT or SIGTERM, also when started in the background), an error or an unplugged board the captures
so far become the session folder DIR (rig.json's notes mark it incomplete unless --max-events were recorded).
After a crash the next `record --out DIR` saves the journal's captures first. impacts.csv gets the true position
and height of each drop from --truth CSV, --ask, or --x-mm/--y-mm/--height-mm, or leaves them empty (unknown):
never the board's estimate (that goes to board_reports.csv)."""

ORDER = 63


def register(sub):
    p = sub.add_parser("record", help="record raw captures from the board into a session folder",
                       description=__doc__)
    p.add_argument("--port", required=True, help="serial port or pyserial URL")
    p.add_argument("--out", required=True, help="session folder to write")
    p.add_argument("--max-events", type=int, default=None, help="stop after this many captures (default: Ctrl-C)")
    p.add_argument("--rig", default=None, help="rig.json template (default: the bundled session-1 rig)")
    p.add_argument("--truth", default=None, metavar="CSV",
                   help="true drops in recording order: columns x_mm, y_mm, height_mm [, case_id, repetition]")
    p.add_argument("--ask", action="store_true", help="ask for each drop's true x, y and height as it comes")
    for key in ("x-mm", "y-mm", "height-mm"):
        p.add_argument(f"--{key}", type=float, default=None, help=f"true {key.replace('-', '_')} of every drop")
    p.add_argument("--baud", type=int, default=115200, help="serial baud rate (USB CDC ignores it)")
    p.add_argument("--force", action="store_true", help="write into a folder that holds other files (kept)")
    p.set_defaults(func=run)


def run(args) -> int:
    import sys

    from ..data import load_rig, load_session
    from ..errors import ConfigError
    from ..link.journal import journal_path
    from ..link.record import finish_session, read_truth_csv
    from ..outputs import check_output_folder
    from ..stop_signals import stopped_by_signals

    fixed = {k: getattr(args, k) for k in ("x_mm", "y_mm", "height_mm") if getattr(args, k) is not None}
    rows = read_truth_csv(args.truth) if args.truth else []
    if args.ask and args.truth:
        raise ConfigError("give --truth or --ask, not both")
    if args.ask and not sys.stdin.isatty():
        raise ConfigError("--ask needs a terminal (give --truth CSV instead)")
    how = (f"from {args.truth}" if args.truth else "typed in at each drop (--ask)" if args.ask else
           f"from the command line ({', '.join(f'{k}={v:g}' for k, v in fixed.items())})" if fixed else "unknown")
    check_output_folder(args.out, args.force)
    journal = journal_path(args.out)
    if journal.exists():     # a recording cut short by a kill: save it before anything else
        n, _ = finish_session(args.out, journal, "unknown (recovered after a crash)", [], {}, "recovered after a crash",
                              args.force)
        print(f"record: saved {n} captures of an interrupted recording into {args.out}; give another --out for "
              "a new recording", file=sys.stderr)
        return 1
    rig = load_rig(args.rig) if args.rig else load_session(None).rig
    with stopped_by_signals() as stop:   # Ctrl-C / kill / hang-up end the recording between reads, saved
        return _record(args, rig, journal, how, rows, fixed, stop)


def _record(args, rig, journal, how, rows, fixed, stop) -> int:
    """Opens the port, records into the journal until a stop, and saves the journal as the session folder."""
    import sys

    from ..errors import ConfigError
    from ..link.journal import CaptureJournal
    from ..link.record import ask_truth, finish_session, record
    from ..link.transport import open_serial

    try:
        port = open_serial(args.port, args.baud)
    except Exception as exc:  # noqa: BLE001  (pyserial raises several types)
        raise ConfigError(f"--port {args.port}: cannot open ({exc})") from None
    sink = CaptureJournal(journal, {"rig": rig.to_dict(), "fs_hz": None})

    def progress(n):
        print(f"\rrecorded {n}", end="", file=sys.stderr, flush=True)
        if args.ask:
            print(file=sys.stderr)
            with stop.interruptible():   # a stop at the prompt: no flag wakes input()
                rows.append(ask_truth(n))

    why = "error"
    try:
        _, _, counters, incomplete, why = record(port, args.max_events, progress=progress, sink=sink, stop=stop)
    finally:
        sink.close()
        try:
            port.close()
        except Exception:  # noqa: BLE001
            pass
        print(file=sys.stderr)
        n, complete = finish_session(args.out, journal, how, rows, fixed, why, args.force)
        print(f"record: {n} captures -> {args.out} ({'complete' if complete else 'INCOMPLETE: ' + why}; labels "
              f"{how})" if n else "record: no complete capture received", file=sys.stderr)
    print(f"record: link: incomplete captures {incomplete}, crc errors {counters['crc_errors']}, lost reports "
          f"{counters['lost_reports']}", file=sys.stderr)
    return 0 if n else 1
