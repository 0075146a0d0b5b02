"""The calibration's stages, in the order they run (docs/method.md, Calibration).

Each stage is a `Stage`: `run(problem, key) -> result` (a JSON-able dict), the cache key of the inputs that
determine that result, and `apply(problem, result)`, what the result changes in the problem (the twin's
parameters, CAL.json's blocks). A stage with a `cache` tag is read from `<stem>.<cache>` when its key matches
(`cache.cached`); the others keep their own resumable caches (the plate grid's chunks, the FEM evaluations,
the design's runs) under the same key.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..progress import progress_bar
from ..materials import material_for_rig
from . import arrival, damping, design, disc_bond, fem, laminate, plate, plate_fem, plate_nu
from .cache import cached, key, model_key
from .problem import CalibrationProblem


@dataclass(frozen=True)
class Stage:
    name: str                                               # its wall time's name in CAL.json
    run: Callable[[CalibrationProblem, str | None], dict]
    apply: Callable[[CalibrationProblem, dict], None]
    key: Callable[[CalibrationProblem], str | None] = lambda problem: None   # None: nothing to key on
    cache: str | None = None        # JSON cache file tag; None: the stage caches (or not) by itself
    wanted: Callable[[CalibrationProblem], bool] = lambda problem: problem.opts.fem and not problem.opts.plate_only
    clocked: bool = True            # False: the stage clocks its own parts

    def __call__(self, problem: CalibrationProblem) -> None:
        if not self.wanted(problem):
            return
        stage_key = self.key(problem)

        def result():
            if self.cache is None or stage_key is None:
                return self.run(problem, stage_key)
            return cached(problem.cache(self.cache), stage_key, lambda: self.run(problem, stage_key))
        res = problem.clock.run(self.name, result) if self.clocked else result()
        problem.stage_results[self.name] = res
        self.apply(problem, res)


# --- plate_grid: E and nu over the full grid, the fast first-arrival model ------------------------------------

def _plate_grid(problem: CalibrationProblem, _key) -> dict:
    opts, targets, rig = problem.opts, problem.targets, problem.rig
    e_axis, nu_axis = problem.e_axis, problem.nu_axis
    setup = arrival.setup_from_rig(rig, targets.x_mm, targets.y_mm, targets.height_mm, n_fft=opts.fast_n_fft)
    noise = problem.noise
    def evaluate(mask):
        return plate.run_grid(setup, problem.cfg_sim, int(rig.bias_counts), targets.peak, targets.dtoa_us, e_axis,
                              nu_axis, cache_path=str(problem.cache("stage1-grid.npz")), workers=opts.workers,
                              progress=opts.progress, noise_counts=noise[0], n_noise=noise[1], seed=noise[2],
                              mask=mask)
    loss = plate.search_grid(evaluate, e_axis, nu_axis)
    e_best, nu_best, loss_best = plate.refine_minimum(loss, e_axis, nu_axis)
    return {"E_mpa": e_best, "nu": nu_best, "loss_eq16_us2": loss_best, "loss": loss}


def _apply_plate_grid(problem: CalibrationProblem, res: dict) -> None:
    opts, e_axis, nu_axis, loss = problem.opts, problem.e_axis, problem.nu_axis, res.pop("loss")
    nu_step = round(float(np.diff(nu_axis).mean()), 6) if nu_axis.size > 1 else opts.nu_step
    fig9 = problem.cache("fig9-plate-loss.png")
    plate.contour_plot(loss, e_axis, nu_axis, (res["E_mpa"], res["nu"]), fig9)
    problem.plate.update({
        "E_mpa": res["E_mpa"], "nu": res["nu"], "loss_eq16_us2": res["loss_eq16_us2"],
        "rms_dtoa_error_us": float(np.sqrt(res["loss_eq16_us2"] / problem.targets.dtoa_us.size)),
        "grid": {"E_mpa": [float(e_axis[0]), float(e_axis[-1]), opts.e_step_mpa],
                 "nu": [float(nu_axis[0]), float(nu_axis[-1]), nu_step], "points": int(np.isfinite(loss).sum()),
                 "coarse_to_fine": bool(loss.size > plate.FULL_GRID_MAX_POINTS)},
        "near_optimal": plate.near_optimal_ranges(loss, e_axis, nu_axis),
        "model": "infinite Mindlin plate, Hertz pulse, core picker (calibration.arrival)",
        "contour_png": str(fig9)})
    params = fem.base_params(problem.rig, res["E_mpa"], res["nu"])
    if opts.support not in ("rig", "auto"):
        params["support"] = opts.support
        if opts.support == "elastic_rim":
            params["rim_stiffness_n_m2"] = float(opts.rim_stiffness_n_m2)
    if not _laminate_wanted(problem):          # a laminate's mesh follows its fitted shape (plate_laminate)
        params.update(fem.capped_mesh(params, problem.rig, opts.max_elements))
    problem.params = params


# --- plate_laminate: a laminate's E1, E2, G12 from the same DToA, each path along its ray ------------------------

def _laminate_key(problem: CalibrationProblem) -> str:
    grid = problem.stage_results["plate_grid"]
    return key(problem.base_key, grid["E_mpa"], grid["nu"], problem.opts.fast_n_fft, laminate.COARSE,
               laminate.REFINE, "laminate-v1")


def _plate_laminate(problem: CalibrationProblem, _key) -> dict:
    targets, rig, opts = problem.targets, problem.rig, problem.opts
    mat = material_for_rig(rig)
    nu12 = float(problem.plate["nu"])
    guess = laminate.pick_anisotropy(rig, targets.x_mm, targets.y_mm, targets.dtoa_us, mat.axis_deg)
    setup = arrival.setup_from_rig(rig, targets.x_mm, targets.y_mm, targets.height_mm, n_fft=opts.fast_n_fft)
    theta = laminate.ray_angles(rig, targets.x_mm, targets.y_mm)
    bar = progress_bar(opts.progress, desc="laminate E1, E2, G12", unit="plate",
                       total=int(np.prod(laminate.COARSE) + np.prod(laminate.REFINE)))
    res = laminate.fit(setup, theta, mat, nu12, guess, problem.plate["E_mpa"] * 1e6,
                       plate.cfg_state(problem.cfg_sim, int(rig.bias_counts)), targets.peak, targets.dtoa_us,
                       noise=problem.noise, workers=opts.workers, progress=bar.update)
    bar.close()
    return res


def _apply_plate_laminate(problem: CalibrationProblem, res: dict) -> None:
    """The twin's plate becomes the fitted laminate: e_pa its isotropic-equivalent modulus (what the later
    stages scale), the shape E2 / E1 and G12 / E1 kept (`fem.LAMINATE_FIELDS`)."""
    problem.plate["laminate"] = res
    problem.plate["E_grid_mpa"] = problem.plate["E_mpa"]
    problem.plate["E_mpa"] = float(res["E_equivalent_mpa"])
    problem.params.update({"e_pa": float(res["E_equivalent_mpa"]) * 1e6, "nu": float(res["nu12"]),
                           "laminate_e2_over_e1": float(res["E2_mpa"] / res["E1_mpa"]),
                           "laminate_g12_over_e1": float(res["G12_mpa"] / res["E1_mpa"])})
    problem.params.update(fem.capped_mesh(problem.params, problem.rig, problem.opts.max_elements))


def _laminate_wanted(problem: CalibrationProblem) -> bool:
    return material_for_rig(problem.rig).orthotropic


# --- plate_fem: E on the twin at the grid's nu, from the AIC DToA ----------------------------------------------

def plate_evaluations(problem: CalibrationProblem, params: dict, tag: str,
                      onset_only: bool = False) -> plate_fem.Evaluations:
    """The twin's DToA observables at (E, nu) with `params` otherwise, cached in `<stem>.stage1-<tag>.json`;
    onset_only: the AIC DToA alone (the others NaN), from runs no longer than its picks need
    (`plate_fem.onset_observables`)."""
    targets = problem.targets

    def run_obs(e_mpa, nu):
        p = dict(params, e_pa=e_mpa * 1e6, nu=nu)

        def run(duration_ms=None):
            flat = p if duration_ms is None else dict(p, duration_ms=duration_ms)
            return problem.simulate(flat, problem.rig, targets.x_mm, targets.y_mm, targets.height_mm)
        if onset_only:
            return plate_fem.onset_observables(run, fem.sim_params(p, problem.rig), problem.cfg_sim,
                                               len(problem.plate_targets.names), *problem.noise)
        return plate_fem.sim_observables(run(), problem.cfg_sim, *problem.noise)
    stage_key = key(problem.base_key, problem.plate_targets.to_json(), params["damping_per_s"], "plate-v3",
                    *model_key(params), *(("onset-only",) if onset_only else ()))
    return plate_fem.Evaluations(run_obs, problem.cache(f"stage1-{tag}.json"), stage_key,
                                 progress=problem.opts.progress, workers=problem.opts.workers)


def _plate_fem(problem: CalibrationProblem, _key) -> dict:
    ev = plate_evaluations(problem, problem.params, "fem", onset_only=True)     # the scan's chi^2 is the AIC's
    e_fem, scan = plate_fem.e_scan(ev, problem.plate_targets, problem.plate["E_mpa"], problem.plate["nu"],
                                   problem.e_bounds, ratios=problem.opts.fem_e_ratios, observables=[0])
    return {"E_mpa": float(e_fem), "scan": scan}


def _apply_plate_fem(problem: CalibrationProblem, res: dict) -> None:
    pl = problem.plate
    pl["E_fast_mpa"] = pl["E_mpa"]
    pl["E_mpa"] = res["E_mpa"]
    problem.params["e_pa"] = res["E_mpa"] * 1e6
    pl["fem_scan_seed_damping"] = {f"{k:.0f}": v for k, v in sorted(res["scan"].items())}
    pl["timing_targets"] = problem.plate_targets.to_json()


# --- damping: D_s from the envelope decay --------------------------------------------------------------------

def _damping_key(problem: CalibrationProblem) -> str:
    p = problem.params
    return key(problem.base_key, p["e_pa"], p["nu"], p["damping_per_s"], "decay-v4", *model_key(p))


def _damping(problem: CalibrationProblem, _key) -> dict:
    """D_s from the envelope decay of the four cases' accepted drops against two FEM runs of them (the current
    D_s, then the one the 1/2 slope predicts); the secant between the runs gives the final step."""
    targets, session, rig, params = problem.targets, problem.session, problem.rig, problem.params
    recs = sorted({int(r) for rs in targets.recording_ids for r in rs})
    blocks = damping.record_blocks(session.adc[recs], problem.cfg)      # sized to what the records keep
    power = np.full((len(session), 4, blocks.count), np.nan)
    power[recs] = damping.block_power(session.adc[recs], problem.cfg, float(rig.bias_counts), blocks)
    p_meas = damping.case_power(power, targets.recording_ids)
    mask = damping.window_mask(p_meas, targets.noise_rms)
    meas = damping.decay_rates(p_meas, mask, blocks.width_ms)

    def sim_rates(d_s):
        p = dict(params, damping_per_s=float(d_s), duration_ms=damping.DECAY_DURATION_MS)
        adc = problem.simulate(p, rig, targets.x_mm, targets.y_mm, targets.height_mm)
        return damping.decay_rates(damping.sim_power(adc, problem.cfg_sim, float(rig.bias_counts), targets.peak,
                                                     *problem.noise, blocks), mask, blocks.width_ms)

    d0 = float(params["damping_per_s"])
    r0 = sim_rates(d0)
    d1 = max(damping.damping_step(meas, r0, d0), damping.FLOOR_PER_S)   # a lightly damped plate: never below 0
    r1 = sim_rates(d1)
    slope = float(np.nanmedian(r1 - r0) / (d1 - d0)) if abs(d1 - d0) > 20.0 else 0.5
    slope = slope if 0.25 < slope < 1.0 else 0.5          # a failed secant falls back to the theory
    d2 = damping.damping_step(meas, r1, d1, slope)
    lo, hi = fem.factor_range("damping_per_s")
    per_drop = [float(d1 + np.nanmedian(meas[i] - r1[i]) / slope) for i in range(len(meas))]
    return {"damping_per_s": float(np.clip(d2, damping.FLOOR_PER_S, hi)), "estimate_per_s": d2,
            "se_per_s": damping.robust_se((meas - r1) / slope),
            "per_drop_per_s": per_drop, "slope_decay_per_damping": slope, "runs_per_s": [d0, d1],
            "measured_decay_per_s": meas, "fem_decay_per_s_at_runs": [r0, r1],
            "window_ms": [damping.START_MS, damping.START_MS + blocks.width_ms * mask.sum(axis=-1)],
            "block_ms": blocks.width_ms,
            "in_range": bool(lo <= d2 <= hi),
            "method": "D_s = D_1 + median(lambda_meas - lambda_fem(D_1)) / slope; lambda = -1/2 slope of the "
                      f"noise-corrected log power in {blocks.width_ms:.2f} ms blocks from 1 ms after the AIC onset "
                      f"while the measured case stays >= {damping.SNR:.0f} x noise (to {blocks.end_ms:.2f} ms: "
                      f"{damping.MAX_MS:.0f} ms or the records' end); FEM runs of the four "
                      f"drops ({damping.DECAY_DURATION_MS:.0f} ms) scaled to the measured peaks, rig noise added"}


def _apply_damping(problem: CalibrationProblem, res: dict) -> None:
    problem.cal["damping_from_decay"] = res


def decay(problem: CalibrationProblem) -> dict:
    """The damping stage's result."""
    return problem.stage_results["damping"]


