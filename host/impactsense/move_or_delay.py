"""Move or delay on one channel, by what predicts the held-out picks: a moved disc's threshold and band picks
each change by their own slowness times the path change, a constant delay shifts both alike
(`diagnose.select` uses it beside the tests of "a constant" in `effects.sensor_position`; docs/method.md)."""

from __future__ import annotations

import numpy as np

from .effects import EFFECTS
from .effects.sensor_position import band_ll

# The Markov path of a move's own evidence (`diagnose._evidence`) at this multiple of ln(n_candidates / alpha):
# its bound assumes the reference predicts an unchanged session exactly; at an unchanged session's new
# positions it does not (docs/findings.md, falsealarm; an empirical calibration). 1.0: the plain Markov bound.
MOVE_EVIDENCE_SCALE = 2.0
# a channel's own timing changes besides a move (`shadows_of_a_stronger_channel`)
OWN_TIMING_CHANGES = ("channel_delay", "channel_lowpass")


def own_evidence_scale(effect: str) -> float:
    return MOVE_EVIDENCE_SCALE if effect == "sensor_position" else 1.0


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


def energy_of_the_move(current, F, folds, results) -> dict:
    """Per sensor, the held-out log-likelihood of the log-energies with the energy law's disc moved by the
    move's fold fit minus with it where it is (nats per drop): a moved disc changes each impact's path, and its
    energy by the geometric and attenuation law (alpha d + beta log d, `residuals.Reference.energy_resid`);
    a constant delay changes no energy (0 for the delay). Along the look direction the timing of a move is
    nearly a constant, its energy change near the disc is not (docs/findings.md, lookdir)."""
    out = {}
    base = current.ll_groups(F)["energy"]
    for c in results:
        if c.effect != "sensor_position":
            continue
        gain = np.zeros(len(F))
        for test, p in zip(folds, c.fold_params):
            m = current.copy()
            pos = (current.sensor_xy_mm if current.energy_sensor_xy_mm is None else current.energy_sensor_xy_mm)
            m.energy_sensor_xy_mm = np.array(pos, float).copy()
            m.energy_sensor_xy_mm[c.sensor] += [p["dx_mm"], p["dy_mm"]]
            gain[test] = m.ll_groups(F.subset(test))["energy"] - base[test]
        out[c.sensor] = gain
    return out


def move_over_delay_with_energy(current, F, folds, results, both: dict) -> dict:
    """`move_over_delay_on_both_picks` plus `energy_of_the_move`: the held-out log-likelihood ratio of the
    move over the constant delay on the threshold picks, the band picks and the log-energies (per drop)."""
    energy = energy_of_the_move(current, F, folds, results)
    return {k: v + energy[k] for k, v in both.items() if k in energy}


MOVE_BY_ENERGY = True   # `name_the_move_over_a_delay` renames (False: it only reports the ratio)
HELD_OUT_FIGURES = True   # `moves_by_held_out_figures` (False: none)
DELAY_OF_AN_EVIDENT_MOVE = True   # `name_the_delay_of_an_evident_move` (False: it names nothing)
EITHER_FIGURE = True    # the move's held-out figure over the delay: picks alone or picks and energies (False:
                        # picks and energies only, at ln(n_candidates / alpha))


def move_beats_delay(both: dict, with_energy: dict, n_candidates: int, alpha: float) -> set:
    """Sensors whose move predicts the held-out picks better than the constant delay by the evidence bound,
    on either of two figures: the threshold and band picks (`move_over_delay_on_both_picks`) or those plus the
    log-energies at the moved energy law (`move_over_delay_with_energy`). Two figures of one comparison,
    Bonferroni: each at ln(2 n_candidates / alpha) (Markov's bound: were the delay the truth, either ratio
    reaches it with probability <= alpha / n_candidates). The energy law's moved disc is the plate's far-field
    law; near a disc it can read a true move worse than the delay (docs/findings.md, loop16), so the picks
    alone are the other figure. EITHER_FIGURE False: the picks-and-energies figure at ln(n_candidates / alpha)."""
    if not EITHER_FIGURE:
        bound = np.log(n_candidates / alpha)
        return {k for k, v in with_energy.items() if float(v.sum()) >= bound}
    bound = np.log(2 * n_candidates / alpha)
    return {k for k in both if float(both[k].sum()) >= bound or float(with_energy.get(k, both[k]).sum()) >= bound}


def name_the_move_over_a_delay(current, F, folds, results, both: dict, move_bound: float, unabsorbed: dict,
                               alpha: float, ratio: dict | None = None) -> dict:
    """Names the move instead of the constant delay on a channel whose delay is named (it has the evidence of
    a change) where the move predicts the held-out picks (threshold and band), or those and the log-energies,
    better than the delay by the evidence bound (`move_beats_delay`). A move along the disc's look direction is
    nearly a constant to the tests of "a constant"; its band picks' and energies' change is not. It only
    renames a named delay: an unchanged session gains no name. Returns the picks-and-energies ratio per sensor
    (`move_over_delay_with_energy`; given as ratio when already computed)."""
    if ratio is None:
        ratio = move_over_delay_with_energy(current, F, folds, results, both)
    if not MOVE_BY_ENERGY:
        return ratio
    better = move_beats_delay(both, ratio, len(results), alpha)
    named_delay = {c.sensor for c in results if c.effect == "channel_delay" and c.significant}
    for c in results:
        if (c.effect == "sensor_position" and not c.significant and c.sensor in named_delay and c.material
                and c.params["offset_mm"] <= move_bound and c.sensor not in unabsorbed and c.sensor in better):
            c.significant = True
    return ratio


