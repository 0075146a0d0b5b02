"""`impactsense monitor --port PORT`: live reports from the board (USB serial, pty emulator or BLE).

A table (or, with --json-lines, one JSON object per report) on stdout; `--plot` also opens a live plot of the
plate (needs a display; without one the monitor says so and carries on without it)."""

ORDER = 62


def register(sub):
    p = sub.add_parser("monitor", help="show live impact reports from the board", description=__doc__)
    p.add_argument("--port", help="serial port or pyserial URL (/dev/ttyACM0, /dev/pts/N, loop://)")
    p.add_argument("--ble", metavar="NAME_OR_ADDRESS", help="connect over BLE instead (bleak)")
    p.add_argument("--json-lines", action="store_true", help="one JSON object per report on stdout")
    p.add_argument("--reconnect", action="store_true", help="re-open the port after a disconnect")
    p.add_argument("--baud", type=int, default=115200,
                   help="serial baud rate (default 115200; USB CDC ignores it, a UART bridge does not)")
    p.add_argument("--plot", action="store_true",
                   help="live plot of the plate: sensors, the last impacts by energy class, the uncertainty")
    p.add_argument("--plot-last", type=int, default=20, metavar="N", help="impacts shown on the plot (default 20)")
    p.add_argument("--db", metavar="EVENTS.sqlite",
                   help="also keep every report in this SQLite event log (appends; no duplicates; see "
                        "`impactsense events`)")
    p.add_argument("--board-id", default=None,
                   help="the board's name in the event log (default: the port, or ble:NAME); give one per board "
                        "when a board's port name can change")
    p.add_argument("--rig", default=None,
                   help="rig.json or session folder for the plot's plate and sensors (default: bundled session-1)")
    p.set_defaults(func=run)


def run(args) -> int:
    import sys

    from ..link import monitor
    from ..link.transport import BleTransport, open_serial

    if not args.port and not args.ble:
        print("monitor: give --port or --ble", file=sys.stderr)
        return 2
    plot = None
    if args.plot:
        from ..data import load_rig, load_session
        from ..link.plot import open_live_plot

        if args.plot_last < 1:
            from ..errors import ConfigError

            raise ConfigError(f"--plot-last must be at least 1, got {args.plot_last}")
        rig = load_rig(args.rig) if args.rig else load_session(None).rig
        plot = open_live_plot((rig.plate_x_mm, rig.plate_y_mm), list(zip(rig.sensor_x_mm, rig.sensor_y_mm)),
                              args.plot_last)
    opener = (lambda: BleTransport(args.ble)) if args.ble else (lambda: open_serial(args.port, args.baud))
    log = None
    if args.db:
        from ..link.eventlog import EventLog

        log = EventLog(args.db, args.board_id or (f"ble:{args.ble}" if args.ble else args.port))
    from ..stop_signals import stopped_by_signals

    try:
        with stopped_by_signals() as stop:  # Ctrl-C / kill / hang-up end it between frames, its log closed
            totals = monitor.run(opener, json_lines=args.json_lines, reconnect=args.reconnect, plot=plot, log=log,
                                 out=sys.stdout, err=sys.stderr, stop=stop)
    finally:
        if log is not None:
            log.close()
    if stop() and stop.name != "SIGINT":  # SIGTERM / SIGHUP: the exit code says which (as a shell reports a kill)
        return 128 + stop.signum
    if plot is not None and plot.refresh():
        import matplotlib.pyplot as plt

        print("monitor: port closed; close the plot window to exit", file=sys.stderr)
        plt.ioff()
        plt.show()
    if totals.get("open_failed"):
        return 2
    return 0 if totals.get("reports", 0) or not totals.get("crc_errors") else 1