def _params_at_decay(problem: CalibrationProblem) -> dict:
    return dict(problem.params, damping_per_s=float(decay(problem)["damping_per_s"]))


# --- support (--support auto): the plate support whose band group delays fit best -----------------------------

def _support_key(problem: CalibrationProblem) -> str:
    return key(problem.base_key, problem.params, decay(problem)["damping_per_s"], plate_nu.SUPPORT_CANDIDATES,
               "support-v1")


def _support(problem: CalibrationProblem, _key) -> dict:
    return plate_nu.choose_support(problem, _params_at_decay(problem))


def _apply_support(problem: CalibrationProblem, res: dict) -> None:
    if res["fields"] != {"support": fem.rig_support(problem.rig)}:   # the rig's own: params stay as they are
        problem.params.update(res["fields"])
    problem.plate["support_choice"] = res


# --- disc_bond (--disc-bond fit): how much plate the discs stiffen ----------------------------------------------

def _disc_bond_key(problem: CalibrationProblem) -> str:
    return key(problem.base_key, problem.params, decay(problem)["damping_per_s"], disc_bond.BOUNDS,
               disc_bond.COARSE, disc_bond.REFINE, "disc-bond-v1")


def _disc_bond(problem: CalibrationProblem, _key) -> dict:
    bar = progress_bar(problem.opts.progress, desc="FEM disc bond (scale, positions)", unit="scale",
                       total=len(disc_bond.COARSE) + disc_bond.REFINE)
    res = disc_bond.fit(problem, _params_at_decay(problem), progress=bar.update)
    bar.close()
    return res


