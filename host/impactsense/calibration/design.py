"""The calibration's `design` stage: the PZT block (and D_s) fitted to the four drops' energies and residual
ratios (docs/method.md, Calibration: design / surrogate).

A Sobol design (budget - infill runs) of FEM runs over `fem.FACTORS`; surrogates of the 16 (drop, sensor)
log10 energies and residual ratios tuned on its 70/15/15 split (the R2 table); Welch screening; surrogate
optimisation; then infill rounds (FEM runs in a shrinking box around the current surrogate optimum,
surrogates refitted with their tuned settings, re-optimised) and a final FEM run at the last optimum. The
fitted point is the best FEM-evaluated one near the surrogate optimum by the weighted objective.

`damping_fixed`: D_s measured directly (the plate stages); the design still spans D_s (screening,
surrogates), the optimisation and the infill hold it there and fit the PZT block.

The misfits: energy_misfit = sum (E_meas - E_sim)^2 and residual_ratio_misfit = sum (ratio_meas - ratio_sim)^2
over drops and sensors (CAL.json "f2" and "f3", the seed's names).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import differential_evolution
from scipy.stats import qmc

from ..outputs import atomic_file
from ..progress import progress_bar
from . import fem, screening, surrogates
from .cache import as_json, cpu_seconds, key, model_key, read, write_json
from .problem import CalibrationProblem, sim_features

INFILL_ROUNDS = 2
CHUNK_RUNS = 8          # design runs simulated side by side between two saves of the design's npz
CLOCKED = ("design_fem", "surrogates", "screening", "optimise", "infill_fem", "fem_confirm")


def unit_damping(d_s: float) -> float:
    """D_s held by the optimisation and the infill, in the design's unit coordinate: up to the design range's top
    (1), and below its low end down to the decay estimate's floor (damping.FLOOR_PER_S; a lightly damped plate's
    infill and confirming FEM runs are then at its measured D_s, the surrogates extrapolate in D_s only)."""
    from .damping import FLOOR_PER_S

    lo_d, hi_d = fem.factor_range("damping_per_s")
    return float(np.clip((d_s - lo_d) / (hi_d - lo_d), (FLOOR_PER_S - lo_d) / (hi_d - lo_d), 1.0))


def unit_to_params(u):
    """Points of the unit cube as fem.FACTORS values."""
    lo = np.array([f[1] for f in fem.FACTORS])
    hi = np.array([f[2] for f in fem.FACTORS])
    return lo + np.asarray(u) * (hi - lo)


def _named(u) -> dict:
    return dict(zip(fem.FACTOR_NAMES, (float(v) for v in unit_to_params(u))))


@dataclass
class DesignRuns:
    """The design's FEM runs (n design and infill points + 1 confirming run): unit points, the 4 x 4 energies
    and residual ratios, which are done; kept in an npz under the design's key (resumable)."""

    u: np.ndarray
    energy: np.ndarray
    ratio: np.ndarray
    done: np.ndarray
    path: Path
    key: str

    @classmethod
    def start(cls, n_init: int, n: int, seed: int, path: Path, design_key: str) -> "DesignRuns":
        d = len(fem.FACTORS)
        u = np.full((n + 1, d), np.nan)        # + 1: the final confirming run
        u[:n_init] = qmc.Sobol(d=d, scramble=True, seed=seed).random(2 ** int(np.ceil(np.log2(n_init))))[:n_init]
        runs = cls(u, np.full((n + 1, 4, 4), np.nan), np.full((n + 1, 4, 4), np.nan), np.zeros(n + 1, bool),
                   path, design_key)
        if path.exists():
            with np.load(path, allow_pickle=False) as z:
                if str(z["key"]) == design_key:
                    runs.energy, runs.ratio, runs.done = z["energy"].copy(), z["ratio"].copy(), z["done"].copy()
                    runs.u[runs.done] = z["u"][runs.done]
        return runs

    def save(self) -> None:
        with atomic_file(self.path) as fh:
            np.savez(fh, key=self.key, energy=self.energy, ratio=self.ratio, done=self.done, u=self.u,
                     x=unit_to_params(np.nan_to_num(self.u)))

    def simulate(self, problem: CalibrationProblem, idx, bar) -> None:
        """Run the FEM at the points idx not done yet (saving after each)."""
        t = problem.targets

        def run(i):
            p = dict(problem.params, **_named(self.u[i]))
            return sim_features(problem.simulate(p, problem.rig, t.x_mm, t.y_mm, t.height_mm), problem.cfg_sim,
                                *problem.noise)
        todo = [i for i in idx if not self.done[i]]
        for chunk in range(0, len(todo), CHUNK_RUNS):     # saved after each chunk (resumable)
            part = todo[chunk:chunk + CHUNK_RUNS]
            for i, f in zip(part, fem.points_concurrently(run, part, problem.opts.workers)):
                self.energy[i], self.ratio[i], self.done[i] = f["energy"], f["residual_ratio"], True
                bar.update(1)
            self.save()

    def outputs(self, m: int, targets):
        """The first m runs as the surrogates' outputs (per drop and sensor, the seed's Table 5 rows; energies
        in log10: they scale as gain^2 and decay exponentially with D_s) and their two misfits [m]."""
        e_sim = np.where(np.isfinite(self.energy[:m]) & (self.energy[:m] > 0), self.energy[:m], 1.0).reshape(m, 16)
        r_sim = np.where(np.isfinite(self.ratio[:m]), self.ratio[:m], 1.0).reshape(m, 16)
        energy_misfit = np.sum((targets.energy.reshape(16)[None] - e_sim) ** 2, axis=1)
        ratio_misfit = np.sum((targets.residual_ratio.reshape(16)[None] - r_sim) ** 2, axis=1)
        return {"sensor_energies_log10": np.log10(e_sim), "residual_ratios": r_sim}, energy_misfit, ratio_misfit


