"""`impactsense emulate DATA --pty`: a pseudo-terminal that behaves like the board, running the firmware
app (compiled natively) on recorded drops."""

ORDER = 61


def register(sub):
    p = sub.add_parser("emulate", help="serve recorded drops through the firmware code on a pty",
                       description=__doc__)
    p.add_argument("data", nargs="?", default=None, help="session folder (default: bundled session-1)")
    p.add_argument("--pty", action="store_true", required=True, help="serve on a pseudo-terminal")
    p.add_argument("--speed", type=float, default=1.0, help="x real time; 0 = as fast as the client reads")
    p.add_argument("--models", default="models", help="export folder with forest_tables.npz (default models/)")
    p.add_argument("--rate", type=int, default=50000, help="per-channel sample rate of the board (Hz)")
    p.add_argument("--limit", type=int, default=None, help="only the first N drops")
    p.add_argument("--threshold", type=float, default=None, help="trigger threshold (counts)")
    p.set_defaults(func=run)


def run(args) -> int:
    import sys
    from pathlib import Path

    from ..data import load_session
    from ..export import firmware_models
    from ..link.emulator import Emulator, serve_pty

    s = load_session(args.data)
    if args.limit:
        s = s.subset(list(range(min(args.limit, len(s)))))
    path = Path(args.models)
    have = path.is_file() or (path / "forest_tables.npz").is_file()
    models, signal = firmware_models(path) if have else (None, None)
    if models is None:
        print(f"emulate: no exported models in {args.models}; reports carry the physics localiser's position (valid=0)", file=sys.stderr)
    extra = {} if args.threshold is None else {"threshold_counts": args.threshold}
    emu = Emulator(s, models, fs_hz=args.rate, signal=signal, **extra)
    serve_pty(emu, speed=args.speed, announce=lambda p: print(p, flush=True))
    print(f"emulate: {emu.app.events} reports from {len(s)} drops", file=sys.stderr)
    return 0
