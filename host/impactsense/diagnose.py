"""Close the loop: residuals of a session against a reference model, the effect that explains them, the
error before and after adding it.

The reference (calibrated on DATA_REF) is the physics model of `residuals` plus its site terms
(`site_reference`: each channel's ToA and log-energy residual as smooth functions of the impact's position
and height, learned on DATA_REF, with cross-fitted residual scales), so an unchanged session sits at the
pick noise and a few-µs signature stands out.

Selection (forward, greedy): every candidate (effect x sensor) is fitted on 4/5 of the cases and scored on
the held-out fifth (5 folds, split by case so repetitions never straddle train and test). The score is
the held-out log-likelihood gain over the current model, summed over drops (nats). A candidate is
significant when (1) its per-case held-out gains are positive by a one-sided t-test at
alpha / n_candidates (Bonferroni over the ~28 candidates of a round, family-wise alpha = 0.05), or its
held-out likelihood ratio exceeds n_candidates / alpha (a move: its square, `move_or_delay.MOVE_EVIDENCE_SCALE`)
with the t-test at plain alpha (`_evidence`; the ratio with each group's gain over its design effect, the
reference's own cross-fitted intra-case correlation: `case_correlation`), (2) it is
material (its size exceeds the rig tolerance the effect states) and (3) for an effect that contains a
simpler one (`Effect.nests`) it also beats that simpler one by the same test. Rivals (`RIVALS`: a moved
sensor and a constant delay on the same channel) are told apart by the one thing that differs between them:
a delay is constant over the impacts, a move's timing change depends on the direction to each impact
(`effects.sensor_position.direction_test`: the direction-dependent part's Wald test, with case-clustered
errors and the reference's own uncertainty) at ALPHA; a delay shifts the channel's whole recording, so its
threshold and band picks (`band_timing`) alike, where a move shifts each by its own slowness
(`effects.sensor_position.band_test`, at ALPHA: what tells a move along a disc's look direction, nearly a
constant to the direction test); or the move's held-out likelihood gain over the delay by the evidence rule
(three tests of the one null "a constant": each at ALPHA). Both pick sets in one regression, a constant shared
(`effects.sensor_position.joint_test`), is reported, not decided on. A move is named only when one of them
rejects the constant and the delay does not predict the held-out threshold and band picks better by n_candidates
/ ALPHA (`move_or_delay`: a sub-sample delay's drop-dependent picks); the delay is then not named (where the
delay has the evidence and the move not, a rejected constant names the move). Where none does, the delay (fewer
parameters) is named, unless the move beats it on a held-out figure (picks; picks and log-energies at the moved
disc) by 2 n_candidates / ALPHA (`move_or_delay`: a move along the look direction, or with evidence but no test).
p-values and `ambiguous` in the report, with the held-out log-likelihood difference of the two. The best
significant candidate is added to the model (parameters refitted on all drops) and the search repeats; it stops
when nothing is significant (then: `none`). 95 % intervals: delete-a-fold jackknife over the 5 folds x t(4)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from . import residuals as R
from .data import Session
from .effects import EFFECTS
from .effects.sensor_position import band_test, direction_test, joint_test
from . import move_or_delay as MD
from . import case_correlation as CC

ALPHA = 0.05   # family-wise, Bonferroni over the candidates of a round
FOLDS = 5
MAX_EFFECTS = 6
PROBE_DROPS = 48
RIVALS = {"sensor_position": "channel_delay", "channel_delay": "sensor_position"}
# A re-glued disc lands near its mark: a sensor move larger than this fraction of the nearest declared sensor
# spacing is not named as a move (a debonded channel's filtered, late arrivals fit one of ~100 mm); its channel
# is reported as one the models cannot absorb (`unabsorbed_channels`: the three-sensor models, flagged).
MAX_MOVE_FRACTION = 0.25


def max_move_mm(sensor_xy_mm) -> float:
    """The largest sensor move `select` names: MAX_MOVE_FRACTION x the nearest declared sensor spacing."""
    s = np.asarray(sensor_xy_mm, float)
    d = np.hypot(*(s[:, None, :] - s[None, :, :]).transpose(2, 0, 1))
    return float(MAX_MOVE_FRACTION * d[np.triu_indices(len(s), 1)].min())


@dataclass
class Candidate:
    effect: str
    sensor: int | None
    params: dict
    score: float
    p_value: float
    material: bool
    significant: bool
    fold_params: list
    rival: dict | None = None   # the rival on the same sensor: its name, held-out gain difference, p
    shadow_of: int | None = None   # not named: a stronger channel's move (delay, low-pass) outranks it (`move_or_delay.shadows_of_a_stronger_channel`)
    tempered: float | None = None   # the score with each group's gain over its design effect (`case_correlation`); None: score

    @property
    def markov_score(self) -> float:
        """The held-out ratio the evidence rule's Markov half reads: the tempered score where one is known."""
        return self.score if self.tempered is None else self.tempered


