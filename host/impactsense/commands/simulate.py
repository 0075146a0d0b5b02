"""impactsense simulate --x MM --y MM --height MM [--params P.json | --calibration CAL.json] --out FILE.npz"""

from __future__ import annotations

import json
import time

ORDER = 40


def register(sub) -> None:
    p = sub.add_parser("simulate", help="simulate one drop with the finite-element twin (raw ADC counts)",
                       description="One ball drop on the rig's plate, simulated by the C++ finite-element model; "
                                   "writes FILE.npz with adc uint16 [1, 4, samples], volts, contact force.")
    p.add_argument("--x", type=float, required=True, metavar="MM", help="impact x (mm)")
    p.add_argument("--y", type=float, required=True, metavar="MM", help="impact y (mm)")
    p.add_argument("--height", type=float, required=True, metavar="MM", help="release height (mm)")
    add_param_options(p)
    p.add_argument("--method", choices=("direct", "fast"), default="direct",
                   help="the direct solver's path: direct (default for one drop) or fast (reciprocity; pays 4 "
                        "solves up front)")
    add_solver_option(p)
    p.add_argument("--noise", action="store_true", help="add the ADC noise (noise_counts_rms)")
    p.add_argument("--seed", type=int, default=None, help="seed of the ADC noise (default: random)")
    p.add_argument("--out", required=True, metavar="FILE.npz", help="file to write")
    p.set_defaults(func=run)


def add_param_options(p) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--params", metavar="PARAMS.json", help="SimParams JSON (default: documented defaults)")
    g.add_argument("--calibration", metavar="CAL.json", help="calibration result; its 'sim_params' are used")
    p.add_argument("--rig", default=None, metavar="RIG",
                   help="rig.json or a session folder for the geometry (default: with --calibration the "
                        "session it was fitted on, else bundled session-1)")


def add_solver_option(p, batch: bool = False) -> None:
    """--solver; default: the parameters' `solver` (SimParams default "direct"); batches: "auto"."""
    said = ("default auto: modal when this plate's modes are already cached, else the parameters' solver"
            if batch else "default: the parameters' solver, direct unless they say modal")
    p.add_argument("--solver", choices=("direct", "modal", "auto") if batch else ("direct", "modal"),
                   default="auto" if batch else None,
                   help=f"direct: the explicit finite-element model (the reference); modal: superposition of the "
                        f"same model's modes (computed once per plate, minutes, and cached on disk: "
                        f"$IMPACTSENSE_MODAL_CACHE or ~/.cache/impactsense/modal); {said}")


def add_scheduler_option(p) -> None:
    """--scheduler ADDRESS: the batch's simulations on a Dask cluster (impactsense.sim.executor)."""
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run the batch's simulations on the Dask cluster whose scheduler is at ADDRESS (e.g. "
                        "tcp://host:8786; needs impactsense[cluster] here and on the workers; default: this "
                        "machine)")


def load_inputs(args):
    from pathlib import Path

    from ..data import load_rig, resolve_session_path
    from ..sim import SimParams

    rig_arg = args.rig
    if rig_arg is None and args.calibration:    # the rig the calibration was fitted on
        from ..zeroshot import read_calibration
        rig_arg = str(read_calibration(Path(args.calibration)).get("data") or "bundled")
    rig_arg = rig_arg or "bundled"
    rig_path = Path(rig_arg) if rig_arg.endswith(".json") else resolve_session_path(rig_arg)
    rig = load_rig(rig_path)
    if args.calibration:
        params = SimParams.from_json(args.calibration)  # a calibration file: its 'sim_params'
    elif args.params:
        params = SimParams.from_json(args.params)
    else:
        params = SimParams.from_rig(rig)
    return params, rig


def run(args) -> int:
    import numpy as np

    from ..sim import simulate_voltages, to_adc

    params, rig = load_inputs(args)
    t0 = time.perf_counter()
    res = simulate_voltages(params, rig, [args.x], [args.y], [args.height], method=args.method,
                            solver=args.solver, workers=2)
    adc = to_adc(res["volts"], params, rig, noise=args.noise, seed=args.seed)
    elapsed = time.perf_counter() - t0
    model = res["model"]
    from ..outputs import atomic_file

    with atomic_file(args.out) as fh:
        np.savez_compressed(fh, adc=adc, volts=res["volts"].astype(np.float32),
                            force_n=res["force_n"][0].astype(np.float32), dt_s=model.dt_s,
                            x_mm=args.x, y_mm=args.y, height_mm=args.height,
                            sim_params=json.dumps(params.to_dict()), model=json.dumps(model.describe()))
    desc = model.describe()
    solver = args.solver or params.solver
    how = f"method {args.method}" if solver == "direct" else "modal solver"
    print(f"mesh {desc['nx']} x {desc['ny']} ({desc['element_mm'][0]:.2f} mm), dt {desc['dt_us']:.3f} us, "
          f"{how}, {elapsed:.2f} s")
    f = res["force_n"][0]
    print(f"contact {res['contact_s'][0] * 1e6:.1f} us, touches {res['contacts'][0]}, peak force {f.max():.1f} N")
    peak = np.abs(adc[0].astype(int) - rig.bias_counts).max(axis=1)
    print("sensor  peak_counts")
    for c, s in enumerate(rig.sensors):
        print(f"{s.name:6s}  {peak[c]:11d}")
    print(f"wrote {args.out}")
    return 0
