"""`impactsense record --port PORT --out DIR`: raw captures from the board into a session folder."""

ORDER = 63


def register(sub):
    p = sub.add_parser("record", help="record raw captures from the board into a session folder",
                       description=__doc__)
    p.add_argument("--port", required=True, help="serial port or pyserial URL")
    p.add_argument("--out", required=True, help="session folder to write")
    p.add_argument("--max-events", type=int, default=None)
    p.add_argument("--rig", default=None, help="rig.json template (default: the bundled session-1 rig)")
    p.add_argument("--height-mm", type=float, default=100.0, help="drop height written to impacts.csv")
    p.add_argument("--baud", type=int, default=115200)
    p.set_defaults(func=run)


def run(args) -> int:
    import sys

    from ..data import load_rig, load_session
    from ..link.record import record, write_recorded_session
    from ..link.transport import open_serial

    rig = load_rig(args.rig) if args.rig else load_session(None).rig
    port = open_serial(args.port, args.baud)
    try:
        events, fs_hz, counters, incomplete = record(
            port, args.max_events, progress=lambda n: print(f"\rrecorded {n}", end="", file=sys.stderr))
    finally:
        port.close()
    print(file=sys.stderr)
    if not events:
        print("record: no complete capture received", file=sys.stderr)
        return 1
    write_recorded_session(args.out, events, fs_hz or 50000, rig, args.height_mm)
    print(f"record: {len(events)} captures -> {args.out} (incomplete {incomplete}, "
          f"crc errors {counters['crc_errors']}, lost reports {counters['lost_reports']})", file=sys.stderr)
    return 0
