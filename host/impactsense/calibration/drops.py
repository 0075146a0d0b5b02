"""Choosing the four calibration drops and their measured targets.

A *drop* here is a lab case (`case_id`: one position and height, dropped several times). A case qualifies
when at least `min_reps` of its repetitions pass the Eq. 35 acceptance rule ("nearer" by distance; on an orthotropic
plate where that leaves fewer than four usable cases, in its material's travel metric, `order_metric`), no accepted repetition has a
clipped, dead or onset-less channel, and it lies at least `sensor_clearance_mm` from every sensor. Its
repeatability is the median over the six sensor pairs of the DToA spread (standard deviation across the
accepted repetitions, microseconds). `auto` takes one case per plate quadrant: the one minimising
spread + `spread_weight` * distance from the quadrant's centre, so the four are well spread and repeatable;
on an anisotropic plate two opposite quadrants take cases near sensor lines along the material axes
(drop_paths.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import _core
from ..errors import ConfigError, DataError
from ..signal import core_config, core_samples
from ..travel import wants_metric
from .drop_paths import choose_cases

BAD_FLAGS = _core.FLAG_CLIPPED | _core.FLAG_DEAD | _core.FLAG_NO_ONSET


def extract(session, cfg=None) -> dict:
    cfg = cfg or core_config(session.rig)
    return _core.extract_batch(core_samples(session.adc, cfg), cfg)


def order_metric(rig) -> list[float]:
    """The travel metric (Q_xx, Q_xy, Q_yy) Eq. 35's "nearer" is measured in before anything is fitted: on an
    orthotropic plate the Kirchhoff ray metric of its material's typical constants along the declared axes (a
    sensor nearer in millimetres across the fibres hears the hit later than one farther along them), else none
    (the Euclidean distance)."""
    from ..materials import kirchhoff_ray_metric, material_for_rig

    mat = material_for_rig(rig)
    if not mat.orthotropic:
        return []
    t = mat.typical()
    return list(kirchhoff_ray_metric(t["e1_pa"], t["e2_pa"], t["g12_pa"], t["nu12"], mat.axis_deg))


def arrival_order_accepted(session, feats, tol_us: float, margin_mm: float, metric=()) -> np.ndarray:
    """Eq. 35 on the drops' declared positions; `metric` (Q_xx, Q_xy, Q_yy): "nearer" in that travel metric."""
    rig = session.rig
    return _core.accept_batch(np.ascontiguousarray(feats["toa_us"], dtype=np.float32),
                              [float(v) for v in rig.sensor_x_mm], [float(v) for v in rig.sensor_y_mm],
                              np.ascontiguousarray(session.xy_mm, dtype=np.float32),
                              float(tol_us), float(margin_mm), [float(v) for v in metric]).astype(bool)


@dataclass
class DropTargets:
    """The measured quantities of the chosen cases (one row per case)."""

    case_ids: list[int]
    recording_ids: list[list[int]]      # accepted repetitions used, per case
    x_mm: np.ndarray
    y_mm: np.ndarray
    height_mm: np.ndarray
    dtoa_us: np.ndarray                 # [4, 6] median over accepted repetitions
    dtoa_spread_us: np.ndarray          # [4] repeatability score
    energy: np.ndarray                  # [4, 4] counts^2
    residual_ratio: np.ndarray          # [4, 4]
    peak: np.ndarray                    # [4, 4]
    first_peak: np.ndarray              # [4, 4]
    noise_rms: np.ndarray               # [4, 4] counts, baseline noise of the measured records
    info: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {
            "case_ids": [int(c) for c in self.case_ids],
            "recording_ids": [[int(r) for r in rs] for rs in self.recording_ids],
            "x_mm": self.x_mm.tolist(), "y_mm": self.y_mm.tolist(), "height_mm": self.height_mm.tolist(),
            "dtoa_us": self.dtoa_us.tolist(), "dtoa_spread_us": self.dtoa_spread_us.tolist(),
            "energy": self.energy.tolist(), "residual_ratio": self.residual_ratio.tolist(),
            "peak": self.peak.tolist(), "first_peak": self.first_peak.tolist(),
            "noise_rms": self.noise_rms.tolist(), **self.info,
        }


def case_table(session, feats, *, tol_us=0.0, margin_mm=0.0, min_reps=2, sensor_clearance_mm=40.0, metric=()):
    """Per-case usability and repeatability. Returns (dict case -> row dict, n_accepted_recordings)."""
    ok_rec = arrival_order_accepted(session, feats, tol_us, margin_mm, metric)
    good_ch = ((feats["flags"] & BAD_FLAGS) == 0).all(axis=1) & (feats["status"] == _core.STATUS_OK)
    sens = session.rig.sensor_xy_mm.astype(float)
    rows = {}
    for case in np.unique(session.case_id):
        recs = np.flatnonzero(session.case_id == case)
        use = recs[ok_rec[recs] & good_ch[recs]]
        x, y = session.x_mm[recs[0]], session.y_mm[recs[0]]
        clearance = float(np.min(np.hypot(sens[:, 0] - x, sens[:, 1] - y)))
        row = {"case": int(case), "recs": use, "n_reps": int(recs.size), "n_ok": int(use.size),
               "x": float(x), "y": float(y), "h": float(session.height_mm[recs[0]]),
               "clearance_mm": clearance, "eq35_rejected": int((~ok_rec[recs]).sum())}
        if use.size >= 2:
            row["spread_us"] = float(np.median(np.std(feats["dtoa_us"][use], axis=0, ddof=1)))
        else:
            row["spread_us"] = np.inf
        row["usable"] = bool(use.size >= min_reps and clearance >= sensor_clearance_mm)
        rows[int(case)] = row
    return rows, int(ok_rec.sum())


