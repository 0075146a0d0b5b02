"""The twin's simulated span (SimParams.duration_ms) read from the rig's calibration drops.

The core's window energies, residual ratio and the site map's twin features run from the ToA to n2 (the sample
where a channel's cumulative energy reaches n2_fraction). On a plate that rings through its record the rig's n2 is
the record's end, while a twin simulated for the default span fades out there: the same features then mean
different spans on the twin and on the rig. The rule (docs/method.md, "The twin's span"): the twin simulates the
calibration drops' median n2 after their first threshold crossing, never less than the default span (a plate whose
energy is in before it keeps its twin), never past what the core reads of the twin's record, and
within a cost: the four reciprocal fields (`sim.simulate.reciprocal_fields`, [samples, nodes] float32 each) within
FIELDS_MAX_BYTES and their runs within RUNS_MAX_CPU_S by the solver-cost rule (`sim.solver_cost.direct_parts`).
"""

from __future__ import annotations

import math

import numpy as np

FIELDS_MAX_BYTES = 1.5e9   # the four reciprocal fields held in memory by simulate-dataset, the site map, the loop
RUNS_MAX_CPU_S = 120.0     # the four reciprocal runs' estimated CPU seconds (the direct path pays them once a twin)


def measured_span_ms(feats: dict, rows, fs_hz: float) -> float | None:
    """Median over `rows` (recording ids) and their channels of n2 - the recording's first threshold crossing, in
    ms (the core's features `extract_batch`: n2 and toa_threshold in the capture's samples); None when no channel
    has both."""
    rows = np.asarray(list(rows), int)
    if rows.size == 0:
        return None
    n2 = np.asarray(feats["n2"], float)[rows]
    cross = np.asarray(feats["toa_threshold"], float)[rows]
    cross = np.where(cross >= 0, cross, np.nan)
    ok_rows = np.isfinite(cross).any(axis=1)
    if not ok_rows.any():
        return None
    first = np.nanmin(np.where(np.isfinite(cross[ok_rows]), cross[ok_rows], np.inf), axis=1)
    after = n2[ok_rows] - first[:, None]
    after = after[(n2[ok_rows] >= 0) & np.isfinite(after) & (after > 0)]
    return float(np.median(after) / fs_hz * 1e3) if after.size else None


def record_span_ms(params, rig) -> float:
    """What the core reads of the twin's record after the first touch (at params.pretrigger_samples), in ms."""
    from ..signal import CORE_MAX_SAMPLES, record_start

    pre = int(params.pretrigger_samples)
    end = min(int(rig.samples), record_start(int(rig.samples), pre, float(rig.fs_hz)) + CORE_MAX_SAMPLES)
    return max(0.0, (end - pre) / float(rig.fs_hz) * 1e3)


def cost_span_ms(params, rig) -> float:
    """The longest span whose four reciprocal fields fit FIELDS_MAX_BYTES and whose runs fit RUNS_MAX_CPU_S
    (solver_cost.direct_parts on the twin's model at its present span, scaled: both grow with the samples)."""
    from ..sim.simulate import get_model
    from ..sim.solver_cost import direct_parts

    model = get_model(params, rig)
    ms = float(params.duration_ms)
    per_ms_bytes = len(model.sensors) * model.n_record * model.nodes * 4 / ms
    per_ms_cpu = direct_parts(model, 0, {"element_steps": 0.0})["runs_cpu_s"] / ms
    return min(FIELDS_MAX_BYTES / per_ms_bytes, RUNS_MAX_CPU_S / per_ms_cpu)


def twin_span(params, rig, feats: dict, rows) -> dict:
    """The twin's span by the rule (module docstring): {"duration_ms", "measured_n2_ms", "wanted_ms", "record_ms",
    "cost_ms", "bound"} ("bound": what set it: "default", "measured", "record" or "cost")."""
    default = float(params.duration_ms)
    measured = measured_span_ms(feats, rows, float(rig.fs_hz))
    out = {"measured_n2_ms": measured, "default_ms": default}
    if measured is None:
        return {**out, "duration_ms": default, "bound": "default"}
    wanted = measured
    record = record_span_ms(params, rig)
    cost = cost_span_ms(params, rig) if wanted > default else math.inf
    span = min(wanted, record, cost)
    bound = "measured" if span == wanted else ("record" if span == record else "cost")
    if span <= default:
        span, bound = default, "default"
    return {**out, "wanted_ms": wanted, "record_ms": record,
            "cost_ms": None if math.isinf(cost) else float(cost), "duration_ms": round(float(span), 3), "bound": bound}
