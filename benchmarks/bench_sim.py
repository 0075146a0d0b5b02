"""Benchmarks of the finite-element twin (issue 3). Prints the figures and exits 1 when one misses issue 3's
target: a 5 ms drop at the ~1 mm mesh <= 2 s on one core (the thread's CPU time of the best run: the machine
may be shared; the wall time is printed beside it), >= 20x faster than the assembled sparse explicit FE, the
490-drop data set <= 60 s on 2 cores (its wall time, or its CPU time over the 2 workers when the machine is
loaded).

    python benchmarks/bench_sim.py            # everything (several minutes)
    python benchmarks/bench_sim.py --quick    # 1 mm drop and the sparse comparison extrapolated from 1500 steps

1. One 5 ms drop at the seed's ~1 mm mesh (320 x 317 = 101,440 elements) on one core: best of --repeat
   runs (wall and the thread's CPU time: the machine may be shared), steps x elements, dt against the
   assembled stability limit, the element bound and Eq. 2, element-updates per second, flops per
   element-update (counted in sim/src/fused.h) against the core's peak (clock x 32 single-precision
   flops/cycle: two 256-bit FMA pipes), and the state streamed per step; the same with the opt-in
   disc_inertia_scaling (the discs no longer set the step).
2. The same mesh and step with an assembled sparse-matrix explicit FE: scikit-fem assembly (Q1 w, beta_x,
   beta_y; bending 2x2 Gauss, shear 1-point = selective reduced integration), scipy.sparse K @ u per step.
3. The 490-drop virtual data set at the default mesh on 2 cores (fast path), and the peak memory.
4. --dtoa N: sub-cycling against the single-step scheme where it matters, DToA against session-1: N measured
   drops (the first of evenly spaced cases) simulated at their positions and heights (fast path, noise seeds
   1 and 2), picked by the signal core like the rig's; RMS of measured - simulated DToA (us, all six pairs)
   for the default mesh single-step (the default) and sub-cycled (forced), and the 1 mm mesh single-step and
   sub-cycled (its default); plus the disc voltages' RMS difference of the two schemes on each mesh.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time

import numpy as np

# sim/src/fused.h, per element and its node: edge sums/differences 12, bilinear coefficients 11, shear 17,
# bending 16, edge terms 10 and their accumulation 6, nodal force 9, central-difference update 12
FLOPS_PER_ELEMENT_UPDATE = 12 + 11 + 17 + 16 + 16 + 9 + 12
STATE_BYTES_PER_NODE = 3 * 4 + 3 * 2 * 4   # u (float32 x 3 fields) + d and beta (float32 x 3 fields x 2)


def core_peak_gflops() -> float:
    mhz = 0.0
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("cpu MHz"):
                mhz = max(mhz, float(line.split(":")[1]))
    except OSError:
        pass
    return mhz * 1e-3 * 32


def bench_drop_1mm(rig, quick: bool, repeat: int, **overrides):
    from impactsense.sim import SimParams
    from impactsense.sim.model import build_model, element_dt_crit, impact_velocity, plate_constants

    p = SimParams.from_rig(rig, element_mm=1.0, duration_ms=5.0, **overrides)
    t0 = time.perf_counter()
    m = build_model(p, rig)
    build_s = time.perf_counter() - t0
    t, d, s = plate_constants(p)
    q = m.hx_m * m.hy_m / 4
    dt_elem = element_dt_crit(m.hx_m, m.hy_m, d, p.nu, s, p.rho_kg_m3 * t * q, p.rho_kg_m3 * t ** 3 / 12 * q)
    v0 = float(impact_velocity(p, 150.0))
    n_total = m.n_record * m.record_every
    n_run = 1500 if quick else n_total
    walls, cpus = [], []
    for _ in range(max(1, repeat)):
        t0, c0 = time.perf_counter(), time.thread_time()   # the run holds this thread (GIL released)
        m.plate.run(dt_s=m.dt_s, n_steps=n_run, record_every=m.record_every, n_record=m.n_record,
                    ball=[0.16, 0.15, m.ball_mass_kg, m.k_hertz, v0, p.g_m_s2], sensors=m.sensors)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.thread_time() - c0)
    el = min(walls)
    rate = n_run * m.elements / el
    drop_s = el * n_total / n_run
    peak = core_peak_gflops()
    return dict(mesh=f"{m.nx} x {m.ny}", elements=m.elements, nodes=m.nodes, dt_us=m.dt_s * 1e6,
                subcycles=m.subcycles, subcycled_nodes=int(m.plate.subcycled_nodes) if m.subcycles > 1 else 0,
                dt_crit_us=m.dt_crit_s * 1e6, dt_element_bound_us=dt_elem * 1e6,
                dt_eq2_us=1e6 / (20 * m.f_max_hz), steps=n_total, build_seconds=build_s,
                drop_seconds=drop_s, drop_cpu_seconds=min(cpus) * n_total / n_run, runs=len(walls),
                drop_seconds_all=[w * n_total / n_run for w in walls], extrapolated=quick,
                element_updates_per_s=rate, flops_per_element_update=FLOPS_PER_ELEMENT_UPDATE,
                gflops=rate * FLOPS_PER_ELEMENT_UPDATE * 1e-9, core_peak_gflops=peak,
                state_mb_per_step=m.nodes * STATE_BYTES_PER_NODE / 1e6), m


def bench_sparse(m, quick: bool):
    """scikit-fem assembly of the same plate (same mesh, dt), scipy.sparse explicit loop."""
    import scipy.sparse as sp
    import skfem
    from skfem.helpers import dot

    p = m.params
    t = p.thickness_mm * 1e-3
    d = p.e_pa * t ** 3 / (12 * (1 - p.nu ** 2))
    s = p.shear_factor * p.e_pa / (2 * (1 + p.nu)) * t
    t0 = time.perf_counter()
    mesh = skfem.MeshQuad.init_tensor(np.linspace(0, m.lx_m, m.nx + 1), np.linspace(0, m.ly_m, m.ny + 1))
    e = skfem.ElementQuad1()
    basis = skfem.Basis(mesh, e, intorder=2)
    basis1 = skfem.Basis(mesh, e, intorder=1)

    @skfem.BilinearForm
    def lap_xx(u, v, w):
        return u.grad[0] * v.grad[0]

    @skfem.BilinearForm
    def lap_yy(u, v, w):
        return u.grad[1] * v.grad[1]

    @skfem.BilinearForm
    def lap_xy(u, v, w):
        return u.grad[0] * v.grad[1]

    @skfem.BilinearForm
    def mass(u, v, w):
        return u * v

    @skfem.BilinearForm
    def grad_x(u, v, w):
        return u.grad[0] * v

    @skfem.BilinearForm
    def grad_y(u, v, w):
        return u.grad[1] * v

    @skfem.BilinearForm
    def gradgrad(u, v, w):
        return dot(u.grad, v.grad)

    xx, yy, xy = (skfem.asm(f, basis) for f in (lap_xx, lap_yy, lap_xy))
    m1 = skfem.asm(mass, basis1)
    gx, gy = skfem.asm(grad_x, basis1), skfem.asm(grad_y, basis1)   # int N_i dN_j/dx (shear, 1-point)
    gg = skfem.asm(gradgrad, basis1)
    h = (1 - p.nu) / 2
    # dofs [w, bx, by]; bending: D [bx,x^2 + by,y^2 + 2 nu bx,x by,y + (1-nu)/2 (bx,y + by,x)^2]
    kbb = sp.bmat([[d * (xx + h * yy), d * (p.nu * xy + h * xy.T)],
                   [d * (p.nu * xy.T + h * xy), d * (yy + h * xx)]])
    # shear: S [(w,x + bx)^2 + (w,y + by)^2] with 1-point quadrature
    kww = s * gg
    kwb = sp.hstack([s * gx.T, s * gy.T])
    kbs = sp.bmat([[s * m1, None], [None, s * m1]])
    k = sp.bmat([[kww, kwb], [kwb.T, kbb + kbs]]).tocsr()
    t_asm = time.perf_counter() - t0
    n = k.shape[0]
    mass_w = np.asarray(skfem.asm(mass, basis).sum(axis=1)).ravel() * p.rho_kg_m3 * t
    mass_r = mass_w * t ** 2 / 12
    inv_m = 1 / np.concatenate([mass_w, mass_r, mass_r])
    u = np.zeros(n)
    v = np.zeros(n)
    u[n // 6] = 1e-6
    dt = m.dt_s
    cd = 0.5 * p.damping_per_s * dt
    n_total = m.n_record * m.record_every
    n_run = 300 if quick else 1500
    t0 = time.perf_counter()
    for _ in range(n_run):
        f = k @ u
        v = ((1 - cd) * v - dt * inv_m * f) / (1 + cd)
        u += dt * v
    el = time.perf_counter() - t0
    return dict(assembly_seconds=t_asm, nnz=int(k.nnz), dofs=int(n), steps_timed=n_run,
                drop_seconds_extrapolated=el * n_total / n_run, step_ms=el / n_run * 1e3)


def bench_dataset(rig, n: int, workers: int):
    from impactsense.sim.doe import virtual_drops
    from impactsense.sim import SimParams, simulate_voltages, to_adc
    from impactsense.sim.simulate import _CACHE

    _CACHE.clear()
    p = SimParams.from_rig(rig)
    x, y, h = virtual_drops(rig, n, 0)
    t0, c0 = time.perf_counter(), _cpu_s()
    res = simulate_voltages(p, rig, x, y, h, workers=workers, progress=False)
    adc = to_adc(res["volts"], p, rig, noise=True, seed=0)
    el, cpu = time.perf_counter() - t0, _cpu_s() - c0
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return dict(drops=n, workers=workers, seconds=el, cpu_seconds=cpu, mesh=res["model"].describe(),
                peak_rss_mb=peak_mb, adc_shape=list(adc.shape))


def _cpu_s() -> float:
    """CPU seconds of this process and its finished children."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def bench_dtoa(n: int, seeds=(1, 2)):
    import impactsense._core as core
    from impactsense.data import load_session
    from impactsense.sim import SimParams, simulate_voltages, to_adc
    from impactsense.sim.simulate import clear_cache

    s1 = load_session("bundled:session-1")
    _, first = np.unique(s1.case_id, return_index=True)
    rows = first[np.linspace(0, len(first) - 1, n).round().astype(int)]
    cfg = core.CoreConfig()
    meas = core.extract_batch(s1.adc[rows].astype(np.int16), cfg)["dtoa_us"]
    out = {}
    for mesh, em in (("default", None), ("1mm", 1.0)):
        volts = {}
        for scheme, over in (("single", dict(subcycle=False)), ("subcycled", dict(subcycle_max_element_mm=10.0))):
            p = SimParams.from_rig(s1.rig, element_mm=em, **over)
            t0 = time.perf_counter()
            res = simulate_voltages(p, s1.rig, s1.x_mm[rows], s1.y_mm[rows], s1.height_mm[rows], method="fast",
                                    progress=False)
            m = res["model"]
            volts[scheme] = res["volts"]
            rms = []
            for seed in seeds:
                sim = core.extract_batch(to_adc(res["volts"], p, s1.rig, noise=True, seed=seed).astype(np.int16),
                                         cfg)["dtoa_us"]
                ok = np.all(np.isfinite(meas), axis=1) & np.all(np.isfinite(sim), axis=1)
                rms.append(dict(seed=seed, drops=int(ok.sum()), rms_us=float(np.sqrt(np.mean((meas[ok] - sim[ok]) ** 2)))))
            out[f"{mesh}_{scheme}"] = dict(steps_per_sample=m.record_every, subcycles=m.subcycles,
                                           seconds=time.perf_counter() - t0, dtoa=rms)
            clear_cache()
        v0, v1 = volts["single"], volts["subcycled"]
        rel = np.sqrt(((v1 - v0) ** 2).mean(axis=2) / (v0 ** 2).mean(axis=2))
        out[f"{mesh}_volts_rel_rms"] = dict(median=float(np.median(rel)), max=float(rel.max()))
    return out


