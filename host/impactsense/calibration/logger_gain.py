"""The twin's logger gain when the PZT design does not run (`calibrate --no-fem`, `--plate-only`).

The seed's circuit gain (SimParams.circuit_gain, ADC-input volts per disc volt) is the bundled logger's. On
another rig's logger (another ADC, another front end, a thin or light plate) the twin's drops then peak at
some multiple of the measured ones: clipped at the rails (a virtual set's energies saturated) or beyond the
int16 range the site map is built in (`simulate-dataset --calibration` stopped with "simulated counts exceed
the int16 range"). Here the four calibration drops are simulated once at the fitted plate (the FEM's fast
path, four drops) and the circuit gain is scaled so that their peaks match the measured ones: the median over
drops and channels of measured / simulated peak (each the largest deviation from the record's level before
the hit). A run that clips is repeated at 1/16 of the gain (the disc's voltage is linear in it).
"""

from __future__ import annotations

import numpy as np

from . import fem

PROBE_SHRINK = 16.0
MAX_PROBES = 3


def record_peaks(adc: np.ndarray, level_samples: int) -> np.ndarray:
    """[n, 4] each record's largest |count - its level| (the median of its first `level_samples`)."""
    a = np.asarray(adc, float)
    level = np.median(a[..., :max(1, int(level_samples))], axis=-1, keepdims=True)
    return np.abs(a - level).max(axis=-1)


def fit_logger_gain(problem, simulate=None) -> dict:
    """Scales problem.params["circuit_gain"] so the twin's calibration drops peak as the measured ones; returns
    what CAL.json records (`logger_gain`). `simulate`: a fem.Simulator (default: the problem's, else the FEM's
    fast path); without the FEM nothing is changed and the reason is returned."""
    from ..sim import SimParams

    simulate = simulate or problem.simulate
    if simulate is None:
        if not fem.available():
            return {"skipped": "the FEM is not available here: the seed's circuit gain kept"}
        simulate = fem.fem_simulator(workers=problem.opts.workers)
    rig, t = problem.rig, problem.targets
    seed_gain = float(problem.params.get("circuit_gain", SimParams().circuit_gain))
    pre = SimParams.from_rig(rig).pretrigger_samples
    gain = seed_gain
    for _ in range(MAX_PROBES):
        adc = np.asarray(simulate({**problem.params, "circuit_gain": gain}, rig, t.x_mm, t.y_mm, t.height_mm))
        if not ((adc == 0) | (adc == rig.adc_max)).any():
            break
        gain /= PROBE_SHRINK
    simulated = record_peaks(adc, max(1, pre // 2))
    measured = np.asarray(t.peak, float)
    ok = np.isfinite(measured) & (measured > 0) & (simulated > 0)
    if not ok.any():
        return {"skipped": "no calibration drop with a peak on both sides: the seed's circuit gain kept"}
    scale = float(np.median(measured[ok] / simulated[ok]))
    problem.params["circuit_gain"] = gain * scale
    return {"circuit_gain": gain * scale, "over_seed": gain * scale / seed_gain,
            "measured_peak_median_counts": float(np.median(measured[ok])),
            "seed_peak_median_counts": float(np.median(simulated[ok])) * seed_gain / gain,
            "rule": "the four calibration drops through the twin at the fitted plate: circuit gain x the median "
                    "measured / simulated peak"}
