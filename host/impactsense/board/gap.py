"""The board's model against the host's: what the host's model uses that the board's does not run, and the two
models' held-out accuracy on the same drops (issue 15: the board must never silently be several times worse).

`impactsense export` trains the board's own model on the board's captures (board.models) with only what fits the
board's rate and event budget (board.cost). Where the host's model leans on something the board leaves out (the
band picks above all, on a laminate) the board's position is several times the host's; export prints and records
both figures, their ratio and the list below, so the gap is never silent.
"""

from __future__ import annotations

import numpy as np

from ..api import predict
from ..metrics import localisation_metrics
from ..models import ImpactModel
from ..signal import SignalConfig
from .cost import POSTERIOR_PER_POINT, signal_instructions

# The board's MAE may exceed the host's by this factor before export calls the board model worse than the host's
# (issue 15's target: within ~10 %).
TARGET_RATIO = 1.1


def _signal(card: dict) -> dict:
    s = card.get("signal")
    return s if isinstance(s, dict) else {}


def _band_on(signal: dict) -> bool:
    return float(signal.get("band_pick_hz", 0) or 0) > 0 and float(signal.get("band_velocity_mm_per_us", 0) or 0) > 0


def band_pick_cost(host_signal: dict, board_signal: dict) -> int | None:
    """What the host's band picks (its frequency, window and travel model) would add to the board's event
    (instructions, board.cost's rates: the demodulator's samples on four channels and the band localiser's
    run), None when its frequency is at or above the board's Nyquist frequency (the board's samples cannot
    carry it)."""
    fs = float(board_signal.get("fs_hz", 0) or 0)
    f0 = float(host_signal.get("band_pick_hz", 0) or 0)
    if not (fs > 0 and 0 < f0 < fs / 2):
        return None
    keys = ("band_pick_hz", "band_window_us", "band_velocity_mm_per_us", "band_metric_xx", "band_metric_xy",
            "band_metric_yy")
    with_band = SignalConfig.from_dict({**board_signal, **{k: host_signal[k] for k in keys if k in host_signal}})
    return int(signal_instructions(with_band)["total"] - signal_instructions(SignalConfig.from_dict(board_signal))["total"])


def board_lacks(host_card: dict, board_card: dict, board_trees: int | None = None) -> list[str]:
    """What the host's model (host_card) uses that the board's (board_card, exported with board_trees trees per
    coordinate) does not, one plain sentence each, the costliest first; [] when the board runs all of it."""
    hs, bs = _signal(host_card), _signal(board_card)
    out = []
    if _band_on(hs) and not _band_on(bs):
        fs_board = float(bs.get("fs_hz", 0) or 0)
        f0 = float(hs["band_pick_hz"])
        cost = band_pick_cost(hs, bs)
        why = (f"at {f0 / 1000:.1f} kHz, at or above the board's Nyquist frequency ({fs_board / 2000:g} kHz)"
               if cost is None else f"~{cost:,} instructions an event more, over the event budget")
        out.append(f"the band picks (their own localiser run, the physics position the mean of both): {why}")
    if host_card.get("position_members"):
        out.append(f"the position members {list(host_card['position_members'])} (the board runs one forest pair on "
                   "the physics position)")
    hk, bk = int(hs.get("localiser_starts", 1) or 1), int(bs.get("localiser_starts", 1) or 1)
    if hk > bk:
        out.append(f"localiser starts: {hk} on the host, {bk} on the board (event budget)")
    grid = int(hs.get("posterior_grid", 0) or 0)
    if grid > 1 and int(bs.get("posterior_grid", 0) or 0) <= 1:
        out.append(f"the localiser's posterior mean ({grid} x {grid} points, ~{POSTERIOR_PER_POINT * grid * grid:,} "
                   "instructions a localiser run, over the event budget)")
    if float(hs.get("dispersion_exponent", 0) or 0) != 0 and float(bs.get("dispersion_exponent", 0) or 0) == 0:
        out.append("the dispersive localiser (the picked cycle's frequency scales each channel's slowness)")
    out += _acquisition_lacks(host_card, board_card)
    if "twin" in host_card and "twin" not in board_card:
        out.append("the twin's site-map match")
    host_trees = int((host_card.get("forest") or {}).get("n_estimators", 0) or 0)
    boosted = board_card.get("board_forests") or {}
    if board_trees is not None and host_trees and boosted.get("use_boosted"):
        out.append(f"forest trees: {host_trees} on the host; on the board {board_trees} boosted trees of depth "
                   f"{boosted.get('depth')} (event budget)")
    elif board_trees is not None and host_trees and board_trees < host_trees:
        out.append(f"forest trees: {host_trees} on the host, {board_trees} on the board (event and flash budgets)")
    return out


