"""The board's trigger threshold chosen from the model's own drops (board.trigger.choose_trigger): a plate whose
first cycles are weak gets a lower threshold that takes every training drop on time, above the quiet start's
noise; a plate the default already takes on time keeps the default (no override written)."""

from dataclasses import replace

import numpy as np

from impactsense import _core
from impactsense.board.capture import TRIGGER_KEY, app_config, board_captures, board_signal, trigger_counts
from impactsense.board.trigger import choose_trigger, missed_or_late, quiet_sd
from impactsense.export_c import trigger_define


def _drops(session1, n=10):
    return session1.subset(np.linspace(0, len(session1) - 1, n).round().astype(int))


def _weakened(s, gain):
    """The drops with every channel's swing about its quiet level scaled by gain (a plate whose arrivals are weaker,
    the same ADC and its noise scaled with them)."""
    x = s.adc.astype(float)
    level = np.median(x[:, :, :200], axis=2, keepdims=True)
    return replace(s, adc=np.rint(level + gain * (x - level)).astype(s.adc.dtype))


def test_a_plate_the_default_takes_on_time_keeps_the_default(session1):
    s = _drops(session1)
    chosen, record = choose_trigger(s, np.arange(len(s)))
    assert chosen is None
    bad = [t["missed"] + t["late"] + t["extra"] for t in record["trials"]]
    assert record["trials"][0]["board_counts"] == _core.TriggerConfig().threshold_counts
    assert bad[0] <= 1 and bad[0] == min(bad)   # a late pick no lower threshold takes earlier keeps the default


def test_weak_first_cycles_get_a_lower_threshold_above_the_noise(session1):
    s = _weakened(_drops(session1), 0.06)
    caps, rows, sig = board_captures(s)
    wanted = np.arange(len(s))
    default = missed_or_late(rows, caps, sig, wanted)
    assert default["missed"] + default["late"] > 0          # the default fires late or not at all here
    chosen, record = choose_trigger(s, wanted)
    assert chosen is not None and chosen < _core.TriggerConfig().threshold_counts
    assert chosen >= record["floor_counts"] >= 5.0 * quiet_sd(caps, sig.baseline_samples) - 1e-6
    caps2, rows2, sig2 = board_captures(s, 50000, {TRIGGER_KEY: chosen})
    after = missed_or_late(rows2, caps2, sig2, wanted)
    assert after["missed"] + after["late"] + after["extra"] < default["missed"] + default["late"] + default["extra"]
    assert after["extra"] == 0                                # no second trigger on the noise or the ringing


def test_the_chosen_threshold_reaches_the_app_the_header_and_the_emulator(session1):
    card = {"signal": {"fs_hz": 100000}, "board_trigger": {"board_counts": 21.0}}
    sig = board_signal(card)
    assert sig[TRIGGER_KEY] == 21.0 and board_signal({"signal": {}}) == {}
    thr, rearm = trigger_counts(sig)
    assert thr == 21.0 and rearm < thr                         # re-armed below the lowered threshold
    cfg = app_config(session1.rig, 50000, sig)
    assert cfg["threshold_counts"] == 21.0 and cfg["rearm_counts"] == rearm
    assert "threshold_counts" not in app_config(session1.rig, 50000, {"fs_hz": 100000})   # the firmware's default
    assert "IMPACTSENSE_TRIGGER_COUNTS 21" in trigger_define(sig) and trigger_define({}) == ""
