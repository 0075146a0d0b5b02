"""`--solver auto` for a batch of virtual drops: `solver_cost`'s estimates of both solvers against a few drops
timed with each, and the batch size where the choice turns (the crossover), estimated and measured.

For each plate (a `synthetic_rig.py` kind's truth, capped as calibrate caps it; `--coarsen F`: the element F x
larger: F^2 fewer dofs, the same band's modes, so a cold modal basis costs ~F^2 less and can be timed on a
loaded machine; a direct drop costs less too, so the crossover is not the full mesh's): the direct path's four
reciprocal runs and `--drops` drops of `simulate-dataset`'s virtual set (fast path, one worker), then the cold
modal basis (a fresh cache folder; with the fixed part of a modal call) and the same drops by the modal solver
(one drop, then all: a call's fixed part apart). The crossover is the batch size where
basis + N modal drops = runs + N direct drops. CPU seconds are this process's user + system time (all its
threads, and the basis's worker processes once ended), so the machine's load does not inflate them.

    python3 benchmarks/bench_batch_solver.py --kind brass-trapezoid --kind cfrp-ud-strip [--coarsen 2] [--drops 16]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from bench_sitemap_cost import kind_inputs  # noqa: E402


def cpu_s() -> float:
    """User + system CPU seconds of this process and of its ended children (the modal basis's slices run in
    worker processes)."""
    import resource

    return sum(r.ru_utime + r.ru_stime for r in (resource.getrusage(resource.RUSAGE_SELF),
                                                 resource.getrusage(resource.RUSAGE_CHILDREN)))


def crossover(basis: float, runs: float, direct_drop: float, modal_drop: float) -> float:
    return (basis - runs) / (direct_drop - modal_drop) if direct_drop > modal_drop else float("inf")


def measure(kind: str, coarsen: float, n_drops: int, batch: int = 2000) -> dict:
    from impactsense.sim import simulate_voltages, solver_cost
    from impactsense.sim.doe import virtual_drops
    from impactsense.sim.model import mesh_size
    from impactsense.sim.modal_basis import load_or_compute
    from impactsense.sim.simulate import clear_cache, get_model, reciprocal_fields

    params, rig = kind_inputs(kind)
    if coarsen != 1:
        _, _, _, hx, hy = mesh_size(params, rig)
        params = params.replace(element_mm=float(coarsen * max(hx, hy) * 1e3))
    clear_cache()
    model = get_model(params, rig)
    x, y, h = virtual_drops(rig, batch, 0)
    rows = solver_cost.pilot_rows(batch)
    window = solver_cost.measured_contact_windows(model, x[rows], y[rows], h[rows])
    est_direct = solver_cost.direct_parts(model, 1, window)
    modes_est = solver_cost.basis_modes(model)
    est_basis = solver_cost.modal_cpu_s(model, 0, cached=False)
    est_modal_drop = solver_cost.modal_cpu_s(model, 1, cached=True) - solver_cost.modal_cpu_s(model, 0, cached=True)

    c0 = cpu_s()
    reciprocal_fields(model, workers=1)
    runs = cpu_s() - c0
    xs, ys, hs = x[:n_drops], y[:n_drops], h[:n_drops]
    c0 = cpu_s()
    simulate_voltages(params, rig, xs, ys, hs, solver="direct", method="fast", workers=1, scheduler="")
    direct_drop = (cpu_s() - c0) / n_drops
    c0 = cpu_s()
    model._basis = load_or_compute(model)        # cold: the cache folder is fresh
    basis = cpu_s() - c0
    c0 = cpu_s()
    simulate_voltages(params, rig, xs[:1], ys[:1], hs[:1], solver="modal", workers=1, scheduler="")
    one = cpu_s() - c0
    c0 = cpu_s()
    simulate_voltages(params, rig, xs, ys, hs, solver="modal", workers=1, scheduler="")
    modal_drop = (cpu_s() - c0 - one) / max(n_drops - 1, 1)   # a call's fixed part (~0.6 s) apart
    basis += one - modal_drop
    return dict(kind=kind, coarsen=coarsen, elements=model.elements, dofs=3 * model.nodes,
                modes_est=modes_est, modes=model._basis.modes, window_steps=window["steps"],
                est_runs=est_direct["runs_cpu_s"], runs=runs, est_direct_drop=est_direct["drop_cpu_s"],
                direct_drop=direct_drop, est_basis=est_basis, basis=basis, est_modal_drop=est_modal_drop,
                modal_drop=modal_drop,
                est_crossover=crossover(est_basis, est_direct["runs_cpu_s"], est_direct["drop_cpu_s"], est_modal_drop),
                crossover=crossover(basis, runs, direct_drop, modal_drop))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kind", action="append", default=[], help="a synthetic_rig.py kind (repeatable)")
    ap.add_argument("--coarsen", type=float, default=1.0, help="element size x this (default 1: calibrate's mesh)")
    ap.add_argument("--drops", type=int, default=16, help="drops timed per solver (default 16)")
    a = ap.parse_args(argv)
    os.environ["IMPACTSENSE_MODAL_CACHE"] = tempfile.mkdtemp(prefix="bench-batch-solver-")
    print(f"{'plate':16s} {'elem':>6s} {'modes est/found':>15s} {'window':>6s} | {'runs s est/meas':>15s} | "
          f"{'direct ms est/meas':>18s} | {'basis s est/meas':>16s} | {'modal ms est/meas':>17s} | "
          f"{'crossover est/meas':>18s}")
    for kind in a.kind:
        r = measure(kind, a.coarsen, a.drops)
        print(f"{r['kind']:16s} {r['elements']:6d} {r['modes_est']:7d}/{r['modes']:7d} {r['window_steps']:6.0f} | "
              f"{r['est_runs']:7.1f}/{r['runs']:7.1f} | {1e3 * r['est_direct_drop']:8.1f}/{1e3 * r['direct_drop']:8.1f} | "
              f"{r['est_basis']:7.0f}/{r['basis']:7.0f}  | {1e3 * r['est_modal_drop']:8.2f}/{1e3 * r['modal_drop']:8.2f} | "
              f"{r['est_crossover']:8.0f}/{r['crossover']:8.0f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
