"""A plate stiffness change sized in E by the twin's own pick-velocity curve (issue 16's `wave_speed` -> E).

A pick is not one frequency's arrival: a threshold / AIC onset on a dispersive A0 arrival catches a cycle that
moves with E, the source's and the disc's bands hold the frequency back, and the twin's mesh has its own
dispersion; so the A0 curve's fixed-frequency law (`loop.e_scale_for_speed`, n = d ln v / d ln E ~ 0.3) is only
a first guess. And the threshold picks' law is not smooth in E: on a thin metal plate whose onset cycles arrive
near half the sampling rate, the pick slowness of a fixed set of drops is flat for the first 1-2 % of E and then
steep (docs/findings.md, issue 16 "E by the twin's own curve"). So E is read off the twin's own curves:

- the twin (the same FEM as the loop's) simulates DATA_NEW's declared drops (each distinct position once) at
  E x (1 + k step), k = 0, 1, 2, ... in the change's direction, each with a few draws of its noise (the same
  draws at every E), picked by diagnose's picker; each slowness statistic over those drops (the threshold
  picks' robust fit, the statistic the diagnosis measured the change with, and the band picks' travel law) is
  a curve s_twin(E);
- a reading is a target on a curve: DATA_NEW's own slowness on the same declared drops less the twin's miss on
  the reference session (DATA_REF's slowness over the twin's at DATA_REF's declared drops and the twin's E). At
  the same positions the position-dependent part of a pick's bias is in both, so it cancels; the diagnosis's
  change (data against the reference, measured on other positions) carries the two position sets' difference
  (docs/findings.md "E and D_s by the twin's own curves"), and is kept as a reading for the record only;
- E is where a least-squares line through the curve's points near the crossing meets the target; the readings'
  E are averaged with weights from their variance. The twin simulates the declared positions, the data land
  about them, so the twin's miss is not the same on two position sets; how much it differs is measured on
  DATA_REF alone (`position_set_sd`: its cases split into random halves, the twin's miss on one half less on the
  other, beyond what the twin's own noise draws show on the same halves, scaled to DATA_NEW's and DATA_REF's case
  counts); a reading's variance is the twin's draw-to-draw scatter plus that term.
A damping change is read the same way off the twin's decay curve (`damping_scale_scan`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

SCAN_STEP = 0.02          # the twin's E grid step (E_new / E_old - 1)
SCAN_MAX_STEPS = 10       # at most this many grid points beyond E (a change up to 20 % of E)
SCAN_PAST = 1             # grid points past the farthest crossing (the local line's other side)
SCAN_DRAWS = 6            # draws of the twin's noise at every E
SPLITS = 8                # random halves of DATA_REF's cases for the position-set term (position_set_sd)
MIN_SPLIT_CASES = 40      # fewer DATA_REF cases: no halves (a robust fit on a few drops is heavy-tailed), draws alone
LOCAL_HALF_WIDTH = 0.03   # ln E half-width of the least-squares line about the crossing
DAMPING_STEP = 0.1        # the twin's D_s grid step (D_s new / D_s old - 1)
DAMPING_MAX_STEPS = 5     # at most this many (a change up to 50 % of D_s; beyond, the local line extrapolates)


def pick_slowness(sessions, picker) -> float:
    """The picks' slowness (us/mm) by `picker` (diagnose's timing picker) over the sessions' drops together: the
    residual reference's robust fit."""
    from . import residuals as R

    F = [R.extract(s, picker) for s in sessions]
    F = dataclasses.replace(F[0], **{k: np.concatenate([getattr(f, k) for f in F]) for k in
                                     ("x_mm", "y_mm", "height_mm", "case_id", "order", "toa_us", "log_energy",
                                      "clipped", "log_centroid", "decay_per_s", "log_noise", "hum_counts",
                                      "plateau_hi", "plateau_lo", "pick_period")})
    return float(R.fit_reference(F, "calibrated").slowness_us_per_mm)


