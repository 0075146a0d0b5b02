"""Forests on the firmware's own inputs: the captures the firmware app takes from the board-rate stream.

Used by the firmware tests and benchmarks (and usable until the trainer targets the board rate): run the
emulator with raw dump over a session, compute the firmware feature vector of every capture with the C++
core (`_link.feature_vector_batch`), fit one RandomForestRegressor per coordinate and a binary energy
RandomForestClassifier (high = m g h at or above the 75th percentile), and write a MODEL_DIR that
`impactsense export` reads.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import _link
from .emulator import Emulator
from .record import CaptureAssembler


def board_captures(session, fs_hz: int = 50000):
    """(captures int16 [R, 4, n], recording index [R], core config) taken by the firmware app."""
    emu = Emulator(session, None, fs_hz=fs_hz, dump_raw=True)
    dec = _link.Decoder()
    asm = CaptureAssembler()
    caps, rows = [], []
    for i, data in emu.drops():
        for f in dec.feed(data):
            if f["kind"] == "raw":
                asm.add(f["raw"])
            elif f["kind"] == "report":
                cap = asm.take(f["report"]["seq"])
                if cap is not None:
                    caps.append(cap)
                    rows.append(i)
    return np.stack(caps), np.asarray(rows), emu.app.core_config


def energy_labels(session) -> np.ndarray:
    e = session.rig.ball_mass_g * session.height_mm
    return (e >= np.percentile(e, 75)).astype(int)


def train_board_models(session, out_dir, n_trees: int = 30, seed: int = 0, fs_hz: int = 50000,
                       test_fraction: float = 0.2):
    from sklearn.ensemble import RandomForestClassifier, RandomForestRegressor
    import joblib

    caps, rows, cfg = board_captures(session, fs_hz)
    X, _ = _link.feature_vector_batch(caps, cfg)
    rng = np.random.default_rng(seed)
    cases = np.unique(session.case_id)
    test_cases = rng.choice(cases, size=int(round(test_fraction * cases.size)), replace=False)
    test = np.isin(session.case_id[rows], test_cases)
    train = ~test
    xy = session.xy_mm[rows]
    cls = energy_labels(session)[rows]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    kw = dict(n_estimators=n_trees, random_state=seed, n_jobs=1)
    joblib.dump(RandomForestRegressor(**kw).fit(X[train], xy[train, 0]), out / "rf_x.joblib")
    joblib.dump(RandomForestRegressor(**kw).fit(X[train], xy[train, 1]), out / "rf_y.joblib")
    joblib.dump(RandomForestClassifier(**kw).fit(X[train], cls[train]), out / "rf_energy.joblib")
    card = {"features": "impactapp::feature_vector (interim, board rate)", "n_features": int(X.shape[1]),
            "fs_hz": fs_hz, "files": {"x": "rf_x.joblib", "y": "rf_y.joblib", "energy": "rf_energy.joblib"},
            "test_recording_ids": [int(r) for r in rows[test]], "seed": seed}
    (out / "model_card.json").write_text(json.dumps(card, indent=1))
    return out
