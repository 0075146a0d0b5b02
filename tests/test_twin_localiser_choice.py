"""The onset threshold chosen on a twin's virtual drops for the rig (travel.chosen_trial, transfer_spread_mm):
among the thresholds the twin's drops cannot tell apart, the one whose twin travel law explains the rig's
calibration drops best; measured drops keep the configured one unless another is clearly better."""

import numpy as np

from impactsense.travel import TravelFit, chosen_trial, metric_of, transfer_spread_mm, travel_distances

SENSORS = np.array([[50.0, 45.0], [400.0, 55.0], [395.0, 300.0], [60.0, 290.0]])


def trials(spreads: dict, rig: dict | None = None) -> list[dict]:
    """Trials in choose_threshold's order (the configured pair, 10 counts and blend 0.35, first); rig: the
    rig's spreads of the pairs that were scored."""
    out = [{"onset_threshold_counts": thr, "aic_blend": blend, "spread_mm": s} for (thr, blend), s in spreads.items()]
    for t in out:
        if rig and (t["onset_threshold_counts"], t["aic_blend"]) in rig:
            t["rig_spread_mm"] = rig[(t["onset_threshold_counts"], t["aic_blend"])]
    return out


def test_measured_drops_keep_the_configured_threshold_unless_another_is_clearly_better():
    tie = trials({(10, 0.35): 6.2, (20, 0.35): 6.0, (30, 0.2): 6.9, (50, 0.2): 9.0})
    assert chosen_trial(tie, 10, 0.35)["onset_threshold_counts"] == 10
    clear = trials({(10, 0.35): 7.4, (20, 0.2): 5.4, (30, 0.2): 5.5, (50, 0.2): 6.4})
    assert chosen_trial(clear, 10, 0.35)["onset_threshold_counts"] == 20


def test_twin_drops_take_the_tie_the_rig_prefers_and_never_one_outside_the_tie():
    spreads = {(10, 0.35): 6.2, (20, 0.35): 6.4, (30, 0.2): 6.9, (50, 0.2): 8.0}
    # 10, 20 and 30 are within THRESHOLD_GAIN of the best (6.2 / 0.85 = 7.29); 50 is not, however well the rig
    # liked it
    got = chosen_trial(trials(spreads, {(10, 0.35): 9.0, (20, 0.35): 5.1, (30, 0.2): 5.6, (50, 0.2): 1.0}), 10, 0.35)
    assert (got["onset_threshold_counts"], got["aic_blend"]) == (20, 0.35)
    # the rig's best is not clearly better than the virtual drops' own choice (10 counts, 5.5 mm): that stays
    got = chosen_trial(trials(spreads, {(10, 0.35): 5.5, (20, 0.35): 5.1, (30, 0.2): 4.8}), 10, 0.35)
    assert got["onset_threshold_counts"] == 10
    # nothing scored on the rig: the measured drops' rule
    assert chosen_trial(trials(spreads, {(20, 0.35): float("nan")}), 10, 0.35)["onset_threshold_counts"] == 10


def test_transfer_spread_fits_the_rigs_delays_and_speed_not_the_shape_of_the_law():
    rng = np.random.default_rng(3)
    xy = np.repeat(np.c_[rng.uniform(80, 370, 4), rng.uniform(80, 270, 4)], 5, axis=0)   # four cases, 5 repeats
    law = TravelFit(1.2, [0.0, 0.0, 0.0, 0.0], metric_of(-0.3, 0.0), 1.0, len(xy))
    period = np.full((len(xy), 4), 4.0)
    jitter = rng.normal(0.0, 0.5, (len(xy), 4))

    def toa(metric, v):   # the rig's picks: its own delays, speed and an arbitrary start per drop
        return (travel_distances(xy, SENSORS, metric) / v + np.array([0.0, 4.0, -6.0, 9.0])[None]
                + rng.uniform(100, 200, (len(xy), 1)) + jitter)

    same_shape = transfer_spread_mm(law, toa(law.metric, 1.5), xy, SENSORS, period, 100000.0)
    other_shape = transfer_spread_mm(law, toa(metric_of(0.2, 0.1), 1.5), xy, SENSORS, period, 100000.0)
    assert same_shape < 1.0 < 3 * same_shape < other_shape     # 0.5 us of jitter at 1.5 mm/us: ~0.5-0.8 mm
    assert np.isnan(transfer_spread_mm(law, np.full((3, 4), np.nan), xy[:3], SENSORS, period[:3], 100000.0))