TARGETS = {"drop_1mm_s": 2.0, "speedup_vs_sparse": 20.0, "dataset_s": 60.0}   # issue 3


def target_misses(out: dict) -> list[str]:
    """Issue 3's targets on the figures this run measured (empty: met)."""
    miss = []
    if "drop_1mm" in out and out["drop_1mm"]["drop_cpu_seconds"] > TARGETS["drop_1mm_s"]:
        miss.append(f"1 mm drop {out['drop_1mm']['drop_cpu_seconds']:.2f} s CPU > {TARGETS['drop_1mm_s']} s")
    if "speedup_vs_sparse" in out and out["speedup_vs_sparse"] < TARGETS["speedup_vs_sparse"]:
        miss.append(f"{out['speedup_vs_sparse']:.1f}x the sparse FE < {TARGETS['speedup_vs_sparse']}x")
    if "dataset" in out and dataset_s(out["dataset"]) > TARGETS["dataset_s"]:
        miss.append(f"data set {dataset_s(out['dataset']):.1f} s > {TARGETS['dataset_s']} s")
    return miss


def dataset_s(ds: dict) -> float:
    """The data set's time on its cores: the wall time, or on a loaded machine the CPU time spread over the
    workers when that is less (what two free cores would take, at best)."""
    return min(ds["seconds"], ds["cpu_seconds"] / ds["workers"])