def case_folds(case_id: np.ndarray, k: int = FOLDS, seed: int = 0) -> list[np.ndarray]:
    """k folds of whole cases (shuffled by seed); a session of fewer than k cases: one case a fold (no empty
    fold: its NaN figures made the out-of-fold 'after' NaN on a 4-case session)."""
    cases = np.unique(case_id)
    rng = np.random.default_rng(seed)
    rng.shuffle(cases)
    groups = np.array_split(cases, min(k, cases.size))
    return [np.flatnonzero(np.isin(case_id, g)) for g in groups]


def _case_sums(gain: np.ndarray, case_id: np.ndarray) -> np.ndarray:
    _, inv = np.unique(case_id, return_inverse=True)
    return np.bincount(inv, weights=gain)


def _one_sided_p(case_gains: np.ndarray) -> float:
    if case_gains.size < 3 or np.allclose(case_gains, 0):
        return 1.0
    if np.std(case_gains) == 0:
        return 0.0 if case_gains.mean() > 0 else 1.0
    t = stats.ttest_1samp(case_gains, 0.0, alternative="greater")
    return float(t.pvalue)


def _evidence(score: float, p_value: float, n_cands: int, scale: float = 1.0, tempered: float | None = None) -> bool:
    """Significant: the per-case held-out gains pass the Bonferroni t-test, or the held-out likelihood ratio
    itself exceeds n_cands / alpha (exp(score): under no change its expectation is at most 1, so by Markov's
    inequality each candidate passes with probability <= alpha / n_cands) with the per-case gains positive at
    plain alpha (the gain is not one case's doing). tempered: the ratio with each group's gain divided by its
    design effect (`case_correlation`: one case's drops share the reference's error, so exp(score) alone has
    an expectation above 1); the Markov half reads the smaller of score / scale and tempered."""
    if score <= 0:
        return False
    ratio = score / scale if tempered is None else min(score / scale, tempered)
    return p_value < ALPHA / n_cands or (ratio >= np.log(n_cands / ALPHA) and p_value < ALPHA)


def _own_evidence(c: Candidate, n_cands: int, plain: bool = False) -> bool:
    """The candidate's evidence against no change (`_evidence` at its own scale, on its tempered ratio unless
    plain: the plain Markov half decides who outranks a weaker channel's delay, a rule that only takes names
    away) and its size material."""
    scale = MD.own_evidence_scale(c.effect)
    return _evidence(c.score, c.p_value, n_cands, scale, None if plain else c.tempered) and c.material