# the families' usual tuning cost, dearest first: the pool starts the networks first so that the two dearest
# tunings run side by side instead of one after the other at the end
_COST_ORDER = ("NN", "GPR", "RF", "SVD")


def _tune_task(task):
    kind, x_tr, y_tr, x_va, y_va, x_te, y_te, trials, seed = task
    return surrogates.tune(kind, x_tr, y_tr, x_va, y_va, x_te, y_te, trials=trials, seed=seed)


def fit_surrogates(opts, x_unit, outputs, split):
    """Every surrogate kind tuned for every output: the R2 table and the best kind per output (validation R2).
    The (output, kind) tunings are independent (each its own seed): they run in `opts.workers` processes
    through the batch executor; the table and the winners are the same as one after the other."""
    from ..sim.executor import Executor

    tr, va, te = split
    jobs = [(oname, m_i, kind) for oname in outputs for m_i, kind in enumerate(surrogates.MODELS)]
    jobs.sort(key=lambda j: _COST_ORDER.index(j[2]) if j[2] in _COST_ORDER else len(_COST_ORDER))
    tasks = [(kind, x_unit[tr], outputs[oname][tr], x_unit[va], outputs[oname][va], x_unit[te], outputs[oname][te],
              opts.surrogate_trials, opts.seed + 17 * m_i) for oname, m_i, kind in jobs]
    bar = progress_bar(opts.progress, total=len(jobs), desc="surrogates", unit="model")
    fits = {}
    for (oname, _, kind), fit in zip(jobs, Executor("", workers=opts.workers, kind="processes").map(_tune_task,
                                                                                                     tasks)):
        fits[oname, kind] = fit
        bar.update(1)
    bar.close()
    table, best = {}, {}
    for oname in outputs:                   # the winners in the families' order, as before (ties: the first)
        table[oname] = {}
        for kind in surrogates.MODELS:
            fit = fits[oname, kind]
            table[oname][kind] = {"r2_test": fit.r2_test, "r2_val": fit.r2_val,
                                  "config": {k: v for k, v in fit.config.items() if k != "d"}}
            if oname not in best or fit.r2_val > best[oname].r2_val:
                best[oname] = fit
    return table, best


