"""Models trained on the firmware's own inputs: the captures the firmware app takes from the board-rate
stream (SAADC scan delays included), through `impactsense train`'s own model code.

The trainer (impactsense.models) fits on 100 kHz recordings; the board samples 4 x 50 kHz, where energies
and sample-count settings differ. Until sessions are recorded on the board (`impactsense record`), this
trains the same model type on what the emulated board captures, for the firmware tests and benchmarks.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import _link
from .emulator import Emulator, signal_for_board
from .record import CaptureAssembler


def board_captures(session, fs_hz: int = 50000, signal: dict | None = None):
    """(captures int16 [R, 4, n], recording index [R], SignalConfig) taken by the firmware app."""
    emu = Emulator(session, None, fs_hz=fs_hz, signal=signal, dump_raw=True)
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
    return np.stack(caps), np.asarray(rows), emu.signal


def train_board_models(session, out_dir, n_trees: int = 30, seed: int = 0, fs_hz: int = 50000,
                       test_fraction: float = 0.2, max_depth: int | None = None) -> Path:
    """Writes a MODEL_DIR (impactsense.models.ImpactModel) trained on the board's captures of a
    case-split training part of `session`; the card lists the held-out recording ids."""
    from ..models import ForestSettings, ImpactModel
    from ..pipeline import featurize

    caps, rows, sig = board_captures(session, fs_hz)
    feats = featurize(caps, sig)
    rng = np.random.default_rng(seed)
    cases = np.unique(session.case_id)
    test_cases = rng.choice(cases, size=int(round(test_fraction * cases.size)), replace=False)
    train = ~np.isin(session.case_id[rows], test_cases)
    settings = ForestSettings(n_estimators=n_trees, seed=seed, max_depth=max_depth)
    model = ImpactModel.fit(feats.take(np.flatnonzero(train)), session.xy_mm[rows][train],
                            session.height_mm[rows][train], session.rig.ball_mass_g, sig, settings)
    out = model.save(out_dir, extra_card={"board_fs_hz": fs_hz, "data": str(session.path),
                                          "test_recording_ids": [int(r) for r in rows[~train]]})
    # The card's channel delays are the rig's own; the scan delays are added by the firmware (and emulator).
    import json

    card_path = Path(out) / "model_card.json"
    card = json.loads(card_path.read_text())
    card["signal"]["channel_delay_us"] = [0.0, 0.0, 0.0, 0.0]
    card_path.write_text(json.dumps(card, indent=1))
    return Path(out)
