"""Move or delay on one channel, by what predicts the held-out picks: a moved disc's threshold and band picks
each change by their own slowness times the path change, a constant delay shifts both alike
(`diagnose.select` uses it beside the tests of "a constant" in `effects.sensor_position`; docs/method.md)."""

from __future__ import annotations

from .effects import EFFECTS
from .effects.sensor_position import band_ll


def move_over_delay_on_both_picks(current, F, folds, results, gains: dict) -> dict:
    """Per sensor, the held-out log-likelihood of its move minus its constant delay per drop (nats, each fold's
    fit scored on its held-out cases), on the threshold picks plus the band picks where the reference has them
    (the move's fit reads both: `effects.sensor_position`). The tests of "a constant" ask whether the channel's
    change varies over the impacts; this asks whether a moved disc is what varies: a delay that is not a whole
    number of samples moves a near-Nyquist onset's threshold picks by a drop-dependent amount the tests read as
    "not a constant" (docs/findings.md, loopmove7), and the move fitted to that scatter predicts the held-out
    picks worse than the delay. `select` names no move the tests alone would name where the delay's held-out
    likelihood ratio over it reaches n_candidates / ALPHA (Markov's bound, as in `_evidence`: were the move
    the truth, that happens with probability <= ALPHA / n_candidates)."""
    by_key = {(c.effect, c.sensor): c for c in results}
    base = band_ll(current, F)
    out = {}
    for (name, sensor), c in by_key.items():
        if name != "sensor_position" or ("channel_delay", sensor) not in by_key:
            continue
        diff = gains[(name, sensor)] - gains[("channel_delay", sensor)]
        if base is not None:
            for cand in (c, by_key[("channel_delay", sensor)]):
                sign = 1.0 if cand is c else -1.0
                for test, p in zip(folds, cand.fold_params):
                    diff[test] += sign * (band_ll(EFFECTS[cand.effect].add(current, sensor, p), F)[test] - base[test])
        out[sensor] = diff
    return out
