"""The onset threshold chosen on a twin's virtual drops for the rig (travel.chosen_trial): the twin is cleaner
than the rig ahead of the flexural arrival, so among thresholds it cannot tell apart the highest is kept;
measured drops keep the configured one unless another is clearly better."""

from impactsense.travel import chosen_trial


def trials(spreads: dict) -> list[dict]:
    """Trials in choose_threshold's order: the configured pair (10 counts, blend 0.35) first."""
    return [{"onset_threshold_counts": thr, "aic_blend": blend, "spread_mm": s} for (thr, blend), s in spreads.items()]


def test_measured_drops_keep_the_configured_threshold_unless_another_is_clearly_better():
    tie = trials({(10, 0.35): 6.2, (20, 0.35): 6.0, (30, 0.2): 6.9, (50, 0.2): 9.0})
    assert chosen_trial(tie, 10, 0.35)["onset_threshold_counts"] == 10
    clear = trials({(10, 0.35): 7.4, (20, 0.2): 5.4, (30, 0.2): 5.5, (50, 0.2): 6.4})
    assert chosen_trial(clear, 10, 0.35)["onset_threshold_counts"] == 20


def test_twin_drops_take_the_highest_threshold_they_cannot_tell_from_the_best():
    tie = trials({(10, 0.35): 6.2, (20, 0.35): 6.4, (20, 0.0): 6.3, (30, 0.35): 7.1, (30, 0.2): 6.9, (50, 0.2): 8.0})
    got = chosen_trial(tie, 10, 0.35, twin=True)
    # 30 counts is within the gain of the best (6.2 / 0.85 = 7.29), 50 is not; of 30's blends the better one
    assert (got["onset_threshold_counts"], got["aic_blend"]) == (30, 0.2)
    # a clear optimum stays the choice on a twin too (the bundled twin's table: only 10 counts within the gain)
    clear = trials({(10, 0.35): 2.84, (10, 0.2): 2.85, (20, 0.35): 3.43, (30, 0.35): 3.88})
    assert chosen_trial(clear, 10, 0.35, twin=True)["onset_threshold_counts"] == 10
