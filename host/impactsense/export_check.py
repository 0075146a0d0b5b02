"""The channel check (channel_check.py, the core's impactcore::ChannelCheck) as the board gets it from `export`:
the card's cubic fits and scales, the plate's size and the event / run thresholds, in the generated C
(impactsense_channel_check, read by impactapp_models.h's exported_channel_check) and in forest_tables.npz (the
emulator's copy, check_level / check_tilt / check_scores), with the card's per-channel choice of a flagged drop's
position (flagged_position.py: "three_sensor_position"; a bit per channel that keeps the four channels'). Only a check whose cubics read the four-channel physics
position (version 2) goes to the board: the three-sensor positions of version 1 cost four localisations an event."""

from __future__ import annotations

import numpy as np

from .export_c import ExportError, _c_float

CHECK_DEFINE = "#define IMPACTSENSE_CHANNEL_CHECK 1           // the channel check (impactcore::ChannelCheck)\n"
CHECK_DECL = """// The channel check (impactcore::ChannelCheck): per channel the level and tilt cubics (10 coefficients, the
// residuals' median, their robust sd), the plate's size, the event and run thresholds, the run's events, the
// channels whose flagged drops keep the four channels' position.
typedef struct {
  float level[4][12];
  float tilt[4][12];
  float plate_x_mm, plate_y_mm, event_score, run_score;
  int32_t run_events;
  int32_t four_channel_mask;   // bit c: a drop flagged on channel c keeps the four channels' position
} impactsense_channel_check;
extern const impactsense_channel_check impactsense_check;
"""


def check_arrays(card: dict, signal: dict, three_channel: bool, card_path=None) -> dict | None:
    """The card's check as arrays {"level": [4, 12], "tilt": [4, 12], "scores": [6]} (float32: the plate's size, the
    event and run thresholds, the run's events, four_channel_mask), or None when the
    board does not run it: no check, a version-1 check, a model without the three-channel classes (the flagged
    event's class) or with a twin."""
    check = card.get("channel_check")
    if not isinstance(check, dict) or int(check.get("version", 1)) < 2 or not three_channel or "twin" in card:
        return None
    fits = {name: np.array([list(f["coef"]) + [f["median"], f["scale"]] for f in check[name]], np.float32)
            for name in ("level", "tilt")}
    scores = np.array([signal["plate_x_mm"], signal["plate_y_mm"], check["event_score"], check["run_score"],
                       check["run_events"], four_channel_mask(check, card_path)], np.float32)
    return {**fits, "scores": scores}


def four_channel_mask(check: dict, card_path=None) -> int:
    """Bit c set where the card's check keeps the four channels' position on a drop flagged on channel c
    (flagged_position.py's "three_sensor_position" false there; absent: 0, the three-sensor path)."""
    keep = check.get("three_sensor_position")
    if keep is None:
        return 0
    if not isinstance(keep, list) or len(keep) != 4:
        raise ExportError(f"{card_path or 'model_card.json'} [channel_check.three_sensor_position]: needs one bool "
                          f"per channel (4 values)")
    return sum(1 << c for c, k in enumerate(keep) if not k)


def check_c(arrays: dict) -> str:
    """impactsense_check as C."""
    rows = lambda a: "{" + ", ".join("{" + ", ".join(_c_float(v) for v in r) + "}" for r in a) + "}"  # noqa: E731
    s = arrays["scores"]
    body = ",\n  ".join([rows(arrays["level"]), rows(arrays["tilt"]), ", ".join(_c_float(v) for v in s[:4]),
                         str(int(s[4])), str(int(s[5]) if len(s) > 5 else 0)])
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


def board_signal_cost(models) -> dict | None:
    """With `export --trees auto`, a model without the twin: the board's instructions an event before the forests
    (board.cost's signal_instructions, "check": the check's share, budgeted; "total" with it); a twin model: None."""
    from .board.cost import EVENT_BUDGET, signal_instructions
    from .signal import SignalConfig

    if models.twin is not None:
        return None
    cost = signal_instructions(SignalConfig.from_dict(models.signal), 4, models.card.get("board_front_end"))
    cost["check"] = budgeted(models, cost, EVENT_BUDGET)
    cost["total"] += cost["check"]
    return cost