def verdict(out: dict) -> int:
    miss = target_misses(out)
    print(f"targets (issue 3): 1 mm drop <= {TARGETS['drop_1mm_s']} s CPU on one core, >= {TARGETS['speedup_vs_sparse']}x "
          f"the sparse FE, 490-drop data set <= {TARGETS['dataset_s']} s: " + ("met" if not miss else "MISSED: " + "; ".join(miss)))
    return 1 if miss else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeat", type=int, default=3, help="runs of the 1 mm drop; the best is reported")
    ap.add_argument("--n", type=int, default=490)
    ap.add_argument("--skip-dataset", action="store_true")
    ap.add_argument("--only-dataset", action="store_true")
    ap.add_argument("--json", default=None, help="also write the figures as JSON")
    ap.add_argument("--dtoa", type=int, default=0, metavar="N",
                    help="DToA vs session-1 over N drops, single-step vs sub-cycled (default mesh and 1 mm)")
    ap.add_argument("--only-dtoa", action="store_true")
    args = ap.parse_args(argv)
    from impactsense.data import bundled_session_path, load_rig

    rig = load_rig(bundled_session_path())
    out = {"load_average": os.getloadavg()}
    if args.dtoa or args.only_dtoa:
        dt = bench_dtoa(args.dtoa or 40)
        out["dtoa"] = dt
        print("DToA vs session-1 (measured - simulated, us RMS over the six pairs; fast path, noise seeds 1, 2):")
        for mesh in ("default", "1mm"):
            for scheme in ("single", "subcycled"):
                r = dt[f"{mesh}_{scheme}"]
                print(f"  {mesh:7s} mesh {scheme:9s} ({r['steps_per_sample']:2d} steps/sample, {r['subcycles']} sub-steps "
                      f"under the discs): " + ", ".join(f"seed {d['seed']} {d['rms_us']:.2f} us ({d['drops']} drops)"
                                                       for d in r["dtoa"]) + f"  [{r['seconds']:.0f} s]")
            v = dt[f"{mesh}_volts_rel_rms"]
            print(f"  {mesh:7s} mesh volts, sub-cycled vs single-step: median {100 * v['median']:.2f} %, "
                  f"max {100 * v['max']:.2f} % RMS")
        if args.only_dtoa:
            print(f"load average: {os.getloadavg()}")
            return 0
    if args.only_dataset:
        ds = bench_dataset(rig, args.n, 2)
        print(f"{ds['drops']}-drop data set, default mesh {ds['mesh']['nx']} x {ds['mesh']['ny']}: "
              f"{ds['seconds']:.1f} s wall ({ds['cpu_seconds']:.1f} s CPU) on 2 workers, peak memory {ds['peak_rss_mb']:.0f} MB; "
              f"load average {os.getloadavg()}")
        return verdict({"dataset": ds})
    drop, model = bench_drop_1mm(rig, args.quick, args.repeat)
    out["drop_1mm"] = drop
    print(f"1 mm mesh ({drop['mesh']} = {drop['elements']} elements), {drop['steps']} steps / 5 ms "
          f"= {drop['steps'] * drop['elements']:.3g} element-updates, one core:")
    print(f"  dt {drop['dt_us']:.4f} us = {drop['dt_us'] / drop['dt_crit_us']:.3f} x the assembled stability limit "
          f"{drop['dt_crit_us']:.4f} us of the plate outside the sub-cycled disc patches ({drop['subcycled_nodes']} "
          f"nodes, {drop['subcycles']} sub-steps; bare-plate element bound {drop['dt_element_bound_us']:.4f} us; Eq. 2 "
          f"allows {drop['dt_eq2_us']:.3f} us); model build {drop['build_seconds']:.2f} s")
    print(f"  drop time           {drop['drop_seconds']:8.2f} s wall, {drop['drop_cpu_seconds']:.2f} s CPU "
          f"(best of {drop['runs']}: {', '.join(f'{x:.2f}' for x in drop['drop_seconds_all'])} s)"
          f"{' (extrapolated)' if drop['extrapolated'] else ''}")
    print(f"  state per step      {drop['state_mb_per_step']:8.2f} MB (u, d, beta in float32)")
    one = bench_drop_1mm(rig, args.quick, args.repeat, subcycle=False)[0]
    out["drop_1mm_single_step"] = one
    print(f"  single-step (subcycle = false): dt {one['dt_us']:.4f} us = {one['dt_us'] / one['dt_crit_us']:.3f} x "
          f"the limit {one['dt_crit_us']:.4f} us set by the disc elements ({one['steps']} steps), drop "
          f"{one['drop_seconds']:.2f} s wall, {one['drop_cpu_seconds']:.2f} s CPU (best of {one['runs']})")
    opt = bench_drop_1mm(rig, args.quick, args.repeat, disc_inertia_scaling=True)[0]
    out["drop_1mm_disc_inertia_scaling"] = opt
    print(f"  opt-in disc_inertia_scaling: dt {opt['dt_us']:.4f} us ({opt['steps']} steps), drop "
          f"{opt['drop_seconds']:.2f} s wall, {opt['drop_cpu_seconds']:.2f} s CPU (best of {opt['runs']})")
    print(f"  element-updates/s   {drop['element_updates_per_s']:8.3g}")
    print(f"  flops/elem-update   {drop['flops_per_element_update']:8d}  -> {drop['gflops']:.1f} GFlop/s "
          f"= {100 * drop['gflops'] / max(drop['core_peak_gflops'], 1e-9):.1f} % of {drop['core_peak_gflops']:.0f} "
          f"GFlop/s single-precision peak")
    sparse = bench_sparse(model, args.quick)
    out["sparse"] = sparse
    ratio = sparse["drop_seconds_extrapolated"] / drop["drop_seconds"]
    out["speedup_vs_sparse"] = ratio
    print(f"scikit-fem assembly + scipy.sparse explicit, same mesh and dt ({sparse['dofs']} dofs, "
          f"{sparse['nnz']} nnz):")
    print(f"  assembly {sparse['assembly_seconds']:.2f} s, {sparse['step_ms']:.2f} ms/step, "
          f"drop {sparse['drop_seconds_extrapolated']:.1f} s (from {sparse['steps_timed']} steps)")
    print(f"  impactsim is {ratio:.1f}x faster")
    if not args.skip_dataset:
        ds = bench_dataset(rig, args.n, 2)
        out["dataset"] = ds
        print(f"{ds['drops']}-drop data set, default mesh {ds['mesh']['nx']} x {ds['mesh']['ny']} "
              f"({ds['mesh']['element_mm'][0]:.2f} mm), dt {ds['mesh']['dt_us']:.3f} us, 2 workers (fast path):")
        print(f"  {ds['seconds']:.1f} s wall, {ds['cpu_seconds']:.1f} s CPU, peak memory {ds['peak_rss_mb']:.0f} MB "
              "(process max RSS)")
    print(f"load average during the run: {out['load_average']}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return verdict(out)


if __name__ == "__main__":
    sys.exit(main())