def _surrogates_beside_screening(clock, opts, x_unit, outputs, split, png: Path):
    """fit_surrogates (worker processes) and the screening (this process, a thread) at the same time: neither
    needs the other. The clock's "surrogates" CPU seconds include the screening's; "screening" is its wall."""
    from ..sim.executor import in_background

    def timed_screen():
        t = time.perf_counter()
        res = screen(x_unit, outputs, png)
        clock.seconds["screening"] = round(time.perf_counter() - t, 3)
        return res
    screened = in_background(timed_screen, "screening")
    table, best = fit_surrogates(opts, x_unit, outputs, split)
    return table, best, screened()


def screen(x_unit, outputs, png: Path):
    """Welch screening of the design's mean outputs, and its chart."""
    ys = {"sensor energy (mean log10)": outputs["sensor_energies_log10"].mean(axis=1),
          "residual ratio (mean)": outputs["residual_ratios"].mean(axis=1)}
    res = {o: screening.welch_screen(unit_to_params(x_unit), y, list(fem.FACTOR_NAMES)) for o, y in ys.items()}
    screening.screening_chart(res, png)
    return res


@dataclass
class SurrogateObjective:
    """w_e log10 energy_misfit + w_r log10 residual_ratio_misfit as the surrogates predict them, over the free
    factors (D_s held at u_damping when given)."""

    models: dict
    weights: tuple
    targets: object
    u_damping: float | None

    @property
    def free(self) -> list:
        i_d = fem.FACTOR_NAMES.index("damping_per_s")
        return [k for k in range(len(fem.FACTORS)) if k != i_d or self.u_damping is None]

    def full(self, uu_free):
        uu = np.empty((len(uu_free), len(fem.FACTORS)))
        uu[:, self.free] = uu_free
        if self.u_damping is not None:
            uu[:, fem.FACTOR_NAMES.index("damping_per_s")] = self.u_damping
        return uu

    def __call__(self, uu):
        e_meas, r_meas = self.targets.energy.reshape(16), self.targets.residual_ratio.reshape(16)
        pred = {o: np.asarray(m.predict(uu)).reshape(len(uu), 16) for o, m in self.models.items()}
        e_hat = 10.0 ** pred["sensor_energies_log10"]
        energy_misfit = np.sum((e_meas[None] - e_hat) ** 2, axis=1)
        ratio_misfit = np.sum((r_meas[None] - pred["residual_ratios"]) ** 2, axis=1)
        return self.weights[0] * np.log10(energy_misfit + 1e-30) \
            + self.weights[1] * np.log10(np.maximum(ratio_misfit, 0) + 1e-30)

    def optimise(self, seed):
        """The surrogate optimum (differential evolution over the free factors): (unit point, objective)."""
        def obj(uu):
            uu = np.asarray(uu)
            return self(self.full(uu.T if uu.ndim == 2 else uu[None]))
        res = differential_evolution(obj, [(0.0, 1.0)] * len(self.free), seed=seed, maxiter=80, popsize=12,
                                     tol=1e-8, polish=False, vectorized=True, updating="deferred")
        return self.full(np.asarray(res.x)[None])[0], float(np.atleast_1d(res.fun)[0])