def evaluate(ref: R.Reference, F: R.Features, folds, effect_name: str, sensor, deff=None, shared=None, params=None):
    """Held-out per-drop log-likelihood gain of one candidate over `ref`, its per-fold params and (deff given) the summed
    gain, each group's part over its design effect (the candidate's own: `case_correlation.candidate_design_effects`)."""
    eff = EFFECTS[effect_name]
    deff = CC.candidate_design_effects(deff, ref, None if params is None else eff.add(ref, sensor, params), F, shared)
    gain = np.zeros(len(F))
    tempered = np.zeros(len(F))
    fold_params = []
    for test in folds:
        train = np.setdiff1d(np.arange(len(F)), test)
        Ftr, Fte = F.subset(train), F.subset(test)
        params = eff.fit(ref, Ftr, sensor)
        fold_params.append(params)
        new, old = eff.add(ref, sensor, params).ll_groups(Fte), ref.ll_groups(Fte)
        groups = {g: new[g] - old[g] for g in new}
        gain[test] = sum(groups.values())
        if deff:
            tempered[test] = CC.tempered(groups, deff)
    return gain, fold_params, (float(tempered.sum()) if deff else None)


def build(ref: R.Reference, F: R.Features, chosen: list[tuple], sweeps: int = 4):
    """The reference with the chosen (effect, sensor) additions fitted jointly by backfitting: each one is
    refitted with all the others in place, a few sweeps (single-channel fits are otherwise biased by the
    other channels' offsets through the per-drop centring). Returns (model, params list)."""
    params = [None] * len(chosen)
    for sweep in range(sweeps if len(chosen) > 1 else 1):
        for j, (name, sensor) in enumerate(chosen):
            m = ref
            for k, (n2, s2) in enumerate(chosen):
                if k != j and params[k] is not None:
                    m = EFFECTS[n2].add(m, s2, params[k])
            params[j] = EFFECTS[name].fit(m, F, sensor)
    m = ref
    for (name, sensor), p in zip(chosen, params):
        m = EFFECTS[name].add(m, sensor, p)
    return m, params