def _apply_disc_bond(problem: CalibrationProblem, res: dict) -> None:
    problem.params[disc_bond.FIELD] = float(res["scale"])
    problem.cal["disc_bond"] = res   # the later stages' keys that name only E, nu or D_s now name the scale too


# --- plate_nu: E, nu and D_s from every repetition's band group delays, positions fitted ------------------------

def _plate_nu_key(problem: CalibrationProblem) -> str | None:
    if problem.opts.nu_rounds == 0 or _laminate_wanted(problem):   # a laminate's nu12 is held
        return None
    d = decay(problem)
    return key(problem.base_key, problem.params, d["damping_per_s"], d["se_per_s"], problem.nu_bounds,
               problem.e_bounds, problem.opts.nu_rounds, "plate-nu-v2")


def _plate_nu(problem: CalibrationProblem, stage_key) -> dict:
    """`plate_nu.run` from (E at the grid's nu, the grid's nu, the decay's D_s) with the decay estimate as D_s's
    prior (its SE and a systematic `plate_nu.DS_SYSTEMATIC` in quadrature)."""
    opts = problem.opts
    if stage_key is None:
        why = "a laminate's nu12 is held" if _laminate_wanted(problem) else "nu_rounds 0"
        return {"identified": False, "rule": f"the nu stage was skipped ({why})", "skipped": True}
    ds0 = float(decay(problem)["damping_per_s"])
    prior = (ds0, float(np.hypot(decay(problem)["se_per_s"], plate_nu.DS_SYSTEMATIC * ds0)))
    bar = progress_bar(opts.progress, desc="FEM nu fit (E, nu, D_s, positions)", unit="run",
                       total=plate_nu.max_evaluations(opts.nu_rounds))
    out = plate_nu.run(problem, _params_at_decay(problem), ds_prior=prior, e_bounds=problem.e_bounds,
                       nu_bounds=problem.nu_bounds, ds_bounds=_ds_bounds(ds0),
                       rounds=int(opts.nu_rounds), progress=bar.update)
    bar.close()
    return out


