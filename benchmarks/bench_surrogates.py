"""Benchmark: the calibration's "surrogates" stage alone, on a design of FEM runs; prints its wall time (per
model family and output) and the test-R2 table (the seed's Table 5).

    python benchmarks/bench_surrogates.py --design DIR_OR_NPZ [--repeat 1]
    python benchmarks/bench_surrogates.py [--out DIR]

--design: a calibration's cached design (`CAL.stage2-design.npz`, or the folder of a CAL.json that holds one,
e.g. the output of `python benchmarks/bench_calibrate.py --out DIR`). Without it, the bundled session-1 is
calibrated first (the full `impactsense calibrate`, minutes) into --out (default: a temporary folder) and its
design is used. The stage is redone exactly as the pipeline does it: the first `budget - budget // 4` runs
(the Sobol design; the rest are infill and the confirming run), the 70/15/15 split of `split_indices`, each
family tuned by `surrogates.tune` with the pipeline's trials and seeds, for both outputs (the 16 log10
sensor energies and the 16 residual-energy ratios).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from impactsense.calibration import surrogates
from impactsense.calibration.pipeline import CalibrateOptions


def load_design(path: Path):
    """(unit-cube inputs, {output: [n, 16]}) of the design runs of a cached sub-problem-2 design."""
    if path.is_dir():
        found = sorted(path.glob("*stage2-design.npz"))
        if not found:
            raise SystemExit(f"{path}: no *stage2-design.npz (run benchmarks/bench_calibrate.py --out {path})")
        path = found[0]
    with np.load(path, allow_pickle=False) as z:
        energy, ratio, done, u = z["energy"], z["ratio"], z["done"], z["u"]
    n = len(done) - 1                   # the last row is the confirming run
    n_init = n - n // 4                 # calibration.design.run: budget - infill runs
    if not done[:n_init].all():
        raise SystemExit(f"{path} [done]: only {int(done[:n_init].sum())} of the {n_init} design runs are done")
    e = energy[:n_init].reshape(n_init, 16)
    e = np.where(np.isfinite(e) & (e > 0), e, 1.0)
    r = ratio[:n_init].reshape(n_init, 16)
    r = np.where(np.isfinite(r), r, 1.0)
    return u[:n_init], {"sensor_energies_log10": np.log10(e), "residual_ratios": r}, path


def run_stage(x, outputs, trials: int, seed: int):
    """The pipeline's surrogate stage: {output: {family: Fitted}} and {output: {family: seconds}}."""
    tr, va, te = surrogates.split_indices(len(x), seed)
    fits, secs = {}, {}
    for oname, y in outputs.items():
        fits[oname], secs[oname] = {}, {}
        for m_i, kind in enumerate(surrogates.MODELS):
            t0 = time.perf_counter()
            fits[oname][kind] = surrogates.tune(kind, x[tr], y[tr], x[va], y[va], x[te], y[te],
                                                trials=trials, seed=seed + 17 * m_i)
            secs[oname][kind] = time.perf_counter() - t0
    return fits, secs


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--design", default=None, help="a cached CAL.stage2-design.npz or the folder holding it")
    ap.add_argument("--out", default=None, help="without --design: where to calibrate (default: a temporary folder)")
    ap.add_argument("--repeat", type=int, default=1, help="time the stage this many times (the table is the last run's)")
    args = ap.parse_args(argv)
    opts = CalibrateOptions()
    if args.design is None:
        from impactsense.calibration.pipeline import calibrate
        out = Path(args.out or tempfile.mkdtemp(prefix="bench-surrogates-"))
        calibrate("bundled", out / "CAL.json", opts)
        args.design = str(out)
    x, outputs, path = load_design(Path(args.design))
    print(f"design {path}: {len(x)} runs x {x.shape[1]} factors; trials {opts.surrogate_trials}, seed {opts.seed}")
    walls = []
    for _ in range(max(1, args.repeat)):
        t0 = time.perf_counter()
        fits, secs = run_stage(x, outputs, opts.surrogate_trials, opts.seed)
        walls.append(time.perf_counter() - t0)
    w = 30
    print(f"\n{'surrogate test R2 (validation R2)':{w}s}" + "".join(f"{k:>16s}" for k in surrogates.MODELS))
    for oname, row in fits.items():
        print(f"{oname:{w}s}" + "".join(f"{f'{row[k].r2_test:.2f} ({row[k].r2_val:.2f})':>16s}" for k in surrogates.MODELS))
    print(f"\n{'seconds':{w}s}" + "".join(f"{k:>16s}" for k in surrogates.MODELS))
    for oname, row in secs.items():
        print(f"{oname:{w}s}" + "".join(f"{row[k]:16.1f}" for k in surrogates.MODELS))
    for oname, row in fits.items():
        best = max(row.values(), key=lambda f: f.r2_val)
        print(f"best by validation R2, {oname}: {best.kind} "
              f"{ {k: v for k, v in best.config.items() if k != 'd'} }")
    print(f"\nsurrogates stage: {' / '.join(f'{t:.1f}' for t in walls)} s wall (min {min(walls):.1f} s)")


if __name__ == "__main__":
    main()