def select(ref: R.Reference, F: R.Features, progress=None, max_effects: int = MAX_EFFECTS,
           unabsorbed: dict | None = None):
    """Forward selection of effects. Returns (accepted candidates in order, final model, last round).
    unabsorbed (filled when given): sensor -> the move the data asked for beyond `max_move_mm` (not named)."""
    folds = case_folds(F.case_id)
    move_bound = max_move_mm(ref.sensor_xy_mm)
    unabsorbed = {} if unabsorbed is None else unabsorbed
    accepted: list[Candidate] = []
    current = ref
    last_round: list[Candidate] = []
    cands = [(n, s) for n, e in EFFECTS.items() for s in e.candidates()]
    deff, shared = CC.session_design_effects(ref, F)   # per group; the site terms' error shared between cases
    for round_ in range(max_effects):
        gains = {}
        results = []
        for name, sensor in cands:
            if progress:
                progress(f"round {round_ + 1}: {name} {sensor}")
            params = EFFECTS[name].fit(current, F, sensor)
            g, fp, gt = evaluate(current, F, folds, name, sensor, deff, shared, params)
            gains[(name, sensor)] = g
            p = _one_sided_p(_case_sums(g, F.case_id))
            results.append(Candidate(name, sensor, params, float(g.sum()), p,
                                     bool(EFFECTS[name].material(params)), False, fp, tempered=gt))
        both = MD.move_over_delay_on_both_picks(current, F, folds, results, gains)
        delay_better = {k: -float(v.sum()) >= np.log(len(cands) / ALPHA) for k, v in both.items()}
        with_energy, move_better = MD.held_out_figures(current, F, folds, results, both, len(cands), ALPHA)
        direction = {}   # per sensor: the move-or-delay tests of its timing change (`direction_test`, `band_test`)
        evident = set()  # (effect, sensor) with the evidence against no change, before the move-or-delay rules
        outranks = {(c.effect, c.sensor) for c in results if _own_evidence(c, len(cands), plain=True)}
        too_far = []     # moves the data ask for beyond a re-glued disc's: the strongest one's channel is flagged
        for c in results:
            ok = _own_evidence(c, len(cands))
            if ok:
                evident.add((c.effect, c.sensor))
            nest = EFFECTS[c.effect].nests
            if ok and nest is not None and (nest, c.sensor) in gains:
                diff = gains[(c.effect, c.sensor)] - gains[(nest, c.sensor)]
                ok = _one_sided_p(_case_sums(diff, F.case_id)) < ALPHA / len(cands)
            if ok and c.effect in RIVALS and c.sensor is not None and c.sensor not in direction:
                direction[c.sensor] = {**direction_test(current, F, c.sensor),
                                       "band": band_test(current, F, c.sensor),
                                       "joint": joint_test(current, F, c.sensor)}
            if ok and c.effect == "sensor_position":   # a move only where the data reject a constant
                ok = _constant_rejected(direction[c.sensor]) and not delay_better.get(c.sensor, False)
                if not ok and ("channel_delay", c.sensor) in gains:   # ... or its held-out gain over it does
                    diff = gains[(c.effect, c.sensor)] - gains[("channel_delay", c.sensor)]
                    ok = (_evidence(float(diff.sum()), _one_sided_p(_case_sums(diff, F.case_id)), len(cands))
                          or (c.sensor in move_better and not delay_better.get(c.sensor, False)))
            if ok and c.effect == "sensor_position" and c.params["offset_mm"] > move_bound:
                ok = False    # larger than a re-glued disc can be: the channel is not a moved disc
                too_far.append(c)
            c.significant = bool(ok)
        _flag_strongest(results, too_far, unabsorbed, move_bound)
        _move_where_a_constant_is_rejected(results, direction, move_bound, unabsorbed, delay_better)
        MD.name_the_move_over_a_delay(current, F, folds, results, both, move_bound, unabsorbed, ALPHA, with_energy)
        MD.name_the_delay_of_an_evident_move(results, evident, len(cands), ALPHA)
        moved = {c.sensor for c in results if c.effect == "sensor_position" and c.significant}
        for c in results:   # a constant the data reject on its channel is not named there: the move is
            if c.effect == "channel_delay" and c.sensor in moved:
                c.significant = False
        MD.shadows_of_a_stronger_channel(results, outranks, move_bound, unabsorbed, np.log(len(cands) / ALPHA))
        _record_rivals(results, gains, direction, moved, F.case_id, both)
        MD.record_with_energy(results, with_energy)
        results.sort(key=lambda c: -c.score)
        last_round = results
        best = next((c for c in results if c.significant), None)
        if best is None:
            break
        accepted.append(best)
        current = _refit(ref, F, accepted)
        # a move the joint refit took beyond the bound: out, its channel flagged; a flagged channel's timing out
        for c in accepted:                                                     # from here on (docs/method.md 6 (h))
            if c.effect == "sensor_position" and c.params["offset_mm"] > move_bound:
                _flag(unabsorbed, c, move_bound)
        kept, flagged_now = MD.leave_out_flagged_timing(ref, accepted, unabsorbed, move_bound)
        if len(kept) != len(accepted) or flagged_now:
            accepted = kept
            current = _refit(ref, F, accepted) if accepted else ref
    return accepted, current, last_round


def _record_rivals(results, gains: dict, direction: dict, moved: set, case_id, both: dict) -> None:
    """Each move and delay candidate's rival record: the held-out gain over its rival on the same sensor, the
    same on both pick sets (`move_over_delay_on_both_picks`, signed as the candidate over its rival), the
    move-or-delay tests' p-values, ambiguous (no move named on the channel) and a shadow's stronger channel."""
    for c in results:
        rv = RIVALS.get(c.effect)
        if rv is None or (rv, c.sensor) not in gains:
            continue
        diff = gains[(c.effect, c.sensor)] - gains[(rv, c.sensor)]
        c.rival = {"effect": rv, "score_difference": float(diff.sum()),
                   "p_value": _one_sided_p(_case_sums(diff, case_id))}
        if c.sensor in both:
            sign = 1.0 if c.effect == "sensor_position" else -1.0
            c.rival["both_picks_score_difference"] = sign * float(both[c.sensor].sum())
        if c.sensor in direction:
            c.rival["direction_p_value"] = direction[c.sensor]["p_value"]
            c.rival["band_p_value"] = direction[c.sensor]["band"]["p_value"]
            c.rival["joint_p_value"] = direction[c.sensor]["joint"]["p_value"]
            c.rival["ambiguous"] = c.sensor not in moved   # neither test rejects a constant
        if c.shadow_of is not None:   # a stronger channel's move outranked it (not named)
            c.rival["shadow_of_sensor"] = c.shadow_of