def _ds_bounds(ds0: float) -> tuple[float, float]:
    """The nu fit's D_s bounds: the design's range, reaching down to the decay's estimate when that lies under it
    (a lightly damped plate, damping.FLOOR_PER_S)."""
    lo, hi = fem.factor_range("damping_per_s")
    return min(lo, ds0), hi


def _apply_plate_nu(problem: CalibrationProblem, nu_fit: dict) -> None:
    """nu (and the fit's D_s) is used only when the fit passes its rule; else the grid's nu and the decay's D_s."""
    nu_grid = problem.plate["nu"]
    nu_used = float(nu_fit["nu"]) if nu_fit["identified"] else nu_grid
    ds_used = float(nu_fit["damping_per_s"]) if nu_fit["identified"] else float(decay(problem)["damping_per_s"])
    nu_fit["used"] = {"nu": nu_used, "damping_per_s": ds_used}
    problem.plate["nu_fit"] = nu_fit
    problem.params["nu"] = nu_used


def held(problem: CalibrationProblem) -> dict:
    """The nu and D_s the plate stages settled on (the nu stage's `used`)."""
    return problem.plate["nu_fit"]["used"]


# --- plate_fem_refit: E again at the nu and D_s held -----------------------------------------------------------

REFIT_RATIOS = (0.97, 1.0, 1.03)      # E scan of the refit, x the E held so far


