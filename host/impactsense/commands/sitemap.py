"""impactsense sitemap [--calibration CAL.json | --params P.json] --out site-map.npz [--step-mm 5]"""

from __future__ import annotations

import time

ORDER = 42


def register(sub) -> None:
    from .simulate import add_param_options, add_scheduler_option, add_solver_option

    p = sub.add_parser("sitemap", help="the twin's site map: a simulated drop at every grid point",
                       description="Simulates a drop from --height-mm at every point of a regular grid over the "
                                   "plate (off the sensor discs) with the calibrated twin and keeps the core's "
                                   "16 twin features per point (uint8, the board's table). `impactsense train "
                                   "--site-map` and `export` use it for the energy class.")
    add_param_options(p)
    p.add_argument("--out", required=True, metavar="site-map.npz", help="site map file to write")
    p.add_argument("--step-mm", type=float, default=5.0, help="grid step (default 5 mm)")
    p.add_argument("--margin-mm", type=float, default=10.0, help="first grid line from the edges (default 10)")
    p.add_argument("--height-mm", type=float, default=175.0, help="reference drop height (default 175)")
    p.add_argument("--every", type=int, default=1, metavar="K",
                   help="simulate every K-th grid line (and the points within 40 mm of an edge), interpolate the "
                        "rest: ~K^2 fewer drops, a coarser map (default 1: every point)")
    p.add_argument("--edge-band-mm", type=float, default=None, metavar="MM",
                   help="with --every K > 1: also simulate every point within MM of an edge (default 40)")
    p.add_argument("--workers", type=int, default=2, help="parallel processes (default 2)")
    add_solver_option(p, batch=True)
    add_scheduler_option(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..signal import SignalConfig
    from ..sitemap import build_site_map
    from .simulate import load_inputs

    params, rig = load_inputs(args)
    from ..errors import ConfigError
    from ..sitemap import EDGE_BAND_MM, map_solver, plan

    band = EDGE_BAND_MM if args.edge_band_mm is None else args.edge_band_mm
    if band < 0:
        raise ConfigError(f"--edge-band-mm must be >= 0, got {band:g}")
    args.solver = map_solver(params, rig, args.solver,
                             int(plan(rig, args.step_mm, args.margin_mm, args.every, band)[2].sum()), args.height_mm)
    t0 = time.time()
    site = build_site_map(params, rig, SignalConfig.for_rig(rig), step_mm=args.step_mm, margin_mm=args.margin_mm,
                          ref_height_mm=args.height_mm, workers=args.workers, solver=args.solver,
                          every=args.every, edge_band_mm=band)
    site.source["calibration"] = args.calibration or args.params or "defaults"
    site.save(args.out)
    print(f"site map {site.nx} x {site.ny} points ({int(site.present.sum())} off the discs), step "
          f"{site.step_mm:g} mm, {site.q.nbytes / 1024:.0f} KB of table, in {time.time() - t0:.0f} s "
          f"({args.solver} solver) -> {args.out}")
    return 0