def prepared_reference(baseline: Session):
    """The reference diagnose fits on a baseline it diagnoses another session against: the picks `choose_picker`
    chooses, the band picks (`band_timing`) and their law, the probe, the site terms at the noise floor with sigma and
    the case ICC. Returns (ref, Fb, picker, picker_trials, band): band is the band picks' setting (None without)."""
    from dataclasses import replace

    from .band_timing import band_picks, band_setting, fit_band
    from .site_reference import choose_picker, noise_floor

    Fb = R.extract(baseline)
    picker, picker_trials = choose_picker(baseline, Fb)   # the picks whose reference explains held-out drops best
    if picker is not None:
        Fb = R.repick(baseline, Fb, picker)
    ref = R.fit_reference(Fb, "calibrated")
    band = band_setting(Fb, ref.slowness_us_per_mm)   # a move shifts band and threshold picks by their own slowness
    if band is not None:
        Fb = replace(Fb, toa_band_us=band_picks(baseline, picker, band))
        fitted = fit_band(ref, Fb)
        ref.band = None if fitted is None else {**fitted, "setting": band}
    ref.probe = make_probe(baseline)
    ref.probe["picker"] = picker
    site, sigma, ref.case_icc = noise_floor(ref, Fb)   # the site terms ride with both sessions' features
    ref.sigma.update(sigma)
    ref.site = site
    return ref, Fb, picker, picker_trials, band


def session_features(ref: R.Reference, data: Session, picker, band):
    """A session's features as diagnose reads them against prepared_reference's ref: its picks, band picks, site terms."""
    from dataclasses import replace

    from .band_timing import band_picks

    Fn = R.extract(data, picker)
    if band is not None:
        Fn = replace(Fn, toa_band_us=band_picks(data, picker, band))
    return ref.site.attach(Fn)


def _move_where_a_constant_is_rejected(results, direction: dict, move_bound: float, unabsorbed: dict,
                                       delay_better: dict) -> None:
    """Marks significant the move on a channel whose delay has the evidence and the move not, where the tests reject
    a constant and the delay is not the better held-out (`delay_better`): the channel changed, not by a constant."""
    passed = {(c.effect, c.sensor) for c in results if c.significant}
    for c in results:
        if (c.effect == "sensor_position" and not c.significant and ("channel_delay", c.sensor) in passed
                and c.material and c.params["offset_mm"] <= move_bound and c.sensor not in unabsorbed):
            c.significant = _constant_rejected(direction[c.sensor]) and not delay_better.get(c.sensor, False)


def _constant_rejected(tests: dict) -> bool:
    """A channel's timing change is not a constant: the direction test or the band test
    (`effects.sensor_position`) rejects a constant at ALPHA. The joint test of both pick sets is reported with
    them, not decided on: on measured drops at other positions than the reference's it rejected a constant
    for a pure delay (docs/findings.md, "both pick sets in one test")."""
    return bool(min(tests["p_value"], tests["band"]["p_value"]) < ALPHA)


def _refit(ref, F, accepted):
    """`build` of the accepted candidates; their params updated. Returns the model."""
    current, params = build(ref, F, [(c.effect, c.sensor) for c in accepted])
    for c, p in zip(accepted, params):
        c.params = p
    return current


