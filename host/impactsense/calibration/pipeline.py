"""`impactsense calibrate`: fit the twin to four measured drops (docs/method.md, Calibration).

`calibrate` builds a `CalibrationProblem` (stage `drops`: four repeatable, accepted cases well spread over the
plate) and runs `stages.STAGES` over it, each cached next to CAL.json as `<stem>.<cache>`, keyed by the inputs
that determine it, so an interrupted run resumes and a finished one is not recomputed:

  plate_grid  E and nu over the full E x nu grid, the delay misfit (Eq. 16) of the fast first-arrival model
              (`plate`, `arrival`), contour plot
  plate_fem   E on the FEM at the grid's nu from the AIC DToA (`plate_fem`): the AIC DToA alone fix only a
              combination of E and nu (the bending stiffness)
  damping     D_s from the envelope decay of the four cases against two FEM runs of them (`damping`)
  support     (`--support auto` only) the plate support whose band group delays fit best
  disc_bond   (`--disc-bond fit` only) how much plate the discs stiffen (SimParams disc_stiffness_scale)
  plate_nu    E, nu and D_s from every repetition's band group delays, positions fitted, the decay's D_s as a
              prior (`plate_nu`); nu (and that D_s) is used only when the fit passes its rule
  plate_fem_refit  E refitted to the AIC DToA at the nu and D_s now held
  design      the PZT block by a Sobol design of FEM runs, surrogates, screening and surrogate optimisation
              with D_s held, a confirming FEM run (`design`)

CAL.json (written atomically at the end) holds every fitted parameter, "sim_params" for the simulator, the
losses, the drops used (never to be tested on) and each stage's wall time.
"""

from __future__ import annotations

import time

from . import fem
from .cache import cpu_seconds, record_compute_times, write_json
from .logger_gain import fit_logger_gain
from .options import MIN_BUDGET, CalibrateOptions
from .problem import build_problem, measured_core_config, picker_overrides, sim_core_config, sim_features
from .loss import twin_loss
from .span import twin_span
from .stages import STAGES, held

__all__ = ["MIN_BUDGET", "CalibrateOptions", "calibrate", "measured_core_config", "picker_overrides",
           "sim_core_config", "sim_features"]


def calibrate(data, out, options: CalibrateOptions | None = None, *, simulate=None) -> dict:
    """Run the calibration of session folder `data`; writes `out` (CAL.json) and returns its dict."""
    t_all, c_all = time.perf_counter(), cpu_seconds()
    problem = build_problem(data, out, options or CalibrateOptions(), simulate)
    for stage in STAGES:
        stage(problem)
    if not problem.opts.fem:
        problem.cal["pzt_damping"] = {"skipped": "run without the FEM (--no-fem): seed's PZT block and D_s kept"}
    elif problem.opts.plate_only:
        problem.cal["pzt_damping"] = {"skipped": "the plate stages only (--plate-only): seed's PZT block and D_s kept"}
    if not problem.opts.fem or problem.opts.plate_only:   # the seed's gain is the bundled logger's: match the peaks
        problem.cal["logger_gain"] = problem.clock.run("logger_gain", lambda: fit_logger_gain(problem, simulate))
    elif not problem.opts.design:
        problem.params["damping_per_s"] = float(held(problem)["damping_per_s"])
        problem.cal["pzt_damping"] = {"skipped": "no PZT design (--no-design): seed's PZT block kept; D_s "
                                                 f"{problem.params['damping_per_s']:.0f} 1/s from the plate stages"}
    # the twin's records carry the rig's noise (the seed's 1.5 counts is the bundled 12-bit logger's)
    problem.params["noise_counts_rms"] = float(problem.noise[0])
    # the twin's records span what the rig's drops ring for (span.py): every command reads it from sim_params
    span = twin_span(fem.sim_params(problem.params, problem.rig), problem.rig, problem.feats,
                     [r for rs in problem.targets.recording_ids for r in rs])
    if problem.opts.twin_span == "default":
        span = {**span, "duration_ms": span["default_ms"], "bound": "default (--twin-span default)"}
    problem.cal["twin_span"] = span
    problem.params["duration_ms"] = problem.cal["twin_span"]["duration_ms"]
    # the twin's decay per frequency band as the rig's (loss.py): a loss factor when the rig's decay rises with it
    loss = twin_loss(problem.session, [r for rs in problem.targets.recording_ids for r in rs],
                     float(problem.params["damping_per_s"]))
    problem.cal["twin_loss"] = loss
    if loss["kept"]:
        problem.params["loss_factor"] = loss["loss_factor"]
        problem.params["damping_per_s"] = loss["damping_per_s"]
    pzt = problem.cal["pzt_damping"]
    result = {**problem.header(), "plate": problem.plate, **problem.cal, "fitted": problem.params,
              "sim_params": fem.sim_params_json(problem.params, problem.rig),
              "loss_at_optimum": {"eq16_us2_fast_model": problem.stage_results["plate_grid"]["loss_eq16_us2"],
                                  "eq16_us2_fem": problem.plate.get("fem_loss_eq16_us2"),
                                  **{k: pzt[k] for k in ("f2", "f3", "f2_rel") if k in pzt}}}
    problem.clock.seconds["total"] = round(time.perf_counter() - t_all, 3)
    problem.clock.cpu["total"] = round(cpu_seconds() - c_all, 2)
    result["wall_time_s"] = problem.clock.seconds
    result["cpu_time_s"] = problem.clock.cpu
    result["stage_compute_time_s"] = record_compute_times(problem.cache("stage-times.json"), problem.clock.seconds)
    write_json(problem.out, result)
    return result
