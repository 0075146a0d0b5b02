"""impactsense simulate-dataset --n 490 [--params P.json | --calibration CAL.json] --out DIR"""

from __future__ import annotations

import json
import time

ORDER = 41


def register(sub) -> None:
    from .simulate import add_param_options, add_scheduler_option, add_solver_option

    p = sub.add_parser("simulate-dataset", help="simulate a virtual session (Sobol positions and heights)",
                       description="Simulates N drops at Sobol positions away from the sensors and heights in 5 mm "
                                   "steps over the calibrated session's range (--calibration; else 100..200 mm, like "
                                   "the bundled lab's DoE) and writes a session folder "
                                   "(rig.json, impacts.csv, recordings.npz) every session tool reads.")
    p.add_argument("--n", type=int, default=490, help="number of drops (default 490)")
    add_param_options(p)
    p.add_argument("--out", required=True, metavar="DIR", help="session folder to write")
    p.add_argument("--force", action="store_true", help="write into a folder that holds other files (kept)")
    p.add_argument("--seed", type=int, default=0, help="Sobol scramble and noise seed")
    p.add_argument("--no-noise", dest="noise", action="store_false", help="noise-free counts")
    p.add_argument("--method", choices=("fast", "direct"), default="fast",
                   help="the direct solver's path: fast (default: reciprocity, 4 solves up front, then cheap per "
                        "drop) or direct (one full run a drop)")
    add_solver_option(p, batch=True)
    add_scheduler_option(p)
    p.add_argument("--no-site-map", dest="site_map", action="store_false",
                   help="with --calibration: do not make the twin's site map (`train --site-map auto` on the folder "
                        "makes it then); by default it is made here, its drops beside the virtual ones")
    p.add_argument("--site-map-cpu-s", type=float, default=None, metavar="S",
                   help="the site map's budget in estimated CPU seconds (default 600, sitemap.SITE_MAP_CPU_S): over it, every 2nd "
                        "(3rd, 4th) grid line and a band along the edges are simulated and the rest interpolated, "
                        "a coarser map (printed); 0 = every grid point whatever it costs")
    p.add_argument("--workers", type=int, default=2, help="parallel processes (default 2)")
    p.add_argument("--edge-mm", type=float, default=20.0, help="keep impacts this far from the edges")
    p.add_argument("--sensor-clearance-mm", type=float, default=25.0,
                   help="keep impacts this far from sensor centres")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from ..data import write_session
    from ..errors import ConfigError
    from ..sim import simulate_voltages, to_adc
    from ..sim.doe import DEFAULT_HEIGHTS_MM, virtual_drops
    from .simulate import load_inputs

    if args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers}")
    from ..outputs import check_output_folder

    check_output_folder(args.out, args.force)
    params, rig = load_inputs(args)
    heights = DEFAULT_HEIGHTS_MM
    if args.calibration:   # the calibrated session's height range (its drops' class boundary and spread)
        heights = calibrated_heights(args.calibration, heights)
    x, y, h = virtual_drops(rig, args.n, args.seed, args.edge_mm, args.sensor_clearance_mm, heights_mm=heights)
    from ..sim.simulate import batch_solver

    args.solver = batch_solver(params, rig, args.solver, x, y, h)
    t0 = time.perf_counter()
    res = simulate_voltages(params, rig, x, y, h, method=args.method, solver=args.solver, workers=args.workers,
                            progress=True)
    site_map = start_site_map(args) if args.calibration and args.site_map else None
    how = f"{args.method} path" if (args.solver or params.solver) == "direct" else "modal solver"
    adc = to_adc(res["volts"], params, rig, noise=args.noise, seed=args.seed)
    elapsed = time.perf_counter() - t0
    raw = dict(rig.to_dict())
    raw["notes"] = (f"SIMULATED by impactsense simulate-dataset ({how}, seed {args.seed}); "
                    "parameters in sim_params.json. " + str(raw.get("notes", "")))
    summary = {"drops": int(args.n), "seconds": round(elapsed, 2), "method": args.method, "solver": args.solver or params.solver,
               "model": res["model"].describe(), "sim_params": params.to_dict(),
               "second_touches": int(np.sum(res["contacts"] > 1)),
               "contact_us_median": float(np.median(res["contact_s"]) * 1e6)}
    extra = {"sim_params.json": json.dumps(summary, indent=1)}
    if args.calibration:   # train on this folder then fits the calibration drops' rig effects (chain.py)
        from ..chain import CALIBRATION_FILE, calibration_record

        extra[CALIBRATION_FILE] = calibration_record(args.calibration)
    out = write_session(args.out, raw, x, y, h, adc, force=args.force, extra_files=extra)
    peak = np.abs(adc.astype(int) - rig.bias_counts).max(axis=2)
    clipped = np.mean((adc == 0) | (adc == rig.adc_max), axis=2).max(axis=0) > 0
    print(f"{args.n} drops in {elapsed:.1f} s ({how}); mesh {summary['model']['nx']} x "
          f"{summary['model']['ny']}, dt {summary['model']['dt_us']:.3f} us")
    print("sensor  peak_median  peak_max  clipped")
    for c, s in enumerate(rig.sensors):
        print(f"{s.name:6s}  {np.median(peak[:, c]):11.0f}  {peak[:, c].max():8d}  {str(bool(clipped[c])):>7s}")
    print(f"wrote {out} (summary in {out / 'sim_params.json'})")
    if site_map is not None:
        site_map()
    return 0