# calibrate's auto choice: cases near sensor lines along the material axes within this (mm); 0: off
# (drop_paths.py; docs/findings.md "Calibration drops along the material axes").
SENSOR_LINE_TOL_MM = 10.0


def line_rule(rig, line_tol_mm: float = SENSOR_LINE_TOL_MM) -> dict:
    """choose_cases' keywords for the rig: the sensors and material axes on a plate whose localiser fits a
    travel metric (travel.wants_metric), nothing on an isotropic one or with line_tol_mm 0."""
    if line_tol_mm <= 0 or not wants_metric(rig):
        return {}
    from ..materials import material_for_rig
    return {"sensors_xy": rig.sensor_xy_mm.astype(float), "axis_deg": float(material_for_rig(rig).axis_deg),
            "line_tol_mm": float(line_tol_mm)}


def _targets(session, feats, rows, chosen, info) -> DropTargets:
    def med(key):
        return np.stack([np.median(feats[key][rows[c]["recs"]], axis=0) for c in chosen]).astype(float)
    return DropTargets(
        case_ids=list(chosen), recording_ids=[rows[c]["recs"].tolist() for c in chosen],
        x_mm=np.array([rows[c]["x"] for c in chosen]), y_mm=np.array([rows[c]["y"] for c in chosen]),
        height_mm=np.array([rows[c]["h"] for c in chosen]),
        dtoa_us=med("dtoa_us"), dtoa_spread_us=np.array([rows[c]["spread_us"] for c in chosen]),
        energy=med("energy"), residual_ratio=med("residual_ratio"), peak=med("peak"),
        first_peak=med("first_peak"), noise_rms=med("noise_rms"), info=info)


def select_drops(session, feats=None, drops="auto", *, tol_us=0.0, margin_mm=0.0, min_reps=2,
                 sensor_clearance_mm=40.0, spread_weight=0.05,
                 line_tol_mm=SENSOR_LINE_TOL_MM) -> DropTargets:
    """The four calibration cases of `session` ("auto" or a list of four case ids; auto: drop_paths.choose_cases,
    on a plate whose localiser fits a metric with two cases near sensor lines along the material axes, within
    line_tol_mm; 0 turns that off)."""
    feats = feats if feats is not None else extract(session)
    kw = dict(tol_us=tol_us, margin_mm=margin_mm, min_reps=min_reps, sensor_clearance_mm=sensor_clearance_mm)
    rows, n_acc = case_table(session, feats, **kw)
    metric = order_metric(session.rig)
    if metric and sum(r["usable"] for r in rows.values()) < 4:
        # a strongly orthotropic plate: in millimetres the arrival order rejects most drops; take its material's
        # travel metric for "nearer" (rigs with four usable cases by distance keep the choice they had)
        rows, n_acc = case_table(session, feats, metric=metric, **kw)
    else:
        metric = []
    where = str(session.path)
    if n_acc == 0:
        raise DataError(where, "recordings", f"all {len(session)} drops are rejected by the Eq. 35 "
                        f"acceptance rule (tol {tol_us} us, margin {margin_mm} mm): no calibration drop")
    usable = [c for c, r in rows.items() if r["usable"]]
    info = {"selection": "auto" if isinstance(drops, str) else "manual", "eq35_tol_us": tol_us,
            "eq35_margin_mm": margin_mm, "min_reps": min_reps, "usable_cases": len(usable),
            "accepted_recordings": n_acc, "eq35_travel_metric": [float(v) for v in metric] or None}
    if not isinstance(drops, str):
        chosen = [int(c) for c in drops]
        if len(chosen) != 4 or len(set(chosen)) != 4:
            raise ConfigError(f"--drops needs four different case ids, got {drops!r}")
        missing = [c for c in chosen if c not in rows]
        if missing:
            raise DataError(where, "case_id", f"case {missing[0]} is not in the session")
        for c in chosen:
            if not rows[c]["usable"]:
                r = rows[c]
                raise DataError(where, "case_id", f"case {c} is not usable for calibration: {r['n_ok']} of "
                                f"{r['n_reps']} repetitions accepted (Eq. 35 rejected {r['eq35_rejected']}; "
                                f"need {min_reps}), {r['clearance_mm']:.0f} mm from the nearest sensor")
        return _targets(session, feats, rows, chosen, info)
    if drops != "auto":
        raise ConfigError(f"--drops must be 'auto' or four comma-separated case ids, got {drops!r}")
    if len(usable) < 4:
        raise DataError(where, "recordings", f"only {len(usable)} usable drop case(s) (need 4): a case needs "
                        f">= {min_reps} repetitions accepted by Eq. 35 with no clipped/dead channel and "
                        f">= {sensor_clearance_mm:.0f} mm from every sensor")
    rule = line_rule(session.rig, line_tol_mm)
    chosen = choose_cases(rows, (session.rig.plate_x_mm, session.rig.plate_y_mm), spread_weight, **rule)
    if rule:
        info["sensor_line_tol_mm"] = rule["line_tol_mm"]
    return _targets(session, feats, rows, chosen, info)
