"""The site map's CPU cost: `sitemap.site_map_cost`'s estimate against a few drops timed through the map's own path.

For each plate: the twin's model (Eq. 1's mesh, capped as calibrate caps it), its build, the four reciprocal runs,
then `--drops` grid points of the map's plan (spread over the plate) simulated one at a time (`--workers 1`) and
turned into the map's features as `build_site_map` does. The measured full-map cost is setup + runs + drops x the
per-drop CPU; printed beside the estimate, part by part. CPU seconds are this process's user + system time (all
its threads), so the machine's load does not inflate them.

    python3 benchmarks/bench_sitemap_cost.py --kind alu-large-thin --kind fr4-scope [--data DIR] \
        [--calibration CAL.json] [--drops 8] [--every 1]

--kind: a `synthetic_rig.py` kind (its truth's material, no session needed); --data: a session folder (the rig's
materials-table prior, or --calibration's twin when given once for that folder: NAME=CAL.json pairs with
--calibration-for).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def kind_inputs(kind: str):
    from synthetic_rig import KINDS

    from impactsense.calibration.options import CalibrateOptions
    from impactsense.sim.model import mesh_size
    from impactsense.data import rig_from_dict
    from impactsense.sim import SimParams

    MAX_ELEMENTS = CalibrateOptions().max_elements
    spec = KINDS[kind]
    sim = dict(spec["sim"])
    rig = rig_from_dict(dict(spec["rig"], density_kg_m3=sim.pop("density_kg_m3", spec["rig"].get("density_kg_m3"))))
    params = SimParams.from_rig(rig).replace(max_height_mm=float(max(spec["heights"])), **sim)
    _, nx, ny, _, _ = mesh_size(params, rig)
    if nx * ny > MAX_ELEMENTS:   # calibrate's cap (calibration.fem.capped_mesh)
        params = params.replace(element_mm=float(np.ceil(100 * np.sqrt(rig.plate_x_mm * rig.plate_y_mm / MAX_ELEMENTS)) / 100))
    return params, rig


def data_inputs(folder: str, calibration: str | None):
    from impactsense.data import load_rig, resolve_session_path
    from impactsense.sim import SimParams

    rig = load_rig(resolve_session_path(folder))
    params = SimParams.from_json(calibration) if calibration else SimParams.from_rig(rig)
    return params, rig


def measure(name: str, params, rig, n_drops: int, every: int, ref_height_mm: float = 175.0) -> dict:
    from impactsense.pipeline import featurize
    from impactsense.signal import SignalConfig
    from impactsense.sim import simulate_voltages, to_adc
    from impactsense.sim.modal_basis import is_cached
    from impactsense.sim.simulate import clear_cache, get_model, reciprocal_fields
    from impactsense.sim.solver_cost import cone_element_steps, direct_parts
    from impactsense.sitemap import plan, site_map_cost, twin_features

    clear_cache()
    c0, w0 = cpu_s(), time.perf_counter()
    model = get_model(params, rig)
    setup = cpu_s() - c0
    c0 = cpu_s()
    reciprocal_fields(model, workers=1)
    runs = cpu_s() - c0
    (x0, y0, nx, ny), _, sim = plan(rig, 5.0, 10.0, every)
    todo = np.flatnonzero(sim)
    pick = np.sort(np.random.default_rng(1).choice(todo, min(n_drops, todo.size), replace=False))   # not the pilot's
    i, j = np.divmod(pick, ny)
    x, y = x0 + 5.0 * i, y0 + 5.0 * j
    sig = SignalConfig.for_rig(rig)
    sig.adc_min, sig.adc_max, sig.sample_offset = -32768, 32767, 0
    c0 = cpu_s()
    res = simulate_voltages(params, rig, x, y, np.full(x.size, ref_height_mm), workers=1, solver="direct",
                            scheduler="")
    drop = (cpu_s() - c0) / x.size
    c0 = cpu_s()
    twin_features(featurize(to_adc(res["volts"], params, rig, clip=False), sig))
    feat = (cpu_s() - c0) / x.size
    cost = site_map_cost(params, rig, every=every, ref_height_mm=ref_height_mm, _model=(model, is_cached(model)))
    est = direct_parts(model, cost["simulated"], cost["window"])
    steps = [len(f) for f in res["force_n"]]
    steps_meas = float(np.mean(steps))
    cone = float(np.mean([cone_element_steps(model, a * 1e-3, b * 1e-3, k) for a, b, k in zip(x, y, steps)]))
    record_steps = len(model.sensors) * model.n_record * model.record_every * model.elements
    measured = setup + runs + cost["simulated"] * (drop + feat)   # the direct path's, whichever `auto` chose
    out = dict(name=name, elements=model.elements, nodes=model.nodes, dt_us=model.dt_s * 1e6,
               n_record=model.n_record, record_every=model.record_every, drops=cost["simulated"],
               est_runs=est["runs_cpu_s"], meas_runs=runs, est_drop=est["drop_cpu_s"], meas_drop=drop,
               meas_feat=feat, meas_setup=setup,
               est_steps=cost["window_steps"],
               meas_steps=steps_meas, estimate=est["cpu_s"], solver=cost["solver"], chosen=cost["cpu_s"],
               measured=measured, c_drop=drop / cone, c_runs=runs / record_steps,
               wall_s=time.perf_counter() - w0)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kind", action="append", default=[], help="a synthetic_rig.py kind (repeatable)")
    ap.add_argument("--data", action="append", default=[], help="[NAME=]a session folder (repeatable)")
    ap.add_argument("--calibration", action="append", default=[],
                    help="CAL.json for the --data folder of the same position (repeatable)")
    ap.add_argument("--drops", type=int, default=8, help="drops timed per plate (default 8)")
    ap.add_argument("--every", type=int, default=1, help="the map's plan (default 1: every point)")
    a = ap.parse_args(argv)
    inputs = [(k, *kind_inputs(k)) for k in a.kind]
    cals = a.calibration + [None] * (len(a.data) - len(a.calibration))
    for d, c in zip(a.data, cals):
        name, _, folder = d.rpartition("=")
        inputs.append((name or Path(folder).name, *data_inputs(folder, c)))
    head = (f"{'plate':16s} {'elem':>6s} {'dt us':>6s} {'rec':>5s} {'drops':>6s} | {'runs est/meas':>13s} | "
            f"{'drop ms est/meas (+feat)':>25s} | {'window steps pilot/timed':>25s} | "
            f"{'direct map CPU-s est/meas':>25s} {'meas/est':>8s}")
    print(head)
    for name, params, rig in inputs:
        r = measure(name, params, rig, a.drops, a.every)
        print(f"{r['name']:16s} {r['elements']:6d} {r['dt_us']:6.3f} {r['n_record']:5d} {r['drops']:6d} | "
              f"{r['est_runs']:6.1f}/{r['meas_runs']:6.1f} | {1e3 * r['est_drop']:7.1f}/{1e3 * r['meas_drop']:7.1f} "
              f"(+{1e3 * r['meas_feat']:5.1f}) | {r['est_steps']:8.0f}/{r['meas_steps']:8.0f}        | "
              f"      {r['estimate']:7.0f}/{r['measured']:7.0f} {r['measured'] / r['estimate']:8.2f}   "
              f"ns/element-step drop {1e9 * r['c_drop']:.2f} runs {1e9 * r['c_runs']:.2f} "
              f"(auto: {r['solver']} {r['chosen']:.0f} CPU-s; setup {r['meas_setup']:.1f} s, wall {r['wall_s']:.0f} s)",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
