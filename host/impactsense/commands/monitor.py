"""`impactsense monitor --port PORT`: live reports from the board (USB serial, pty emulator or BLE)."""

ORDER = 62


def register(sub):
    p = sub.add_parser("monitor", help="show live impact reports from the board", description=__doc__)
    p.add_argument("--port", help="serial port or pyserial URL (/dev/ttyACM0, /dev/pts/N, loop://)")
    p.add_argument("--ble", metavar="NAME_OR_ADDRESS", help="connect over BLE instead (bleak)")
    p.add_argument("--json-lines", action="store_true", help="one JSON object per report on stdout")
    p.add_argument("--reconnect", action="store_true", help="re-open the port after a disconnect")
    p.add_argument("--baud", type=int, default=115200)
    p.set_defaults(func=run)


def run(args) -> int:
    import sys

    from ..link import monitor
    from ..link.transport import BleTransport, open_serial

    if not args.port and not args.ble:
        print("monitor: give --port or --ble", file=sys.stderr)
        return 2
    opener = (lambda: BleTransport(args.ble)) if args.ble else (lambda: open_serial(args.port, args.baud))
    totals = monitor.run(opener, json_lines=args.json_lines, reconnect=args.reconnect)
    return 0 if totals.get("reports", 0) or not totals.get("crc_errors") else 1