def event_estimate(models, n_trees: dict, signal_cost: dict | None = None) -> dict:
    """The board's instructions an event of this export, by part (board.cost.event_parts): the forests' prefixes
    n_trees {x, y, energy} each walked to its deepest leaf, a twin model's match, the channel check's share when
    the board runs it. signal_cost: board_signal_cost's, when export already has it."""
    from .board.cost import event_parts
    from .board.drop_cost import model_inputs
    from .signal import SignalConfig

    twin = models.twin
    return event_parts(SignalConfig.from_dict(models.signal), models.card.get("board_front_end"),
                       **model_inputs(models, n_trees),
                       twin=None if twin is None else {"grid": twin["grid"], "config": twin["config"]},
                       check_terms=(max((len(m.terms) for m in models.three_channel.values()), default=0)
                                    if models.channel_check else None),
                       check=None if signal_cost is None else int(signal_cost.get("check", 0)))


def drops_estimate(models, n_trees: dict, parts: dict) -> dict | None:
    """What to expect on the model's own session (board.drop_cost.rig_estimate: every drop priced whole on the host's
    counts of the board's captures; not a bound), or None when the card's session is not at hand."""
    from .board.drop_cost import rig_estimate
    from .board.scores import held_out_rows
    from .errors import ImpactSenseError

    try:
        session = held_out_rows(models.card)[0]
    except (ImpactSenseError, OSError, KeyError, ValueError):
        return None
    return rig_estimate(models, n_trees, parts, session, int(models.card.get("board_fs_hz") or 50000))


def estimate_form(est: dict) -> str:
    """Which estimate export's verdict reads: "parts" (no session at hand: the parts' worst cases), "drops" (the
    model's session, none of whose drops models a mains hum or redoes a channel: its slowest drop priced whole) or
    "hum" (a session with such a drop: the larger of the two)."""
    drops = est.get("drops") or {}
    if not drops:
        return "parts"
    return "hum" if drops.get("hum") or drops.get("beyond_base") else "drops"


def estimate_total(est: dict) -> int:
    """The export's event estimate, the one its verdict reads: without the model's session, the parts' worst cases
    (board.cost); with it, its slowest drop priced whole (board.drop_cost) on a session none of whose drops models a
    mains hum or redoes a channel, and the larger of the two on one that does (each form alone has passed a model
    that ran over: the parts on a glass plate ringing through its record, the drops with the hum's rate fitted
    without the hum's run: docs/findings.md "Session 26: exportest")."""
    drops = est.get("drops") or {}
    if not drops:
        return int(est["total"])
    if drops.get("hum") or drops.get("beyond_base"):   # a hum (or a channel redone): neither form alone bounds it
        return max(int(est["total"]), int(drops["slowest"]))
    return int(drops["slowest"])


def flagged_total(est: dict) -> int | None:
    """The flagged event's estimate (a twin's cued search, the check's three-sensor path) by the same rule as
    estimate_total; None without a flagged path on the board."""
    if "flagged" not in est:
        return None
    drops = est.get("drops") or {}
    if not drops or "flagged" not in drops:
        return int(est["flagged"])
    if drops.get("hum") or drops.get("beyond_base"):
        return max(int(est["flagged"]), int(drops["flagged"]))
    return int(drops["flagged"])


QEMU_COMMAND = "python3 benchmarks/bench_firmware_cost.py --export E --data D"


def event_verdict(est: dict, flagged: bool = False) -> str:
    """The board's event budget against export's estimate and its measured error (board.cost ESTIMATE_RATIO_BAND,
    by estimate_form): "ok" when even the estimate's worst under-count keeps it within EVENT_BUDGET, "OVER" when even
    its worst over-count leaves it above, "near" otherwise (measure it on qemu). flagged: the flagged event's
    (flagged_total; the band's high end at least FLAGGED_RATIO_HIGH); None without a flagged path."""
    from .board.cost import ESTIMATE_RATIO_BAND, EVENT_BUDGET, FLAGGED_RATIO_HIGH

    total = flagged_total(est) if flagged else estimate_total(est)
    if total is None:
        return None
    low, high = ESTIMATE_RATIO_BAND[estimate_form(est)]
    if flagged:
        high = max(high, FLAGGED_RATIO_HIGH)
    if total / low <= EVENT_BUDGET:
        return "ok"
    return "OVER" if total / high > EVENT_BUDGET else "near"