def record_with_energy(results, ratio: dict) -> None:
    """Each move and delay candidate's rival record gets the move-over-delay ratio on the picks and energies
    (`move_over_delay_with_energy`), signed as the candidate over its rival."""
    for c in results:
        if c.rival and c.sensor in ratio and c.effect in ("sensor_position", "channel_delay"):
            sign = 1.0 if c.effect == "sensor_position" else -1.0
            c.rival["picks_and_energy_score_difference"] = sign * float(ratio[c.sensor].sum())


def held_out_figures(current, F, folds, results, both: dict, n_candidates: int, alpha: float):
    """(`move_over_delay_with_energy`, the sensors whose move beats the delay by `move_beats_delay`) for
    `diagnose.select`: a move with its own evidence against no change that no test of a constant names is named
    where it beats the delay on a held-out figure (HELD_OUT_FIGURES False: the set is empty)."""
    with_energy = move_over_delay_with_energy(current, F, folds, results, both)
    return with_energy, (move_beats_delay(both, with_energy, n_candidates, alpha) if HELD_OUT_FIGURES else set())


def name_the_delay_of_an_evident_move(results, evident: set, n_candidates: int, alpha: float) -> None:
    """Names the constant delay on a channel whose move has the evidence against no change (in `evident`) but is
    not named (no test rejects a constant, neither held-out figure prefers the move) and whose delay's own
    held-out ratio reaches ln(n_candidates / alpha) (the Markov half of `diagnose._evidence`, read on the ratio
    tempered by the design effect where the reference has one: `Candidate.markov_score`; its per-case t-test
    can miss on heavy-tailed case gains): the channel changed, and of the two rivals the constant is the
    simpler. Only on a channel with such a move and no rival named: no name without the evidence of a change."""
    if not DELAY_OF_AN_EVIDENT_MOVE:
        return
    named = {c.sensor for c in results if c.significant and c.effect in ("sensor_position", "channel_delay")}
    bound = np.log(n_candidates / alpha)
    for c in results:
        if (c.effect == "channel_delay" and not c.significant and c.sensor not in named and c.material
                and ("sensor_position", c.sensor) in evident and c.markov_score >= bound):
            c.significant = True


def shadows_of_a_stronger_channel(results, evident: set, move_bound: float, unabsorbed: dict,
                                  ratio_bound: float | None = None) -> None:
    """A channel whose move has the evidence against no change but no test rejects a constant (so neither the
    move nor, without its own evidence, the delay is named) outranks the other channels' delays that score
    below it: those are not named this round (`Candidate.shadow_of`). The per-drop centring couples the
    channels' timing, so one channel's change gives another channel's constant delay a held-out gain of its
    own; without this rule the weaker shadow was named on the wrong sensor. It only takes names away (an
    unchanged session cannot gain one); a move that rejects a constant is not a shadow and stays.
    With ratio_bound (ln(n_candidates / alpha), the Markov half of `diagnose._evidence`): a channel's own delay or
    low-pass that is material and not named, whose held-out likelihood ratio reaches it (its per-case t-test
    missed: a low-pass's late picks grow with distance and fall on a few cases), outranks them too. A debonded
    channel's picks, late by tens of us, were otherwise named as equal delays on each of the three others."""
    moves = [c for c in results if c.effect == "sensor_position" and not c.significant
             and ("sensor_position", c.sensor) in evident and c.params["offset_mm"] <= move_bound
             and c.sensor not in unabsorbed]
    if ratio_bound is not None:
        moves += [c for c in results if c.effect in OWN_TIMING_CHANGES and not c.significant and c.material
                  and c.sensor is not None and c.score >= ratio_bound]
    for c in results:
        if not c.significant or c.effect != "channel_delay":
            continue
        stronger = [m for m in moves if m.sensor != c.sensor and m.score > c.score]
        if stronger:
            c.significant = False
            c.shadow_of = max(stronger, key=lambda m: m.score).sensor


TIMING_ONLY = ("channel_delay", "sensor_position")   # effects that change a channel's timing and nothing else


def leave_out_flagged_timing(ref, accepted: list, unabsorbed: dict, move_bound: float = np.inf) -> tuple[list, bool]:
    """(accepted less its moves beyond move_bound and the timing-only effects on flagged channels, whether a channel
    was newly flagged); sets
    `ref.timing_out` (in place) to the flagged channels. A flagged channel's picks are not a disc's (the retrained
    models leave it out: three-sensor position and class); kept in the per-drop centring, its misfit reaches the
    other channels as shadow delays and moves (a debonded disc's picks, late by 14-150 us growing with distance,
    named moves of 20-30 mm on two other sensors), and a delay on it would describe nothing the models use."""
    accepted = [c for c in accepted if not (c.effect == "sensor_position" and c.params["offset_mm"] > move_bound)]
    out = tuple(sorted(unabsorbed))
    if out == tuple(ref.timing_out):
        return accepted, False
    ref.timing_out = out
    return [c for c in accepted if not (c.effect in TIMING_ONLY and c.sensor in unabsorbed)], True
