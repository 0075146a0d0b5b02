"""Errors instead of wrong numbers: checks that a session and a model belong together, that drops carry their
true positions, and that option values name real drops."""

from __future__ import annotations

import numpy as np

from .data import IMPACTS_FILE, RIG_FILE, Rig, Session
from .errors import ConfigError, DataError

# What a model learned about its rig: a session must agree on these to be scored by it.
SENSOR_TOL_MM = 1.0
PLATE_TOL = 0.01        # relative, plate size and thickness


def rig_summary(rig: Rig) -> dict:
    """The rig facts a model card keeps (model_card.json "rig")."""
    return {"plate_material": rig.plate_material, "plate_x_mm": rig.plate_x_mm, "plate_y_mm": rig.plate_y_mm,
            "thickness_mm": rig.thickness_mm, "sensor_xy_mm": rig.sensor_xy_mm.astype(float).round(3).tolist(),
            "fs_hz": rig.fs_hz, "adc_bits": rig.adc_bits, "ball_mass_g": rig.ball_mass_g}


def check_rig(card: dict, rig: Rig, card_path, session_path) -> None:
    """DataError unless the session's rig.json is the rig of the model card (sensors, sample rate, plate,
    logger). Cards without a "rig" entry are checked on what their signal settings hold. A retrained model whose
    rig has a disc where the diagnosis placed it (retrain's `sensors_moved`) keeps the sessions' declared
    positions (`declared_sensor_xy_mm`): its sessions' rig.json is checked against those."""
    want = card.get("rig") if isinstance(card.get("rig"), dict) else {}
    signal = card.get("signal") if isinstance(card.get("signal"), dict) else {}
    where = f"{session_path}/{RIG_FILE}"
    problems = []
    fs = want.get("fs_hz", signal.get("fs_hz"))
    if isinstance(fs, (int, float)) and abs(float(fs) - rig.fs_hz) > 1e-6 * max(float(fs), 1.0):
        problems.append(f"fs_hz {rig.fs_hz:g} but the model was trained at {float(fs):g}")
    try:
        key = "declared_sensor_xy_mm" if "declared_sensor_xy_mm" in want else "sensor_xy_mm"
        card_xy = (np.asarray(want[key], float) if key in want else
                   np.stack([np.asarray(signal["sensor_x_mm"], float), np.asarray(signal["sensor_y_mm"], float)], 1))
    except (KeyError, TypeError, ValueError):
        card_xy = None
    if card_xy is not None:
        if card_xy.shape != rig.sensor_xy_mm.shape or np.abs(card_xy - rig.sensor_xy_mm).max() > SENSOR_TOL_MM:
            problems.append(f"sensors at {rig.sensor_xy_mm.round(1).tolist()} mm but the model's are at "
                            f"{card_xy.round(1).tolist()}")
    for key in ("plate_x_mm", "plate_y_mm", "thickness_mm"):
        v = want.get(key, signal.get(key))
        if isinstance(v, (int, float)) and abs(float(v) - getattr(rig, key)) > PLATE_TOL * float(v):
            problems.append(f"{key} {getattr(rig, key):g} but the model's is {float(v):g}")
    if want.get("plate_material") not in (None, rig.plate_material):
        problems.append(f"plate_material {rig.plate_material!r} but the model's is {want['plate_material']!r}")
    adc_max = signal.get("adc_max")
    if isinstance(adc_max, int):
        adc_max += int(signal.get("sample_offset", 0) or 0)   # the core's rails are after the re-centring
    if isinstance(adc_max, int) and adc_max != rig.adc_max:
        problems.append(f"a {rig.adc_bits}-bit logger but the model's ADC range is 0..{adc_max}")
    if problems:
        raise DataError(where, None, "the session's rig is not the model's (" + "; ".join(problems) + f"; model "
                        f"card {card_path}): train a model on this rig, or give the session of the model's rig")


def require_labels(session: Session, rows=None) -> None:
    """DataError when drops (all, or `rows`) have no true position/height (recorded without them)."""
    rows = np.arange(len(session)) if rows is None else np.asarray(rows, int)
    for col in ("x_mm", "y_mm", "height_mm"):
        bad = ~np.isfinite(getattr(session, col)[rows])
        if bad.any():
            raise DataError(session.path / IMPACTS_FILE, col, f"unknown (empty) for {int(bad.sum())} drops, e.g. "
                            f"recording {int(session.recording_id[rows[bad][0]])}: fill in the true values "
                            "(`impactsense record --truth`) before training or scoring on them")


def exclude_rows(ids, session: Session, source: str) -> np.ndarray | None:
    """Recording ids to row indices; ConfigError naming `source` for ids that are not in the session."""
    if ids is None:
        return None
    ids = np.asarray(ids)
    if ids.size == 0:
        return ids.astype(int)
    if ids.dtype.kind not in "iu":
        raise ConfigError(f"{source}: recording ids must be integers")
    known = {int(r): k for k, r in enumerate(session.recording_id)}
    bad = [int(i) for i in ids.ravel() if int(i) not in known]
    if bad:
        raise ConfigError(f"{source}: recording id(s) {bad[:5]} not in {session.path} (ids 0..{len(session) - 1})")
    return np.asarray([known[int(i)] for i in ids.ravel()], int)