# The board's trigger is named when it missed or took late more than this share of the drops (board.models
# trigger_record).
TRIGGER_SHARE = 0.02


def _acquisition_lacks(host_card: dict, board_card: dict) -> list[str]:
    """What the board's acquisition lacks on this rig: an anti-alias front end where the rig's recordings are
    faster than the board and rig.json declares none (the rig's content above the board's Nyquist frequency aliases
    into its picks), and a trigger that missed drops or fired late on them (its threshold above the arrivals' first
    cycles: the link's set_threshold, `impactsense emulate --threshold`)."""
    out = []
    rig_fs = float((host_card.get("rig") or {}).get("fs_hz", 0) or 0)
    board_fs = float(board_card.get("board_fs_hz", 0) or 0)
    if board_fs > 0 and rig_fs > board_fs + 1 and "board_front_end" not in board_card:
        out.append(f"an anti-alias front end (rig.json board_front_end): the recordings at {rig_fs / 1000:g} kHz carry "
                   f"content above the board's Nyquist frequency ({board_fs / 2000:g} kHz) that aliases into its picks")
    trig = board_card.get("board_trigger") or {}
    drops, captured, late = (int(trig.get(k, 0) or 0) for k in ("drops", "captured", "late"))
    if drops and (drops - captured > TRIGGER_SHARE * drops or late > TRIGGER_SHARE * drops):
        out.append(f"a trigger that reaches the arrivals: at its threshold ({trig.get('threshold_counts')} of the rig's "
                   f"counts) it captured {captured} of {drops} drops and took {late} late (the first arrival inside "
                   "its baseline frames); a lower threshold (the link's set_threshold) catches them")
    return out


def host_positions(model_dir, session, rows: np.ndarray) -> np.ndarray:
    """The host model's reported positions (ImpactModel.predict at the rig's rate: the twin's match where the
    model has one) of `rows` of `session`, NaN where it reports none."""
    xy = np.asarray(predict(ImpactModel.load(model_dir), session.adc[np.asarray(rows, int)])["xy_mm"], float)
    return xy.reshape(-1, 2)


def compare(truth: np.ndarray, host_xy: np.ndarray, board_xy: np.ndarray, inner_mm=None) -> dict:
    """Both models' Eq. 36 metrics on the drops where both give a finite position: {'scored', 'host', 'board',
    'ratio_mae' (board / host MAE per axis), 'target_ratio', 'within_target'}."""
    truth, host_xy, board_xy = (np.asarray(a, float).reshape(-1, 2) for a in (truth, host_xy, board_xy))
    both = np.isfinite(host_xy).all(1) & np.isfinite(board_xy).all(1)
    if not both.any():
        return {"scored": 0}
    h = localisation_metrics(truth[both], host_xy[both])
    b = localisation_metrics(truth[both], board_xy[both])
    ratio = float(b["mae_mm"] / h["mae_mm"]) if h["mae_mm"] > 0 else float("inf")
    return {"scored": int(both.sum()), "host": h, "board": b, "ratio_mae": ratio, "target_ratio": TARGET_RATIO,
            "within_target": bool(ratio <= TARGET_RATIO)}