def _plate_fem_refit(problem: CalibrationProblem, _key) -> dict:
    params, nu_fit, nu_used = problem.params, problem.plate["nu_fit"], held(problem)["nu"]
    ev = plate_evaluations(problem, dict(params, damping_per_s=held(problem)["damping_per_s"]), "fem-ds")
    e_aic, scan = plate_fem.e_scan(ev, problem.plate_targets, float(params["e_pa"]) / 1e6, nu_used,
                                   problem.e_bounds, ratios=REFIT_RATIOS, walk=1.03, observables=[0])
    # with nu identified, E is the group-delay fit's (the group delays move smoothly with E; the AIC DToA
    # move in whole samples and fix E more loosely, docs/findings.md); else the delay misfit's at the grid's nu
    e_mpa = round(float(nu_fit["E_mpa"]), 1) if nu_fit["identified"] else e_aic
    # its ln E difference on the scan's outer points: when E stayed where the scan started, two runs made already
    ident = plate_fem.nu_identifiability(ev, problem.plate_targets, e_mpa, nu_used, nu_bounds=problem.nu_bounds,
                                         e_ratios=(REFIT_RATIOS[0], REFIT_RATIOS[-1]))
    return {"E_mpa": e_mpa, "E_aic_mpa": e_aic, "scan": scan, "nu_identifiability": ident,
            "observables": ev(e_mpa, nu_used)}


