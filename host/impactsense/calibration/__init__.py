"""Calibration of the FEM twin on four measured drops (issue 4; docs/method.md, Calibration).

    from impactsense.calibration import CalibrateOptions, calibrate
    cal = calibrate("session-folder", "CAL.json", CalibrateOptions(budget=64))

Modules: `drops` (choice of the four drops), `arrival` (fast first-arrival model), `plate` (sub-problem 1),
`fem` (the simulator's parameters), `surrogates`, `screening`, `pipeline` (stages, caches, CAL.json).
`_standin` is a private test stand-in for the FEM, never used by a command.
"""

from .pipeline import CalibrateOptions, calibrate

__all__ = ["CalibrateOptions", "calibrate"]