def _flag_strongest(results, too_far: list, unabsorbed: dict, move_bound: float) -> None:
    """Flags, of the moves beyond the bound this round, the channel whose move has the most evidence (the
    others' asks are its misfit spread by the per-drop centring; not the first in channel order), and names no
    move on a flagged channel (its timing is not a disc's; a delay may still take its mean lag)."""
    if too_far:
        _flag(unabsorbed, max(too_far, key=lambda c: c.score), move_bound)
    for c in results:
        if c.effect == "sensor_position" and c.sensor in unabsorbed:
            c.significant = False


def _flag(unabsorbed: dict, c: Candidate, move_bound: float) -> None:
    """Records channel c.sensor as one whose change the models cannot absorb (a move beyond move_bound): one
    channel at most (the three-sensor models leave one out; a second one's large move is the first one's
    misfit spread by the per-drop centring, not named either)."""
    if not unabsorbed:
        unabsorbed[c.sensor] = {"sensor": c.sensor, "effect": c.effect, "params": _jsonable(c.params),
                                "param_ci95": _param_ci(c, _param_se(c)), "max_move_mm": move_bound,
                                "score": c.score}


def out_of_fold_metrics(ref: R.Reference, F: R.Features, accepted: list[Candidate]) -> dict:
    """Metrics of the model with the accepted effects, each fold scored with effects fitted on the others."""
    folds = case_folds(F.case_id, seed=1)
    sq, mae, en, n, ne = 0.0, 0.0, 0.0, 0, 0
    for test in folds:
        train = np.setdiff1d(np.arange(len(F)), test)
        Ftr, Fte = F.subset(train), F.subset(test)
        m, _ = build(ref, Ftr, [(c.effect, c.sensor) for c in accepted])
        k = R.metrics(m, Fte)
        sq += k["dtoa_rms_us"] ** 2 * len(test)
        mae += k["mae_mm"] * len(test)
        nen = int((~m.clip_mask(Fte)).sum())
        en += k["energy_rms"] ** 2 * nen
        n += len(test)
        ne += nen
    return {"mae_mm": mae / n, "dtoa_rms_us": float(np.sqrt(sq / n)), "energy_rms": float(np.sqrt(en / ne))}


def make_probe(session: Session, n: int = PROBE_DROPS, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    rows = np.sort(rng.choice(len(session), size=min(n, len(session)), replace=False))
    return {"session": session.subset(rows)}


def _jsonable(v):
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (np.floating, float)):
        return float(v)
    if isinstance(v, (np.integer, int)):
        return int(v)
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    return v


def _param_se(c: Candidate) -> dict:
    """Delete-a-fold jackknife standard error of each parameter over the case folds."""
    out = {}
    for k in c.params:
        vals = np.array([fp[k] for fp in c.fold_params if isinstance(fp.get(k), (int, float))], float)
        if len(vals) > 1:
            n = len(vals)
            out[k] = float(np.sqrt((n - 1) / n * np.sum((vals - vals.mean()) ** 2)))
    return out


def _param_ci(c: Candidate, se: dict) -> dict:
    """95 % interval of each parameter: value +- t(0.975, folds - 1) x jackknife standard error, the half-width
    at least the step of the grid the effect fits it on (`Effect.resolution`): the jackknife of a grid argmax is
    zero wherever every fold lands on one node, which says nothing of the data; and inside the parameter's
    physical domain (`Effect.bounds`: an amplitude near zero is not read below it) (docs/method.md section 6)."""
    t = float(stats.t.ppf(0.975, max(len(c.fold_params) - 1, 1)))
    effect = EFFECTS.get(c.effect)
    step = effect.resolution(c.params) if effect is not None else {}
    domain = effect.bounds(c.params) if effect is not None else {}
    half = {k: max(t * v, float(step.get(k, 0.0))) for k, v in se.items()}
    out = {}
    for k, h in half.items():
        if isinstance(c.params.get(k), (int, float)):
            lo, hi = domain.get(k, (-np.inf, np.inf))
            out[k] = [float(max(c.params[k] - h, lo)), float(min(c.params[k] + h, hi))]
    return out