def _apply_plate_fem_refit(problem: CalibrationProblem, res: dict) -> None:
    nu_fit, nu_used, e_mpa = problem.plate["nu_fit"], held(problem)["nu"], float(res["E_mpa"])
    obs, pt = res["observables"], problem.plate_targets
    problem.params["e_pa"] = e_mpa * 1e6
    misfit = float(plate.delay_misfit(obs[:, 0], pt.dtoa[:, 0]))
    if nu_fit["identified"]:
        claimed = (f"E, nu and D_s: nu {nu_used:.3f} +- {nu_fit['sd']['nu']:.3f}, E and D_s from the band group "
                   "delays of every repetition (positions fitted); E_aic_mpa is Eq. 16's E at that nu")
    else:
        claimed = ("E / (1 - nu^2), the bending stiffness; nu is the grid's and E follows from it (Eq. 16): the "
                   f"group-delay fit of nu is not identified ({nu_fit['rule']}); D_s from the envelope decay")
    problem.plate.update({
        "nu": nu_used, "nu_grid": problem.stage_results["plate_grid"]["nu"], "E_aic_mpa": float(res["E_aic_mpa"]),
        "E_mpa": e_mpa, "stiffness_E_over_1_minus_nu2_mpa": e_mpa / (1 - nu_used ** 2),
        "fem_scan": {f"{k:.0f}": v for k, v in sorted(res["scan"].items())},
        "fem_loss_eq16_us2": misfit, "fem_rms_dtoa_error_us": float(np.sqrt(misfit / problem.targets.dtoa_us.size)),
        "fem_chi2_all_observables": plate_fem.chi2(obs, pt),
        "fem_rms_residual_us": {n: float(np.sqrt(np.nanmean((obs[:, k] - pt.dtoa[:, k]) ** 2)))
                                for k, n in enumerate(pt.names)},
        "nu_identifiability": res["nu_identifiability"],
        "claimed": claimed})


# --- design: the PZT block (and D_s) by a Sobol design of FEM runs, surrogates, optimisation -------------------

def _apply_design(problem: CalibrationProblem, res: dict) -> None:
    problem.params.update(res.pop("fitted"))
    problem.cal["channel_amplitude_gain_meas_over_sim"] = res["channel_amplitude_gain_meas_over_sim"]
    problem.cal["pzt_damping"] = res


STAGES = (
    Stage("plate_grid", _plate_grid, _apply_plate_grid, wanted=lambda problem: True),
    Stage("plate_laminate", _plate_laminate, _apply_plate_laminate, key=_laminate_key, cache="laminate.json",
          wanted=_laminate_wanted),
    Stage("plate_fem", _plate_fem, _apply_plate_fem, wanted=lambda problem: problem.opts.fem),
    Stage("damping", _damping, _apply_damping, key=_damping_key, cache="damping.json"),
    Stage("support", _support, _apply_support, key=_support_key, cache="support.json",
          wanted=lambda problem: problem.opts.fem and not problem.opts.plate_only and problem.opts.support == "auto"),
    Stage("disc_bond", _disc_bond, _apply_disc_bond, key=_disc_bond_key, cache="disc-bond.json",
          wanted=lambda problem: problem.opts.fem and not problem.opts.plate_only and problem.opts.disc_bond == "fit"),
    Stage("plate_nu", _plate_nu, _apply_plate_nu, key=_plate_nu_key, cache="plate-nu.json"),
    Stage("plate_fem_refit", _plate_fem_refit, _apply_plate_fem_refit),
    Stage("design", lambda problem, _key: design.run(problem, held(problem)["damping_per_s"]), _apply_design,
          clocked=False, wanted=lambda problem: problem.opts.fem and not problem.opts.plate_only and problem.opts.design),
)
