"""The board's accuracy: the firmware app (emulated board, exported node tables) over a session's drops, and
the held-out drops a model card names, as its model sees them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import _link
from ..data import load_session
from ..errors import DataError
from ..link.emulator import Emulator
from ..metrics import region_metrics
from ..models import impact_energy_j
from ..pipeline import featurize
from ..signal import SignalConfig
from .capture import board_captures, board_signal


def board_reports(session, models, signal: dict, fs_hz: int = 50000) -> dict:
    """The firmware app (emulated board, exported node tables) over `session`'s drops: {drop row: the first
    valid report it sent, decoded from the wire}; drops without a valid report are absent."""
    dec, got = _link.Decoder(), {}
    for i, data in Emulator(session, models, fs_hz=fs_hz, signal=signal).drops():
        for f in dec.feed(data):
            if f["kind"] == "report" and f["report"].get("valid", True):
                got.setdefault(i, f["report"])
    return got


def board_accuracy(session, models, signal: dict, energy_threshold_j: float, fs_hz: int = 50000,
                   reports: dict | None = None) -> dict:
    """The firmware app (emulated board, exported node tables) over `session`'s drops, scored against the true
    positions and energy classes: Eq. 36 metrics of the reports with valid positions, their class accuracy,
    and how many drops gave a report. reports: board_reports' of these drops, when already run."""
    got = board_reports(session, models, signal, fs_hz) if reports is None else reports
    rows = np.asarray(sorted(got), int)
    pred = np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in rows]).reshape(-1, 2)
    label = (impact_energy_j(session.height_mm, session.rig.ball_mass_g) >= energy_threshold_j).astype(int)
    cls = np.array([got[i]["energy_class"] for i in rows], int)
    return {"n": len(session), "reported": int(rows.size), "fs_hz": int(fs_hz),
            **region_metrics(session.xy_mm[rows], pred, session.rig.inner_region_mm),
            "energy_class_accuracy": float(np.mean(cls == label[rows])) if rows.size else float("nan")}


def report_positions(reports: dict, n: int) -> np.ndarray:
    """The reported positions [n, 2] of board_reports' drops (NaN where a drop gave no valid report)."""
    out = np.full((int(n), 2), np.nan)
    for i, r in reports.items():
        out[i] = r["x_mm"], r["y_mm"]
    return out


def held_out_rows(card: dict):
    """(session, row indices of the model card's held-out drops), rows None when the card lists none. A
    sim-trained model's (zeroshot) are the measured test split, the calibration drops never in it."""
    split = card.get("zero_shot") or card.get("split") or {}
    ids = split.get("test_recordings")
    if ids is None:
        ids = card.get("test_recording_ids")
    data = split.get("data_path") or card.get("data")
    s = load_session(data if data and Path(str(data)).is_dir() else None)
    want = split.get("recordings_hash"), split.get("data_hash")
    if any(want) and not (want[0] and want[0] == s.recordings_hash()) and not (want[1] and want[1] == s.fingerprint()):
        raise DataError("model card", "split.data_path", f"the model's session {data!r} is not there or has other "
                        f"recordings now ({s.path} read instead): its held-out drops cannot be scored")
    if ids is None:
        return s, None
    index = {int(r): k for k, r in enumerate(s.recording_id)}
    return s, np.asarray([index[int(r)] for r in ids if int(r) in index], dtype=int)


def held_out_features(card: dict):
    """(Features, true xy [R, 2], heights [R]) of the card's held-out drops (all drops if it lists none) as
    the model sees them: a board-rate model's through the emulated board's captures."""
    s, rows = held_out_rows(card)
    rows = np.arange(len(s)) if rows is None else rows
    signal = board_signal(card)   # a board model's trigger as export writes it (board.trigger)
    board_fs = card.get("board_fs_hz")
    if board_fs and abs(float(board_fs) - s.rig.fs_hz) > 1:
        caps, got, sig = board_captures(s.subset(rows), int(board_fs), signal)
        rows = rows[got]
        f = featurize(caps, sig)
    else:
        f = featurize(s.adc[rows], SignalConfig.from_dict(signal))
    return f, s.xy_mm[rows], s.height_mm[rows]
