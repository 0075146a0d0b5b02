"""Other rigs (issue 15): the orthotropic twin against analytic frequencies, and the zero-shot chain per rig.

1. Frequencies: the lowest 10 modes of a simply supported 450 x 350 x 2.5 mm CFRP plate (E1 70, E2 20, G12 5
   GPa, nu12 0.3; fibres along x and at 30 deg is not analytic, so along x) on two meshes, against the
   Mindlin Navier solution and Kirchhoff's f_mn; target: max error <= 1 % on the coarse mesh.
2. Per rig (each DATA folder given, or the folders named in $IMPACTSENSE_RIGS, separated by ':'; a missing
   folder is skipped with the reason): the twin the rig's rig.json makes (material, mesh, stable step, one
   drop's time, its DToA against --twin-drops measured drops), and unless --no-chain the step-by-step zero-shot chain a user runs:
       impactsense calibrate DATA --out CAL.json
       impactsense simulate-dataset --calibration CAL.json --n 490 --out V
       impactsense train V --out M --test-fraction 0 [--site-map auto]
       impactsense evaluate DATA --model M --json E.json        (calibration drops excluded by the model)
   timed per step; targets: calibrate + virtual set + train <= 600 s, MAE <= 4.0 mm, class >= 0.95.

    python3 benchmarks/bench_anyrig.py [DATA ...] [--no-chain] [--work DIR] [--n 490]

Exits non-zero when a figure misses its target.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from benchlib import run_logged  # noqa: E402


def frequencies() -> bool:
    from test_sim_orthotropic import CFRP, ss_frequencies_fe
    from impactsense.sim import SimParams, dispersion, material

    p = SimParams(support="simply_supported", **CFRP)
    f_m, f_k, modes = dispersion.ss_orthotropic_frequencies(0.45, 0.35, material.bending_matrix(p),
                                                             material.shear_matrix(p), p.rho_kg_m3, 2.5e-3)
    ok = True
    for nx, ny in ((45, 35), (90, 70)):
        t0 = time.perf_counter()
        f_fe = ss_frequencies_fe(p, 0.45, 0.35, nx, ny)
        em, ek = np.abs(f_fe / f_m - 1), np.abs(f_fe / f_k - 1)
        print(f"SS CFRP plate, {nx} x {ny} elements ({450 / nx:.0f} mm): max |f_FE / f_Mindlin - 1| "
              f"{em.max() * 100:.3f} %, max |f_FE / f_Kirchhoff - 1| {ek.max() * 100:.3f} % "
              f"({time.perf_counter() - t0:.1f} s)")
        if nx == 45:
            ok &= bool(em.max() <= 0.01)
    print("  modes " + ", ".join(f"{m}{n}:{f:.1f} Hz" for (m, n), f in zip(modes, f_k)) + " (Kirchhoff)")
    return ok


def twin(data: Path, n_drops: int) -> None:
    """The twin rig.json makes (material from the materials table, no calibration): its mesh, one drop's
    time, and its DToA against the measured drops at the same positions (the core's picks on both; the
    rig's channel delays unknown, so the DToA's per-pair mean is removed: what remains is the twin's
    position-dependent error, i.e. its wave speeds and their direction-dependence)."""
    from impactsense.data import load_session
    from impactsense.pipeline import SignalConfig, featurize
    from impactsense.sim import SimParams, simulate_drops
    from impactsense.sim.model import build_model

    session = load_session(data)
    rig = session.rig
    p = SimParams.from_rig(rig)
    t0 = time.perf_counter()
    m = build_model(p, rig)
    t_build = time.perf_counter() - t0
    mat = {k: getattr(p, k) for k in ("e_pa", "nu", "e2_pa", "g12_pa", "material_axes_deg")}
    d = m.describe()
    print(f"{data.name}: {mat}; mesh {d['nx']} x {d['ny']} ({d['element_mm'][0]:.2f} mm), dt {d['dt_us']:.3f} us "
          f"(limit {d['dt_crit_us']:.3f}), f_max {d['f_max_hz'] / 1e3:.1f} kHz; built in {t_build:.1f} s")
    rng = np.random.default_rng(0)
    rows = rng.choice(len(session), n_drops, replace=False)
    t0 = time.perf_counter()
    adc = simulate_drops(p, rig, session.x_mm[rows], session.y_mm[rows], session.height_mm[rows], progress=False)
    t_sim = time.perf_counter() - t0
    cfg = SignalConfig.for_rig(rig)
    meas, sim = featurize(session.adc[rows], cfg), featurize(adc, cfg)
    pairs = [(i, j) for i in range(4) for j in range(i + 1, 4)]
    dm = np.stack([meas.toa_us[:, i] - meas.toa_us[:, j] for i, j in pairs], 1)
    ds = np.stack([sim.toa_us[:, i] - sim.toa_us[:, j] for i, j in pairs], 1)
    ok = meas.usable & sim.usable
    err = (ds - dm)[ok]
    err -= np.median(err, axis=0)
    print(f"  {n_drops} drops simulated in {t_sim:.1f} s ({t_sim / n_drops:.2f} s each); twin - measured DToA "
          f"(per-pair median removed) rms {np.sqrt(np.mean(err ** 2)):.2f} us, median |.| "
          f"{np.median(np.abs(err)):.2f} us over {int(ok.sum())} drops")


def chain(data: Path, work: Path, n: int) -> bool:
    exe = str(Path(sys.executable).with_name("impactsense"))
    w = work / data.name
    w.mkdir(parents=True, exist_ok=True)
    log = w / "chain.log"
    cal, virt, model, ev = w / "CAL.json", w / "V", w / "M", w / "E.json"
    steps = {"calibrate": [exe, "calibrate", str(data), "--out", str(cal)],
             "simulate-dataset": [exe, "simulate-dataset", "--calibration", str(cal), "--n", str(n),
                                  "--out", str(virt)],
             "train": [exe, "train", str(virt), "--out", str(model), "--test-fraction", "0", "--site-map", "auto"]}
    times = {name: run_logged(cmd, log)[0] for name, cmd in steps.items()}  # wall seconds
    run_logged([exe, "evaluate", str(data), "--model", str(model), "--json", str(ev)], log)
    rep = json.loads(ev.read_text())
    total = sum(times.values())
    mae, cls = rep["all"]["mae_mm"], rep.get("energy_class_accuracy")
    print(f"{data.name} zero-shot: " + ", ".join(f"{k} {v:.0f} s" for k, v in times.items())
          + f" (total {total:.0f} s); n {rep['n']}, MAE {mae:.2f} mm, class {cls}")
    return total <= 600 and mae <= 4.0 and cls is not None and cls >= 0.95


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="*", type=Path)
    ap.add_argument("--no-chain", action="store_true")
    ap.add_argument("--work", type=Path, default=Path("bench-anyrig"))
    ap.add_argument("--n", type=int, default=490)
    ap.add_argument("--twin-drops", type=int, default=24, help="measured drops the uncalibrated twin redoes")
    a = ap.parse_args()
    ok = frequencies()
    rigs = a.data or [Path(s) for s in os.environ.get("IMPACTSENSE_RIGS", "").split(":") if s]
    if not rigs:
        print("no rig folders given (DATA or $IMPACTSENSE_RIGS): per-rig figures skipped")
    for d in rigs:
        if not (d / "rig.json").is_file():
            print(f"{d}: skipped (no rig.json there)")
            continue
        twin(d, a.twin_drops)
        if not a.no_chain:
            ok &= chain(d, a.work, a.n)
    scope = "frequencies only (no chain run)" if a.no_chain or not rigs else "frequencies and zero-shot chain"
    print(f"targets met: {scope}" if ok else f"a target was missed ({scope})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
