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
    from impactsense.export import FIRMWARE_CODE_BYTES, MODELS_FLASH_BUDGET, TWIN_MAX_TREES
    from impactsense.pipeline import FEATURE_NAMES

    for name in ("impactsense_forest_tables.c", "impactsense_models.h", "forest_tables.npz",
                 "impactsense_models_m2c.c"):     # both forms: env nano33ble and env nano33ble_m2cgen
        assert (MODELS / name).is_file(), name
    assert shipped["features"] == FEATURE_NAMES            # the core computes what the forests were trained on
    assert shipped["data_hash"] == load_session("bundled").fingerprint() and shipped["n_train_drops"] >= 700
    assert shipped["signal_fs_hz"] == 50000.0 and shipped["within_budget"]
    # the flash budget is for code + models: the tables within what the firmware's code leaves of 256 KB
    assert shipped["flash_budget_bytes"] == MODELS_FLASH_BUDGET
    assert shipped["table_bytes_total"] + FIRMWARE_CODE_BYTES <= 256 * 1024
    assert shipped["twin"] and shipped["trees"]["x"] <= TWIN_MAX_TREES and shipped["trees"]["y"] <= TWIN_MAX_TREES
    for name in ("impactsense_models.h", "impactsense_forest_tables.c", "impactsense_models_m2c.c"):
        head = (MODELS / name).read_text()[:4000]
        assert shipped["model_card_sha256_16"] in head, name   # the header and both forms come from one export
    tables = np.load(MODELS / "forest_tables.npz")
    # forest.h: each forest's roots, then its split-node count
    assert int(tables["x_roots"].size) == shipped["trees"]["x"] + 1 and int(tables["y_roots"].size) == shipped["trees"]["y"] + 1


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
