"""A channel's blocked move outranks the other channels' weaker delays (`move_or_delay.shadows_of_a_stronger_channel`).

The per-drop centring couples the channels' timing: a moved disc whose move has the evidence against no change, but
whose timing change no test tells from a constant, gave another channel's delay a held-out gain of its own, and that
weaker delay was named on the wrong sensor (docs/findings.md, issue 16 loopdraws3). The rule only takes names away.
"""

from __future__ import annotations


from impactsense import diagnose as D
from impactsense import move_or_delay as MD


def cand(effect, sensor, score, significant, offset_mm=6.0):
    params = {"offset_mm": offset_mm} if effect == "sensor_position" else {}
    return D.Candidate(effect, sensor, params, score, 0.03, True, significant, [])


def run(results, evident=None, move_bound=40.0, unabsorbed=None):
    if evident is None:
        evident = {(c.effect, c.sensor) for c in results}
    MD.shadows_of_a_stronger_channel(results, evident, move_bound, unabsorbed or {})
    return {(c.effect, c.sensor): (c.significant, c.shadow_of) for c in results}


def test_a_weaker_delay_on_another_channel_is_not_named_below_a_blocked_move():
    out = run([cand("sensor_position", 3, 18.2, False), cand("channel_delay", 1, 15.2, True),
               cand("channel_delay", 2, 25.0, True), cand("channel_delay", 3, 12.3, True),
               cand("sensor_position", 0, 10.0, True), cand("wave_speed", None, 9.0, True)])
    assert out[("channel_delay", 1)] == (False, 3)        # the shadow: weaker, another channel
    assert out[("channel_delay", 2)] == (True, None)      # stronger than the move: kept
    assert out[("channel_delay", 3)] == (True, None)      # the move's own channel: kept
    assert out[("sensor_position", 0)] == (True, None)    # a move that rejected a constant is not a shadow
    assert out[("wave_speed", None)] == (True, None)      # not a channel's timing


def test_nothing_changes_without_a_move_with_the_evidence():
    base = [cand("sensor_position", 3, 18.2, False), cand("channel_delay", 1, 15.2, True)]
    assert run(base, evident={("channel_delay", 1)})[("channel_delay", 1)] == (True, None)   # move under the bar
    base = [cand("sensor_position", 3, 18.2, False, offset_mm=60.0), cand("channel_delay", 1, 15.2, True)]
    assert run(base, move_bound=30.0)[("channel_delay", 1)] == (True, None)   # beyond a re-glued disc
    base = [cand("sensor_position", 3, 18.2, False), cand("channel_delay", 1, 15.2, True)]
    assert run(base, unabsorbed={3: {}})[("channel_delay", 1)] == (True, None)   # a flagged channel
    base = [cand("sensor_position", 3, 18.2, True), cand("channel_delay", 1, 15.2, True)]
    assert run(base)[("channel_delay", 1)] == (True, None)   # the move itself is named: nothing blocked


def test_the_rule_never_names_anything():
    results = [cand("sensor_position", 3, 18.2, False), cand("channel_delay", 1, 15.2, False),
               cand("channel_delay", 3, 12.3, False)]
    assert not any(sig for sig, _ in run(results).values())


def test_a_channels_own_delay_or_lowpass_with_the_ratio_evidence_outranks_the_others_delays():
    """A debonded channel (late picks growing with distance, on a few cases): its low-pass and delay have the
    held-out ratio but miss the per-case t-test; the equal delays the centring gives the three other channels
    are its shadow, not three delays (the round after the gain, on a narrow strip's 8 cases)."""
    bound = 6.3   # ln(28 / 0.05)

    def results(lp_score=72.1, lp_material=True):
        lp = cand("channel_lowpass", 3, lp_score, False)
        lp.material = lp_material
        return [lp, cand("channel_delay", 2, 7.2, True), cand("channel_delay", 1, 4.8, False),
                cand("wave_speed", None, 7.0, True)]

    out = run(results(), evident=set())
    assert out[("channel_delay", 2)] == (True, None)      # without the ratio bound: as before
    MD.shadows_of_a_stronger_channel(r := results(), set(), 40.0, {}, bound)
    got = {(c.effect, c.sensor): (c.significant, c.shadow_of) for c in r}
    assert got[("channel_delay", 2)] == (False, 3)        # the shadow of channel 3's low-pass
    assert got[("wave_speed", None)] == (True, None)      # not a channel's timing
    assert got[("channel_lowpass", 3)] == (False, None)   # the rule names nothing
    for weak in (results(lp_score=5.0), results(lp_material=False)):   # under the bound; not material
        MD.shadows_of_a_stronger_channel(weak, set(), 40.0, {}, bound)
        assert [c.significant for c in weak if c.effect == "channel_delay"] == [True, False]
    own = [cand("channel_delay", 3, 48.7, False), cand("channel_delay", 3, 7.0, True)]
    MD.shadows_of_a_stronger_channel(own, set(), 40.0, {}, bound)
    assert own[1].significant                             # its own channel: not a shadow