def infill(problem, runs: DesignRuns, objective: SurrogateObjective, best, n_init: int, n_infill: int, bar):
    """The infill rounds: FEM runs in a box (radius 0.15, halved each round) around the surrogate optimum, the
    tuned surrogates refitted on every run so far, re-optimised. Returns the first and last optimum, the last
    predicted objective and the seconds spent optimising and in the FEM."""
    opts, d = problem.opts, len(fem.FACTORS)
    t0 = time.perf_counter()
    u_opt, j_pred = objective.optimise(opts.seed)
    first_opt = u_opt.copy()
    t_opt, t_fem, start = time.perf_counter() - t0, 0.0, n_init
    for r in range(INFILL_ROUNDS):
        k = n_infill // INFILL_ROUNDS + (n_infill % INFILL_ROUNDS if r == INFILL_ROUNDS - 1 else 0)
        if k <= 0:
            continue
        box = qmc.Sobol(d=d, scramble=True, seed=opts.seed + 101 + r).random(2 ** int(np.ceil(np.log2(max(2, k - 1)))))
        radius = 0.15 / 2 ** r
        pts = np.vstack([u_opt[None], np.clip(u_opt + (2 * box - 1) * radius, 0, 1)])[:k]
        if objective.u_damping is not None:
            pts[:, fem.FACTOR_NAMES.index("damping_per_s")] = objective.u_damping
        idx = range(start, start + k)
        for i, pnt in zip(idx, pts):
            if not runs.done[i]:
                runs.u[i] = pnt
        t1 = time.perf_counter()
        runs.simulate(problem, idx, bar)
        t_fem += time.perf_counter() - t1
        start += k
        t1 = time.perf_counter()
        outs_all, _, _ = runs.outputs(start, problem.targets)
        for o in objective.models:     # refit the tuned surrogates on every FEM run so far
            m = surrogates.build(best[o].kind, best[o].config, opts.seed)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                m.fit(runs.u[:start], outs_all[o])
            objective.models[o] = m
        u_opt, j_pred = objective.optimise(opts.seed + 1 + r)
        t_opt += time.perf_counter() - t1
    return first_opt, u_opt, j_pred, t_opt, t_fem


def run(problem: CalibrationProblem, damping_fixed=None) -> dict:
    """The design stage's CAL.json block "pzt_damping" (with "fitted": the factors at the chosen run)."""
    opts, params, clock = problem.opts, problem.params, problem.clock
    n = int(opts.budget)
    n_infill = n // 4
    n_init = n - n_infill
    u_d = None if damping_fixed is None else unit_damping(damping_fixed)
    design_key = key(problem.base_key, params["e_pa"], params["nu"], n, opts.seed, u_d, "infill-v2",
                     *model_key(params))
    result_path, result_key = problem.cache("stage2-result.json"), key(design_key, opts.surrogate_trials, "result-v3")
    hit = read(result_path, result_key)
    if hit is not None:
        clock.seconds.update({stage: 0.0 for stage in CLOCKED})
        hit.pop("key")
        return hit
    runs = DesignRuns.start(n_init, n, opts.seed, problem.cache("stage2-design.npz"), design_key)
    bar = progress_bar(opts.progress, total=n + 1, initial=int(runs.done.sum()),
                       desc="FEM runs (design, infill, confirm)", unit="run")
    clock.run("design_fem", runs.simulate, problem, range(n_init), bar)
    outputs, _, _ = runs.outputs(n_init, problem.targets)
    x_unit = runs.u[:n_init]
    split = surrogates.split_indices(n_init, opts.seed)
    png = problem.cache("fig10-screening.png")
    table, best, screened = clock.run("surrogates", _surrogates_beside_screening, clock, opts, x_unit, outputs,
                                      split, png)
    # each term weighted by its surrogate's validated skill (R2 on the validation split, clipped to [0, 1]):
    # a residual-ratio surrogate that cannot predict (noisy ratios, clipping) must not steer the optimum
    weights = tuple(float(np.clip(best[o].r2_val, 0.0, 1.0)) for o in ("sensor_energies_log10", "residual_ratios"))
    objective = SurrogateObjective({o: b.model for o, b in best.items()}, weights, problem.targets, u_d)
    c0 = cpu_seconds()
    first_opt, u_opt, j_pred, t_opt, t_fem = infill(problem, runs, objective, best, n_init, n_infill, bar)
    clock.cpu["optimise_and_infill_fem"] = round(cpu_seconds() - c0, 2)
    clock.seconds["optimise"] = round(t_opt, 3)
    clock.seconds["infill_fem"] = round(t_fem, 3)
    if not runs.done[n]:
        runs.u[n] = u_opt
    clock.run("fem_confirm", runs.simulate, problem, [n], bar)
    bar.close()
    surrogate = {"first_surrogate_optimum": _named(first_opt), "final_surrogate_optimum": _named(u_opt),
                 "surrogate_predicted_objective": j_pred, "surrogate_r2_test": table,
                 "best_surrogate": {o: b.kind for o, b in best.items()},
                 "split": {"train": len(split[0]), "validation": len(split[1]), "test": len(split[2])},
                 "screening": {o: rows[:20] for o, rows in screened.items()}, "screening_png": str(png)}
    out = summary(problem, runs, n_init, n_infill, weights, u_d is not None, surrogate)
    write_json(result_path, {"key": result_key, **out})
    return as_json(out)


