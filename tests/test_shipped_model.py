"""The model shipped in models/ -- what `pio run` builds into the board -- is made by the current code, fits the
board's budgets, and localises and classifies a session it never saw (session-2, a later day) when the
firmware app runs it on the emulated board.

It is trained on all of session-1 at the board's rate (README, "Firmware": the command that remakes it)."""

import json
from pathlib import Path

import numpy as np
import pytest

MODELS = Path(__file__).resolve().parents[1] / "models"


@pytest.fixture(scope="module")
def shipped():
    summary = json.loads((MODELS / "export.json").read_text())
    return summary


def test_shipped_model_is_complete_current_and_within_the_board_budgets(shipped):
    from impactsense.data import load_session
    from impactsense.export import TWIN_MAX_TREES
    from impactsense.pipeline import FEATURE_NAMES

    for name in ("impactsense_forest_tables.c", "impactsense_models.h", "forest_tables.npz"):
        assert (MODELS / name).is_file(), name
    assert shipped["features"] == FEATURE_NAMES            # the core computes what the forests were trained on
    assert shipped["data_hash"] == load_session("bundled").fingerprint() and shipped["n_train_drops"] >= 700
    assert shipped["signal_fs_hz"] == 50000.0 and shipped["within_budget"]
    assert shipped["table_bytes_total"] <= 256 * 1024      # flash budget for all models
    assert shipped["twin"] and shipped["trees"]["x"] <= TWIN_MAX_TREES and shipped["trees"]["y"] <= TWIN_MAX_TREES
    h = (MODELS / "impactsense_models.h").read_text()
    assert shipped["model_card_sha256_16"] in h             # the header and the tables come from one export


def test_shipped_model_on_the_emulated_board_scores_session_2(shipped):
    """Session-2 (160 drops, a later day, never trained on) through the firmware app with the shipped tables:
    the project's whole-plate target (MAE <= 5 mm) and an energy class well above the seed's 0.78."""
    from impactsense.data import load_session
    from impactsense.export import firmware_models
    from impactsense.board.scores import board_accuracy

    models, signal = firmware_models(MODELS)
    s2 = load_session("bundled:session-2")
    acc = board_accuracy(s2, models, signal, float(shipped["energy_threshold_j"]), 50000)
    assert acc["reported"] >= 0.97 * acc["n"]
    assert acc["all"]["mae_mm"] <= 5.0 and acc["energy_class_accuracy"] >= 0.85
    assert np.isfinite(acc["all"]["r2"]) and acc["all"]["r2"] >= 0.98
