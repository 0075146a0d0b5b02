"""The channel check (channel_check.py, the core's impactcore::ChannelCheck) as the board gets it from `export`:
the card's cubic fits and scales, the plate's size and the event / run thresholds, in the generated C
(impactsense_channel_check, read by impactapp_models.h's exported_channel_check) and in forest_tables.npz (the
emulator's copy, check_level / check_tilt / check_scores). Only a check whose cubics read the four-channel physics
position (version 2) goes to the board: the three-sensor positions of version 1 cost four localisations an event."""

from __future__ import annotations

import numpy as np

from .export_c import _c_float

CHECK_DEFINE = "#define IMPACTSENSE_CHANNEL_CHECK 1           // the channel check (impactcore::ChannelCheck)\n"
CHECK_DECL = """// The channel check (impactcore::ChannelCheck): per channel the level and tilt cubics (10 coefficients, the
// residuals' median, their robust sd), the plate's size, the event and run thresholds, the run's events.
typedef struct {
  float level[4][12];
  float tilt[4][12];
  float plate_x_mm, plate_y_mm, event_score, run_score;
  int32_t run_events;
} impactsense_channel_check;
extern const impactsense_channel_check impactsense_check;
"""


def check_arrays(card: dict, signal: dict, three_channel: bool) -> dict | None:
    """The card's check as arrays {"level": [4, 12], "tilt": [4, 12], "scores": [5]} (float32), or None when the
    board does not run it: no check, a version-1 check, a model without the three-channel classes (the flagged
    event's class) or with a twin."""
    check = card.get("channel_check")
    if not isinstance(check, dict) or int(check.get("version", 1)) < 2 or not three_channel or "twin" in card:
        return None
    fits = {name: np.array([list(f["coef"]) + [f["median"], f["scale"]] for f in check[name]], np.float32)
            for name in ("level", "tilt")}
    scores = np.array([signal["plate_x_mm"], signal["plate_y_mm"], check["event_score"], check["run_score"],
                       check["run_events"]], np.float32)
    return {**fits, "scores": scores}


def check_c(arrays: dict) -> str:
    """impactsense_check as C."""
    rows = lambda a: "{" + ", ".join("{" + ", ".join(_c_float(v) for v in r) + "}" for r in a) + "}"  # noqa: E731
    s = arrays["scores"]
    body = ",\n  ".join([rows(arrays["level"]), rows(arrays["tilt"]), ", ".join(_c_float(v) for v in s[:4]),
                         str(int(s[4]))])
    return f"const impactsense_channel_check impactsense_check = {{\n  {body}\n}};\n\n"


def npz_arrays(arrays: dict | None) -> dict:
    """The check's arrays as forest_tables.npz keys ({} without one)."""
    return {f"check_{k}": v for k, v in (arrays or {}).items()}


def from_npz(z) -> dict | None:
    """The check's arrays back from forest_tables.npz (None when it has none)."""
    if "check_scores" not in z.files:
        return None
    return {k: np.asarray(z[f"check_{k}"], np.float32) for k in ("level", "tilt", "scores")}


def binding_dict(arrays: dict | None) -> dict | None:
    """The check as _link.ForestModels' channel_check argument."""
    if arrays is None:
        return None
    return {k: np.asarray(v, np.float32).ravel().tolist() for k, v in arrays.items()}


def budgeted(models, signal_cost: dict, budget: int) -> int:
    """With `export --trees auto` (the event budget, board.cost): the instructions the check takes from the forests'
    share; when an event it flags (a localiser run without the channel and the three-channel class instead of the
    forests) does not fit the budget with the check itself, the board does not get it (models.channel_check None,
    models.card_note says why) and 0."""
    from .board.cost import check_instructions
    from .signal import SignalConfig

    if not models.channel_check:
        return 0
    terms = max((len(m.terms) for m in models.three_channel.values()), default=0)
    cost = check_instructions(SignalConfig.from_dict(models.signal), terms)
    need = signal_cost["total"] + cost["check"] + cost["flagged"]
    if need > budget:
        models.channel_check = None
        models.check_note = (f"the channel check stays on the host: an event it flags would take ~{need:,} "
                             f"instructions (check {cost['check']:,}, localiser without the channel and class "
                             f"{cost['flagged']:,}) of the board's {budget:,}")
        return 0
    return cost["check"]
