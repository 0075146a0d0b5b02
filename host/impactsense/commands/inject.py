"""impactsense inject DATA --out DIR [--hum 40 --hum-hz 50 --offset 8 --glitch 0.1 --drift 0.02 --noise 2
--dead-channel K | --debond K] [--rows all|test] [--seed 0]: a session folder with lab faults put in."""

from __future__ import annotations

ORDER = 55


def add_fault_options(p) -> None:
    """The fault options (FaultSpec's fields), shared with `emulate --inject`'s spelling."""
    g = p.add_argument_group("faults (impactsense.faults.FaultSpec)")
    g.add_argument("--hum", type=float, default=0.0, help="mains hum amplitude, counts (per channel 0.5..1 x)")
    g.add_argument("--hum-hz", type=float, default=50.0, help="mains frequency (default 50)")
    g.add_argument("--offset", type=float, default=0.0, help="sd of the per-record DC offsets, counts")
    g.add_argument("--glitch", type=float, default=0.0,
                   help="fraction of records with a 1-2 sample spike of 200..2000 counts")
    g.add_argument("--drift", type=float, default=0.0, help="gain drift over the session (0.02 = +-2 %%)")
    g.add_argument("--noise", type=float, default=0.0, help="white noise sd, counts")
    g.add_argument("--dead-channel", type=int, default=-1, metavar="K", help="channel K carries no signal")
    g.add_argument("--debond", type=int, default=-1, metavar="K",
                   help="channel K reads x0.4 through a first-order 3..5 kHz low-pass")
    g.add_argument("--debond-hz", type=float, default=0.0, help="the debond's cut-off (default drawn in 3..5 kHz)")
    g.add_argument("--seed", type=int, default=0, help="fault draw seed (default 0)")


def spec_from_args(args):
    from ..faults import FaultSpec, validate

    return validate(FaultSpec(hum=args.hum, hum_hz=args.hum_hz, offset=args.offset, glitch=args.glitch,
                              drift=args.drift, noise=args.noise, dead_channel=args.dead_channel,
                              debond=args.debond, debond_hz=args.debond_hz, seed=args.seed))


def register(sub) -> None:
    p = sub.add_parser("inject", help="put lab faults (hum, offsets, glitches, drift, a dead or debonded "
                                      "channel) into a session's recordings", description=__doc__)
    p.add_argument("data", help="session folder (or 'bundled')")
    p.add_argument("--out", required=True, help="session folder to write (never the input)")
    p.add_argument("--rows", default="all", metavar="all|test|MODEL_DIR",
                   help="all drops, the held-out split of `train`'s defaults (test: 20 %% of cases, seed 0), "
                        "or a model folder's held-out drops")
    add_fault_options(p)
    p.set_defaults(func=run)


def select_rows(session, rows: str):
    import numpy as np

    from ..split import case_split

    if rows == "all":
        return np.arange(len(session))
    if rows == "test":
        return case_split(session.case_id, 0.2, 0)[1]
    from ..models import ImpactModel

    return np.asarray(ImpactModel.load(rows).card.get("split", {}).get("test_recordings", []), int)


def run(args) -> int:
    from pathlib import Path

    from ..data import load_session, write_session
    from ..errors import ConfigError
    from ..faults import inject_session

    spec = spec_from_args(args)
    session = load_session(args.data)
    out = Path(args.out)
    if out.resolve() == Path(session.path).resolve():
        raise ConfigError("--out must not be the input session folder")
    if out.exists() and any(out.iterdir()) and not (out / "rig.json").is_file():
        raise ConfigError(f"--out {out}: exists and is not a session folder; choose another")
    rows = select_rows(session, args.rows)
    if len(rows) == 0:
        raise ConfigError(f"--rows {args.rows}: no drops selected")
    faulty = inject_session(session.subset(rows), spec)
    raw = dict(session.rig.raw)
    raw["notes"] = (raw.get("notes", "") + f" Faults injected by impactsense inject ({spec.describe() or 'none'}) "
                    f"into {len(rows)} drops of {session.name}.").strip()
    write_session(out, raw, faulty.x_mm, faulty.y_mm, faulty.height_mm, faulty.adc,
                  case_id=faulty.case_id, repetition=faulty.repetition)
    print(f"wrote {out}: {len(rows)} drops of {session.name} with {spec.describe() or 'no faults'}")
    return 0