def summary(problem, runs: DesignRuns, n_init: int, n_infill: int, weights, damping_held: bool,
            surrogate: dict) -> dict:
    """The chosen run and the misfits: the fit is the best FEM-confirmed point of the trust region around the
    surrogate optimum (the infill runs and the final optimum's run); the best point anywhere is reported beside
    it (a lone lucky point of the global design is not a fit: the energy misfit is flat along gain x D_s).
    `surrogate`: the surrogates' part of the block (optima, R2 table, split, screening)."""
    targets, n = problem.targets, len(runs.done) - 1
    _, energy_misfit, ratio_misfit = runs.outputs(n + 1, targets)
    j_all = weights[0] * np.log10(energy_misfit + 1e-30) + weights[1] * np.log10(ratio_misfit + 1e-30)
    i_best = int(np.argmin(j_all))
    i_fit = n_init + int(np.argmin(j_all[n_init:n + 1]))
    e_norm = float(np.sum(targets.energy.reshape(16) ** 2))
    # what one PZT block cannot fit: the rig's per-channel gains (electronics). Amplitude factor per channel,
    # measured / simulated at the fit (geometric mean over the four drops), for tools that map simulated
    # records to this rig
    energy = runs.energy[i_fit]
    ratio_e = np.where(np.isfinite(energy) & (energy > 0), targets.energy / energy, np.nan)
    gain = np.sqrt(np.exp(np.nanmean(np.log(ratio_e), axis=0)))
    return {
        "channel_amplitude_gain_meas_over_sim": [float(g) for g in gain],
        "fitted": _named(runs.u[i_fit]), "budget": n,
        "chosen": f"best FEM run near the surrogate optimum (run {i_fit}; {n_init}..{n - 1} infill, {n} final optimum)",
        "runs": {"design": n_init, "infill": n_infill, "confirm": 1},
        "f2": float(energy_misfit[i_fit]), "f3": float(ratio_misfit[i_fit]),
        "f2_rel": float(energy_misfit[i_fit]) / e_norm,
        "best_fem_evaluated_point": {"run": i_best, "objective": float(j_all[i_best]),
                                     "f2_rel": float(energy_misfit[i_best]) / e_norm, "f3": float(ratio_misfit[i_best]),
                                     "params": _named(runs.u[i_best])},
        "first_surrogate_optimum": surrogate["first_surrogate_optimum"],
        "final_surrogate_optimum": surrogate["final_surrogate_optimum"],
        "objective": "minimise w2 log10 f2 + w3 log10 f3, w = validation R2 of the surrogate (clipped 0..1)"
                     + ("; D_s held at the envelope-decay estimate" if damping_held else ""),
        "objective_weights": {"f2": weights[0], "f3": weights[1]},
        "surrogate_predicted_objective": surrogate["surrogate_predicted_objective"],
        "fem_confirm": {"f2": float(energy_misfit[n]), "f3": float(ratio_misfit[n]), "objective": float(j_all[n])},
        "best_initial_design_point": {"index": int(np.argmin(j_all[:n_init])),
                                      "objective": float(j_all[:n_init].min())},
        **{k: surrogate[k] for k in ("surrogate_r2_test", "best_surrogate", "split", "screening", "screening_png")},
        "outputs": "surrogates model the 16 (drop, sensor) log10 energies and residual ratios (R2 = mean over "
                   "the 16); f2 = sum (E meas - E sim)^2 [counts^4], f2_rel = f2 / sum E_meas^2; f3 = sum "
                   "(Eresid/E meas - Eresid/E sim)^2 over the 4 drops x 4 sensors",
    }