class Statistics:
    """The slowness statistics of a set of drops, as the diagnosis reads them: the threshold picks' (`pick`:
    the residual reference's robust fit) and, when DATA_REF has band picks (`band_timing.band_setting`), the
    band picks' (`band`: their travel law, `band_timing.fit_band`; a narrow band's arrival, whose law in E is
    the A0 curve's at one frequency and whose onset is not a near-Nyquist cycle)."""

    def __init__(self, base, picker):
        from . import residuals as R
        from .band_timing import band_setting

        self.picker = picker
        F = R.extract(base, picker)
        self.model = R.fit_reference(F, "calibrated")
        self.band = band_setting(F, self.model.slowness_us_per_mm)

    def __call__(self, session) -> dict:
        from . import residuals as R
        from .band_timing import band_picks, fit_band

        out = {"pick": pick_slowness([session], self.picker)}
        if self.band is not None:
            F = dataclasses.replace(R.extract(session, self.picker),
                                    toa_band_us=band_picks(session, self.picker, self.band))
            fitted = fit_band(self.model, F)
            if fitted is not None:
                out["band"] = fitted["slowness_us_per_mm"]
        return out


def twin_statistics(params, session, e_scale: float, stats, draws: int = SCAN_DRAWS, seed: int = 0,
                    workers: int = 2) -> dict:
    """{statistic: ln slowness per draw} of `session`'s declared drops simulated by the twin at E x e_scale (each
    distinct declared position simulated once; draw k of the twin's noise: seed + k); `stats` a callable
    session -> {statistic: slowness} (`Statistics`, or the threshold picks' alone)."""
    return _ln_statistics([stats(t) for t in twin_sessions(params, session, e_scale, draws, seed, workers)])


def _ln_statistics(rows: list) -> dict:
    """{statistic: ln slowness per row} of the statistics every row has."""
    return {key: np.log([r[key] for r in rows]) for key in rows[0] if all(key in r for r in rows)}


def twin_sessions(params, session, e_scale: float, draws: int = SCAN_DRAWS, seed: int = 0, workers: int = 2) -> list:
    """`session` with its recordings replaced by the twin's at its declared drops and E x e_scale (each distinct
    declared position simulated once), one session per draw of the twin's noise (draw k: seed + k)."""
    from .sim.simulate import simulate_voltages, to_adc

    where = np.stack([session.x_mm, session.y_mm, session.height_mm], 1)
    pos, inv = np.unique(where, axis=0, return_inverse=True)
    p = dataclasses.replace(params, e_pa=params.e_pa * e_scale)
    volts = simulate_voltages(p, session.rig, pos[:, 0], pos[:, 1], pos[:, 2], workers=workers)["volts"]
    volts = volts[np.asarray(inv).ravel()]
    return [dataclasses.replace(session, adc=to_adc(volts, p, session.rig, noise=True, seed=seed + k))
            for k in range(draws)]