def start_site_map(args):
    """The calibrated twin's site map, which `train --site-map auto` on the folder uses (chain.site_map: the
    measured session's rig, CAL.json's twin), started in a thread once the virtual drops are simulated: its
    drops reuse their model (and the reciprocal fields) and keep both cores busy while the virtual drops are
    converted and written. Returns a callable that waits for it and caches it in the folder; None when no map
    is needed (the twin's map is cached already, e.g. the bundled twin's) or the measured session is unreadable
    (train reports that)."""
    from pathlib import Path

    from ..chain import measured_session
    from ..errors import DataError
    from ..sim import SimParams
    from ..sim.executor import in_background
    from ..zeroshot import build_twin_site_map, cached_twin_site_map, twin_site_map

    try:
        session, _ = measured_session(Path(args.calibration))
    except DataError:
        return None
    params = SimParams.from_json(args.calibration)
    if cached_twin_site_map(params, Path(args.out)) is not None:
        return None
    from ..sitemap import SITE_MAP_CPU_S

    budget = SITE_MAP_CPU_S if args.site_map_cpu_s is None else args.site_map_cpu_s
    built = in_background(lambda: build_twin_site_map(params, session, progress=False, cpu_budget_s=budget),
                          "site-map")

    def finish():
        from ..sitemap import describe_cost, every_for_budget

        cost = every_for_budget(params, session.rig, budget)
        print(f"finishing the twin's site map for `train --site-map auto` (simulated in the background since the "
              f"virtual drops: {describe_cost(cost)}; --no-site-map skips it) ...", flush=True)
        site = twin_site_map(params, session, Path(args.out), built=built())
        print(f"the twin's site map: {site.nx} x {site.ny} points, step {site.step_mm:g} mm (for train --site-map "
              "auto)")
    return finish


def calibrated_heights(cal_path, default):
    """The height range (mm) of the session a calibration was fitted on (sim.doe.measured_heights); `default`
    when that session cannot be read."""
    from pathlib import Path

    from ..data import load_session
    from ..errors import DataError
    from ..sim.doe import measured_heights
    from ..zeroshot import read_calibration

    data = read_calibration(Path(cal_path)).get("data")
    if not data:
        return default
    try:
        return measured_heights(load_session(data))
    except DataError:
        return default