def verdicts(est: dict) -> dict:
    """export.json's "event_verdict" and, with a flagged path on the board, "flagged_event_verdict"."""
    out = {"event_verdict": event_verdict(est)}
    if "flagged" in est:
        out["flagged_event_verdict"] = event_verdict(est, flagged=True)
    return out


def verdict_text(est: dict, flagged: bool = False, export_dir=None, data=None) -> str:
    """event_verdict as export prints it: the verdict and the range of qemu's event the band gives; near the budget
    the qemu command (the export's folder and the model's session where given)."""
    from .board.cost import ESTIMATE_RATIO_BAND, EVENT_BUDGET, FLAGGED_RATIO_HIGH

    verdict = event_verdict(est, flagged)
    total = flagged_total(est) if flagged else estimate_total(est)
    low, high = ESTIMATE_RATIO_BAND[estimate_form(est)]
    high = max(high, FLAGGED_RATIO_HIGH) if flagged else high
    span = (f"{total / high:,.0f}-{total / low:,.0f} on the board: the estimate has measured {low:g}-{high:g} x "
            f"qemu's slowest event")
    if verdict == "near":
        command = QEMU_COMMAND.replace("--export E", f"--export {export_dir or 'E'}").replace(
            "--data D", f"--data {data or 'D'}")
        return f"budget {EVENT_BUDGET:,}: near the budget, {span}; measure it on qemu: `{command}`"
    return f"budget {EVENT_BUDGET:,}: {verdict}, {span}"


def within_event_budget(est: dict | None) -> bool | None:
    """export's JSON line: True ("ok"), False ("OVER") or None (near the budget, or no estimate)."""
    if est is None:
        return None
    return {"ok": True, "OVER": False}.get(event_verdict(est))


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


def mask_of(arrays: dict) -> int:
    """The arrays' four_channel_mask (an export from before it: 0)."""
    scores = arrays["scores"]
    return int(scores[5]) if len(scores) > 5 else 0


def four_channel_within(models, signal_cost: dict | None, forests: int | None) -> None:
    """With `export --trees auto`: a drop flagged on a channel whose choice is the four channels' runs the
    three-sensor path (its class) and the forests; when that does not fit the event budget (signal_cost["total"]
    with the check's share, the forests' instructions, the flagged event's localiser and class), the board takes the
    three-sensor path on every channel (the mask 0, models.four_channel_note says why). The clean event's forests
    are not cut for it."""
    from .board.cost import EVENT_BUDGET as budget
    from .board.cost import check_instructions
    from .signal import SignalConfig

    if signal_cost is None or forests is None or not models.channel_check or not mask_of(models.channel_check):
        return   # a twin model, or no cost estimate of the forests (`--trees all`, N, boosted): kept
    terms = max((len(m.terms) for m in models.three_channel.values()), default=0)
    flagged = check_instructions(SignalConfig.from_dict(models.signal), terms)["flagged"]
    need = signal_cost["total"] + forests + flagged
    if need > budget:
        models.channel_check["scores"][5] = 0
        models.four_channel_note = (f"a flagged drop keeps the three-sensor path on every channel on the board: the "
                                    f"four channels' position on one would take ~{need:,} instructions (forests "
                                    f"{forests:,}, localiser without the channel and class {flagged:,}) of {budget:,}")


def four_channel_summary(models) -> dict:
    """export.json's "flagged_four_channels": the channels whose flagged drops keep the four channels' position on
    the board, or why none does (four_channel_within); {} without the check on the board."""
    if models.channel_check is None:
        return {}
    mask = mask_of(models.channel_check)
    return {"flagged_four_channels": [c for c in range(4) if mask >> c & 1] if models.four_channel_note is None
            else models.four_channel_note}
