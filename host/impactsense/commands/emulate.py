"""`impactsense emulate [DATA] --pty`: a pseudo-terminal that behaves like the board, running the firmware
app (compiled natively) on recorded drops.

It prints the pty's path (e.g. /dev/pts/5) and serves clients one after another until interrupted (Ctrl-C),
as a board on a USB port does: `impactsense monitor --port PATH`, `pio device monitor -p PATH`, then another.
The app's report counter and clock run on across clients; while no client is connected the drops wait."""

ORDER = 61


def register(sub):
    p = sub.add_parser("emulate", help="serve recorded drops through the firmware code on a pty",
                       description=__doc__)
    p.add_argument("data", nargs="?", default=None, help="session folder (default: bundled session-1)")
    p.add_argument("--pty", action="store_true", required=True, help="serve on a pseudo-terminal")
    p.add_argument("--speed", type=float, default=1.0, help="x real time; 0 = as fast as the client reads")
    p.add_argument("--models", default=None, metavar="DIR|none",
                   help="export folder with forest_tables.npz (`impactsense export`); default: the board model "
                        "shipped with the package; 'none': no models, reports carry the physics localiser's "
                        "position (valid=0)")
    p.add_argument("--rate", type=int, default=50000, help="per-channel sample rate of the board (Hz)")
    p.add_argument("--limit", type=int, default=None, help="only the first N drops")
    p.add_argument("--threshold", type=float, default=None, help="trigger threshold (counts)")
    p.add_argument("--once", action="store_true",
                   help="serve one client, one pass through the drops, then exit")
    p.add_argument("--passes", type=int, default=None, metavar="N",
                   help="passes through the drops before exiting (default: 1 with --once, else 0 = until "
                        "interrupted)")
    p.add_argument("--link", default=None, metavar="PATH",
                   help="also make PATH a symlink to the pty (a stable name across emulator restarts)")
    p.add_argument("--inject", default=None, metavar="hum=40,glitch=0.1,offset=8,...",
                   help="put lab faults into the drops first (the fields of `impactsense inject`: hum, hum_hz, "
                        "offset, glitch, drift, noise, dead_channel, debond, debond_hz, seed)")
    p.set_defaults(func=run)


def run(args) -> int:
    import sys
    from pathlib import Path

    from ..data import load_session
    from ..errors import ConfigError
    from ..export import firmware_models, shipped_board_model
    from ..link.emulator import Emulator, serve_pty

    passes = args.passes if args.passes is not None else (1 if args.once else 0)
    if passes < 0:
        raise ConfigError(f"--passes must be >= 0, got {passes}")
    if args.models is None:
        path = shipped_board_model()
        if path is None:
            raise ConfigError("no shipped board model found with the package; give --models DIR or --models none")
    else:
        path = None if args.models == "none" else Path(args.models)
    s = load_session(args.data)
    if args.limit:
        s = s.subset(list(range(min(args.limit, len(s)))))
    if args.inject:
        from ..faults import inject_session, parse_spec

        spec = parse_spec(args.inject)
        s = inject_session(s, spec)
        print(f"emulate: faults {spec.describe() or 'none'}", file=sys.stderr)
    models, signal = firmware_models(path) if path is not None else (None, None)
    if signal:
        _require_models_rig(signal, s, path)
    print(f"emulate: {len(s)} drops of {s.name}, models: "
          f"{path if path is not None else 'none (reports carry the physics position, valid=0)'}", file=sys.stderr)
    extra = {} if args.threshold is None else {"threshold_counts": args.threshold}
    emu = Emulator(s, models, fs_hz=args.rate, signal=signal, **extra)
    import faulthandler

    from ..stop_signals import stopped_by_signals

    faulthandler.enable()   # a native crash (SIGSEGV, SIGABRT, ...) prints the Python stack to stderr
    code = 0
    with stopped_by_signals() as stop:   # Ctrl-C / kill / hang-up: the pty closed and the link removed between drops
        serve_pty(emu, speed=args.speed, announce=lambda p: print(p, flush=True), once=args.once,
                  passes=passes, link=args.link, connect_timeout_s=600.0 if args.once else None,
                  log=lambda m: print(f"emulate: {m}", file=sys.stderr, flush=True), stop=stop)
    if stop() and stop.name != "SIGINT":   # SIGTERM / SIGHUP: said, and a non-zero exit (128 + signum)
        print(f"emulate: stopped by {stop.name}", file=sys.stderr)
        code = 128 + stop.signum
    print(f"emulate: {emu.app.events} reports", file=sys.stderr, flush=True)
    return code


def _require_models_rig(signal: dict, session, path) -> None:
    """ConfigError unless the exported models were made for the session's sensors and plate (the shipped model
    is the bundled rig's: on another rig its positions would be silently wrong)."""
    import numpy as np

    from ..checks import PLATE_TOL, SENSOR_TOL_MM
    from ..errors import ConfigError

    rig = session.rig
    try:
        xy = np.stack([np.asarray(signal["sensor_x_mm"], float), np.asarray(signal["sensor_y_mm"], float)], 1)
        plate = np.array([float(signal["plate_x_mm"]), float(signal["plate_y_mm"])])
    except (KeyError, TypeError, ValueError):
        return
    same = (xy.shape == rig.sensor_xy_mm.shape and np.abs(xy - rig.sensor_xy_mm).max() <= SENSOR_TOL_MM
            and np.all(np.abs(plate - (rig.plate_x_mm, rig.plate_y_mm)) <= PLATE_TOL * plate))
    if not same:
        raise ConfigError(f"the board models in {path} were exported for another rig (sensors at "
                          f"{xy.round(1).tolist()} mm, plate {plate[0]:g} x {plate[1]:g} mm) than {session.path}'s "
                          f"(sensors at {rig.sensor_xy_mm.round(1).tolist()} mm): give --models DIR "
                          f"(`impactsense export` of a model trained on this rig) or --models none")