def position_set_sd(base, twins: list, stats, new_cases: int, splits: int = SPLITS, seed: int = 0) -> dict:
    """{statistic: sd in ln s of a same-drop reading's position-set term}: the twin's miss (the data's ln s less
    the mean of the twin's `twins` draws at the declared positions) differs from one position set to another by
    the landing scatter about the declared positions (and by any noise the twin's draws do not have). Measured on
    DATA_REF alone: its cases split `splits` times into random halves A, B; d = miss_A - miss_B holds that term
    and the noise, the twin's draws' own d_k (each draw about the draws' mean, on the same halves) the noise alone;
    the excess, mean d^2 - (1 + 1/K) (mean d_k^2 K / (K - 1)) = 4 v / n_ref for a per-case variance v, is scaled
    to a reading's two sets, v (1 / new_cases + 1 / n_ref) (docs/method.md). Empty when DATA_REF has fewer than
    MIN_SPLIT_CASES cases or the twin fewer than two draws."""
    cases = np.unique(base.case_id)
    if cases.size < MIN_SPLIT_CASES or len(twins) < 2:
        return {}
    rng = np.random.default_rng(seed)
    data_d: dict = {}
    noise_d: dict = {}
    for _ in range(splits):
        half = rng.permutation(cases)[: cases.size // 2]
        sides = []
        for h in (half, np.setdiff1d(cases, half)):
            rows = np.flatnonzero(np.isin(base.case_id, h))
            data, twin = stats(base.subset(rows)), _ln_statistics([stats(t.subset(rows)) for t in twins])
            sides.append({k: (float(np.log(data[k]) - np.mean(v)), v - np.mean(v)) for k, v in twin.items()
                          if k in data})
        for k in sides[0].keys() & sides[1].keys():
            data_d.setdefault(k, []).append(sides[0][k][0] - sides[1][k][0])
            noise_d.setdefault(k, []).append(sides[0][k][1] - sides[1][k][1])
    K = len(twins)
    scale = cases.size / 4.0 * (1.0 / max(new_cases, 1) + 1.0 / cases.size)
    out = {}
    for k, d in data_d.items():
        noise = np.mean(np.square(noise_d[k])) * K / (K - 1)     # one draw's d variance
        out[k] = float(np.sqrt(max(np.mean(np.square(d)) - (1.0 + 1.0 / K) * noise, 0.0) * scale))
    return out


def crossing(ln_e: np.ndarray, ln_s: np.ndarray, target: float, half_width: float = LOCAL_HALF_WIDTH):
    """(ln E where the curve ln s(ln E) meets `target`, the local slope d ln s / d ln E): the crossing of the
    piecewise-linear curve farthest from E (the last one the grid passes; its nearest end when it passes none),
    then the least-squares line through the points within half_width of it (at least two)."""
    order = np.argsort(np.abs(ln_e))
    le, ls = np.asarray(ln_e, float)[order], np.asarray(ln_s, float)[order]
    at = le[int(np.argmin(np.abs(ls - target)))]
    for i in range(len(le) - 1):
        a, b = ls[i] - target, ls[i + 1] - target
        if a * b < 0 or a == 0:
            at = le[i] + (le[i + 1] - le[i]) * a / (a - b)
    near = np.abs(le - at) <= half_width + 1e-12
    if near.sum() < 2:
        near = np.isin(np.arange(len(le)), np.argsort(np.abs(le - at))[:2])
    slope, icpt = np.polyfit(le[near], ls[near], 1)
    if slope == 0:
        return float(at), 0.0
    return float((target - icpt) / slope), float(slope)


def _beyond(ln_s, target, sign) -> bool:
    """The grid has passed the target by SCAN_PAST points (in the change's direction)."""
    past = [i for i, v in enumerate(ln_s) if sign * (v - target) >= 0]
    return bool(past) and len(ln_s) - 1 - past[0] >= SCAN_PAST


def _targets(data, base, stats, twin_ref: dict, ln_s0: float, change_pct: float) -> dict:
    """{reading: (statistic, target ln slowness on the twin's curve)}: the diagnosis's change (`change`: the
    threshold picks' ln s at E less ln(1 + change)); with DATA_REF, each statistic's data reading (`pick`,
    `band`): DATA_NEW's ln s less the twin's miss on DATA_REF (its ln s over the twin's mean at DATA_REF's
    declared drops and E)."""
    out = {"change": ("pick", ln_s0 - float(np.log1p(change_pct / 100.0)))}
    if base is None:
        return out
    new, ref = stats(data), stats(base)
    for key in twin_ref:
        if key in new and key in ref:
            out[key] = (key, float(np.log(new[key]) - np.log(ref[key]) + np.mean(twin_ref[key])))
    return out


def e_scale_scan(params, data, picker, change_pct: float, base=None, ci=None, seed: int = 0,
                 workers: int = 2, draws: int = SCAN_DRAWS) -> dict:
    """E_new / E_old of the twin's plate from the twin's own pick-velocity curves on DATA_NEW's declared drops
    (the module doc). `change_pct` is the diagnosis's pick velocity change (data against DATA_REF), `ci` its 95 %
    interval; with `base` (DATA_REF) the data's own slowness statistics are read against the twin's at the same
    drops (`_targets`) and E is their mean weighted by each reading's variance (`reading_sd`: the twin's draw
    scatter plus the position-set term, over the curve's slope squared); without, the change's reading. Returns
    {"e_scale" (put in), "readings" {name: E scale}, "exponent" (-the local slope of the threshold picks' curve at
    the answer), "first_guess" (the A0 curve's), "e_scale_lo", "e_scale_hi", "curve": [(E scale, {statistic: mean slowness})], "reading_sd" {name: sd in ln E, what weighs it},
    "sd_terms" {name: {"draws", "positions"}}}."""
    from .loop import e_scale_for_speed

    stats = Statistics(base, picker) if base is not None else (lambda s: {"pick": pick_slowness([s], picker)})
    per = [twin_statistics(params, data, 1.0, stats, draws, seed, workers)]
    ln_s0 = float(np.mean(per[0]["pick"]))
    twin_ref, positions = {}, {}
    if base is not None:
        ref_twins = twin_sessions(params, base, 1.0, draws, seed, workers)
        twin_ref = _ln_statistics([stats(t) for t in ref_twins])
        positions = position_set_sd(base, ref_twins, stats, np.unique(data.case_id).size, seed=seed)
    targets = _targets(data, base, stats, twin_ref, ln_s0, change_pct)
    sign = 1.0 if change_pct < 0 else -1.0              # a slower pick: a larger slowness, a softer plate
    ln_e = [0.0]
    for k in range(1, SCAN_MAX_STEPS + 1):
        if all(_beyond([np.mean(q[key]) for q in per], t, sign) for key, t in targets.values()):
            break
        ln_e.append(float(np.log(1.0 - sign * k * SCAN_STEP)))
        per.append(twin_statistics(params, data, float(np.exp(ln_e[-1])), stats, draws, seed, workers))
    ln_e = np.array(ln_e)
    curves = {key: np.array([np.mean(q[key]) for q in per]) for key in per[0]}
    got = {name: crossing(ln_e, curves[key], t) for name, (key, t) in targets.items()}
    terms = {}
    for name, (key, _) in targets.items():
        if name != "change" and got[name][1] != 0:
            at = int(np.argmin(np.abs(ln_e - got[name][0])))
            terms[name] = {"draws": float(np.hypot(np.std(per[at][key], ddof=1), np.std(twin_ref[key], ddof=1))
                                          / abs(got[name][1]))}
            if key in positions:
                terms[name]["positions"] = positions[key] / abs(got[name][1])
    sd = reading_sd(terms)
    w = {name: 1.0 / max(v, 1e-6) ** 2 for name, v in sd.items()}
    answer = sum(w[n] * got[n][0] for n in w) / sum(w.values()) if w else got["change"][0]
    out = {"e_scale": float(np.exp(answer)), "readings": {n: float(np.exp(v[0])) for n, v in got.items()},
           "exponent": -got["pick" if "pick" in got else "change"][1],
           "first_guess": e_scale_for_speed(params, 1000.0 / float(np.exp(ln_s0)), change_pct),
           "curve": [(float(np.exp(e)), {k: float(np.exp(c[i])) for k, c in curves.items()})
                     for i, e in enumerate(ln_e)],
           "reading_sd": sd, "sd_terms": terms}
    out.update(_interval(answer, got, sd, ci))
    return out


def reading_sd(terms: dict) -> dict:
    """{reading: sd in ln E} from its terms (each in ln E): the twin's draw-to-draw scatter at the answer and at
    DATA_REF's drops (the noise) and the position-set term (`position_set_sd`, what the data's halves show beyond
    the twin's own), independent, so their variances add."""
    return {name: float(np.hypot(t["draws"], t.get("positions", 0.0))) for name, t in terms.items()}


def _interval(answer: float, got: dict, sd: dict, ci) -> dict:
    """e_scale_lo / e_scale_hi about the answer: the wider of the readings' own (1.96 x the smallest reading's
    sd: they share DATA_NEW's drops, so no narrowing is claimed for their mean) and the diagnosis's change
    interval through the threshold picks' curve at the answer. A reading's sd holds the drops' landing scatter
    about their declared positions where DATA_REF could be split (`reading_sd`); the change's fold jackknife
    sees every drop-level error, the position-dependent part included (an upper bound for a same-drop
    reading)."""
    half = 1.96 * min(sd.values()) if sd else 0.0
    slope = got["pick"][1] if "pick" in got else got["change"][1]
    if ci is not None and slope != 0:
        half = max(half, max(abs(np.log1p(c / 100.0) - np.log1p(c0 / 100.0)) for c, c0 in
                             zip(ci, (np.mean(ci), np.mean(ci)))) / abs(slope))
    if half <= 0:
        return {}
    return {"e_scale_lo": float(np.exp(answer - half)), "e_scale_hi": float(np.exp(answer + half))}


def decay_statistic(session, picker=None) -> float:
    """The drops' envelope decay rate (1/s): the median of the core's decay_per_s over drops and channels."""
    from . import residuals as R

    return float(np.nanmedian(R.extract(session, picker).decay_per_s))


def damping_scale_scan(params, data, picker, extra_decay_per_s: float, base=None, seed: int = 0,
                       workers: int = 2, draws: int = 3) -> dict:
    """D_s new / D_s old of the twin's plate from the twin's own decay curve on DATA_NEW's declared drops: the
    twin at D_s x (1 + k DAMPING_STEP) (k = 0, 1, ... in the change's direction), the drops' median envelope
    decay (`decay_statistic`) each; the target is DATA_NEW's own decay less the twin's miss on DATA_REF (with
    `base`), else the twin's decay at D_s plus the diagnosis's extra decay. Every mode decays as
    exp(-D_s t / 2), but the envelope 1-8 ms after the onset also holds the noise the faster decay reaches
    sooner, so the decay moves by less than D_s / 2 (docs/findings.md). Returns {"damping_scale", "readings"}."""
    def twin(session, scale):
        where = np.stack([session.x_mm, session.y_mm, session.height_mm], 1)
        pos, inv = np.unique(where, axis=0, return_inverse=True)
        p = dataclasses.replace(params, damping_per_s=params.damping_per_s * scale)
        from .sim.simulate import simulate_voltages, to_adc

        volts = simulate_voltages(p, session.rig, pos[:, 0], pos[:, 1], pos[:, 2], workers=workers)["volts"]
        volts = volts[np.asarray(inv).ravel()]
        return float(np.mean([decay_statistic(dataclasses.replace(session, adc=to_adc(volts, p, session.rig,
                                                                                      noise=True, seed=seed + k)),
                                              picker) for k in range(draws)]))

    values = [twin(data, 1.0)]
    targets = {"change": values[0] + extra_decay_per_s}
    if base is not None:
        targets["same_drops"] = decay_statistic(data, picker) - decay_statistic(base, picker) + twin(base, 1.0)
    sign = 1.0 if extra_decay_per_s > 0 else -1.0
    ln_d = [0.0]
    for k in range(1, DAMPING_MAX_STEPS + 1):
        if all(_beyond(values, t, sign) for t in targets.values()):
            break
        ln_d.append(float(np.log(1.0 + sign * k * DAMPING_STEP)))
        values.append(twin(data, float(np.exp(ln_d[-1]))))
    got = {n: float(np.exp(crossing(np.array(ln_d), np.array(values), t, 1.5 * DAMPING_STEP)[0]))
           for n, t in targets.items()}
    return {"damping_scale": got["same_drops" if "same_drops" in got else "change"], "readings": got}


def size_plate_change(params, data, accepted, picker, seed: int = 0, workers: int = 2, base=None) -> list:
    """`accepted` with each wave_speed candidate's E change sized by the twin's own curves (`e_scale_scan`;
    `base`: DATA_REF, for the data's readings against the twin at the same drops): its params gain e_scale
    (E_new / E_old, what `corrected_twin` puts in), e_scale_<reading> for each reading (change, pick, band),
    e_scale_sd_<reading> (the sd in ln E that weighs it), e_exponent (-d ln s / d ln E of the threshold picks'
    curve at the answer), e_scale_curve (the A0 curve's first guess) and e_scale_lo / e_scale_hi (the range of E
    a session's pick noise and landing scatter allow); and each damping
    candidate's D_s change by the twin's decay curve (`damping_scale_scan`): damping_scale (D_s new / D_s old,
    what `corrected_twin` puts in) and damping_scale_<reading>."""
    from .diagnose import _param_ci, _param_se

    out = []
    for c in accepted:
        if c.effect == "wave_speed" and "e_scale" not in c.params:
            ci = _param_ci(c, _param_se(c)).get("change_pct")
            scan = e_scale_scan(params, data, picker, c.params["change_pct"], base, ci, seed, workers)
            extra = {"e_scale": scan["e_scale"], "e_exponent": scan["exponent"], "e_scale_curve": scan["first_guess"]}
            extra.update({f"e_scale_{name}": v for name, v in scan["readings"].items()})
            extra.update({f"e_scale_sd_{name}": v for name, v in scan.get("reading_sd", {}).items()})
            extra.update({k: scan[k] for k in ("e_scale_lo", "e_scale_hi") if k in scan})
            c = dataclasses.replace(c, params={**c.params, **extra})
        elif c.effect == "damping" and "damping_scale" not in c.params:
            scan = damping_scale_scan(params, data, picker, c.params["extra_decay_per_s"], base, seed, workers)
            extra = {"damping_scale": scan["damping_scale"]}
            extra.update({f"damping_scale_{name}": v for name, v in scan["readings"].items()})
            c = dataclasses.replace(c, params={**c.params, **extra})
        out.append(c)
    return out