def diagnose(baseline: Session, data: Session, progress=None, same: bool | None = None):
    """The whole loop. Returns (result dict in the JSON schema of issue 5, details for the report)."""
    if same is None:
        same = Path(baseline.path).resolve() == Path(data.path).resolve() and len(baseline) == len(data)
    if same:   # the first loop: the nominal reference on the session's own picks
        Fb = Fn = R.extract(baseline)
        picker, picker_trials = None, []
        ref = R.fit_reference(Fb, "nominal")
        ref.probe = make_probe(baseline)
        ref.probe["picker"] = picker
    else:
        ref, Fb, picker, picker_trials, band = prepared_reference(baseline)
        Fn = session_features(ref, data, picker, band)
    before = R.metrics(ref, Fn)
    unabsorbed: dict = {}
    accepted, final, last_round = select(ref, Fn, progress, unabsorbed=unabsorbed)
    before = R.metrics(ref, Fn) if ref.timing_out else before   # over the channels kept (a flagged one left out)
    after = out_of_fold_metrics(ref, Fn, accepted) if accepted else dict(before)
    effects = []
    for c in sorted(accepted, key=lambda c: -c.score):
        se = _param_se(c)
        effects.append({"effect": c.effect, "sensor": c.sensor, "params": _jsonable(c.params),
                        "score": c.score, "significant": True, "p_value": c.p_value,
                        "param_se": se, "param_ci95": _param_ci(c, se), "units": EFFECTS[c.effect].units,
                        "rival": c.rival})
    if not effects:
        effects.append({"effect": "none", "sensor": None, "params": {}, "score": 0.0,
                        "significant": False})
    # the strongest rejected candidate of each family, for the record (never significant)
    seen = {(e["effect"], e["sensor"]) for e in effects}
    families = set()
    for c in last_round:
        if c.significant or c.effect in families or (c.effect, c.sensor) in seen:
            continue
        families.add(c.effect)
        effects.append({"effect": c.effect, "sensor": c.sensor, "params": _jsonable(c.params),
                        "score": c.score, "significant": False, "p_value": c.p_value,
                        "units": EFFECTS[c.effect].units, "rival": c.rival})
    result = {"effects": effects, "before": before, "after": after,
              # channels whose change the effects cannot describe (a move beyond a re-glued disc's): the
              # models leave them out (three-sensor position and class), flagged
              "unabsorbed_channels": [unabsorbed[k] for k in sorted(unabsorbed)],
              "baseline": str(baseline.path), "data": str(data.path),
              "reference": "nominal (first loop)" if same else "calibrated on the baseline",
              "core_config": {**R.timing_picker(picker), "rig_delay_us": _jsonable(final.delay_us)},
              "timing_picker": _jsonable(picker), "timing_picker_trials": _jsonable(picker_trials),
              "model": {"velocity_m_s": final.velocity_m_s, "sensor_xy_mm": _jsonable(final.sensor_xy_mm),
                        "gain": _jsonable(np.exp(final.gain_log / 2)), "anisotropy": _jsonable(final.aniso),
                        "decay_per_s": final.decay0_per_s}}
    from .residual_dependence import dependence, repeatability

    result["residuals"] = {"dependence_before": dependence(ref, Fn), "dependence_after": dependence(final, Fn),
                           "repeatability": repeatability(Fn),
                           "noise_rms_counts": np.exp(np.median(Fn.log_noise, axis=0)).tolist(),
                           "hum_counts_50_60hz": np.sqrt((Fn.hum_counts ** 2).mean(axis=0)).tolist(),
                           "clipped_drops": Fn.clipped.sum(axis=0).tolist()}
    details = {"ref": ref, "final": final, "F": Fn, "accepted": accepted}
    return _jsonable(result), details


# ---- report ----------------------------------------------------------------------------------------
def write_report(result: dict, details: dict, out_dir: str | Path, loop: dict | None = None) -> Path:
    """summary.md, the figures and report.html (self-contained) in out_dir: see `impactsense.loop_report`."""
    from .loop_report import write_report as _write

    return _write(result, details, out_dir, loop)
