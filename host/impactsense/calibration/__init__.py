"""Calibration of the FEM twin on four measured drops (issue 4; docs/method.md, Calibration).

    from impactsense.calibration import CalibrateOptions, calibrate
    cal = calibrate("session-folder", "CAL.json", CalibrateOptions(budget=64))

Modules: `options` (CalibrateOptions), `problem` (CalibrationProblem: the drops and what the stages build up),
`stages` (STAGES, each `stage(problem)` with its cache key, `cache`), `pipeline` (calibrate: the stages in
order, CAL.json); the stages' physics: `drops` (choice of the four drops), `arrival` (fast first-arrival
model), `plate` (the delay misfit over the E x nu grid), `plate_fem`, `damping`, `plate_nu`, `disc_bond`,
`design` (the PZT block: Sobol design, `surrogates`, `screening`), `fem` (the simulator's parameters).
`_standin` is a private test stand-in for the FEM, never used by a command.
"""

from .pipeline import CalibrateOptions, calibrate

__all__ = ["CalibrateOptions", "calibrate"]
