"""The evidence rule's design effect (`impactsense.case_correlation`): one case's drops share their error, and
a held-out likelihood ratio summed over them breaks Markov's bound unless divided by 1 + (m - 1) ICC."""

import numpy as np

from impactsense import case_correlation as CC

BOUND = np.log(28 / 0.05)   # the Markov half's ln(n_candidates / alpha)


def _clustered(rng, cases, m, icc, channels=4):
    case = np.repeat(np.arange(cases), m)
    r = (np.sqrt(icc) * rng.standard_normal((cases, channels))[case]
         + np.sqrt(1 - icc) * rng.standard_normal((cases * m, channels)))
    return r, case


def test_the_intra_case_correlation_is_the_shared_share_of_the_variance():
    rng = np.random.default_rng(1)
    for icc in (0.0, 0.3, 0.6, 0.9):
        r, case = _clustered(rng, 200, 3, icc)
        assert abs(CC.intra_case_correlation(r, case) - icc) < 0.07, icc
    r, case = _clustered(rng, 200, 3, 0.6)
    r[::7, 1] = np.nan                              # missing picks are left out, not read as zeros
    assert abs(CC.intra_case_correlation(r, case) - 0.6) < 0.07
    assert CC.design_effects({"timing": 0.5, "energy": 0.0}, case) == {"timing": 2.0, "energy": 1.0}


def test_the_held_out_ratio_of_a_shift_that_is_not_there_needs_the_design_effect():
    """A null channel shift fitted on 4/5 of 40 cases x 3 drops (ICC 0.6, rig-b's cross-fitted timing ICC
    0.58) and scored on the held-out fifth: the plain ratio passes ln(28 / 0.05) more often than the
    alpha / n_candidates Markov's bound allows; the ratio over the design effect does not."""
    rng = np.random.default_rng(0)
    runs, cases, m, icc = 2000, 40, 3, 0.6
    plain, temp = np.zeros(runs), np.zeros(runs)
    for k in range(runs):
        r, case = _clustered(rng, cases, m, icc, channels=1)
        y = r[:, 0]
        gain = np.zeros(y.size)
        for fold in np.array_split(rng.permutation(cases), 5):
            test = np.isin(case, fold)
            d = y[~test].mean()
            gain[test] = -0.5 * ((y[test] - d) ** 2 - y[test] ** 2)   # unit scale: the total sd
        plain[k] = gain.sum()
        temp[k] = CC.tempered({"timing": gain}, CC.design_effects({"timing": icc}, case)).sum()
    allowed = 0.05 / 28
    assert np.mean(plain >= BOUND) > 2 * allowed
    assert np.mean(temp >= BOUND) <= allowed


def test_the_evidence_rule_reads_the_tempered_ratio():
    """`diagnose._evidence`: the measured rig-b s16 hum-control's false delay (8.58 nats, tempered 3.98 with the
    reference's timing design effect 2.15) has no evidence; a true delay's 19.3 nats (rig-b s6, loop16: tempered
    8.98) keeps it; the Bonferroni half (per-case p < alpha / n) is not tempered; a move reads the smaller of its
    own scale's and the tempered ratio."""
    from impactsense import diagnose as D
    from impactsense import move_or_delay as MD

    n, deff = 28, 2.15
    assert D._evidence(8.58, 0.04, n) and not D._evidence(8.58, 0.04, n, tempered=8.58 / deff)
    assert D._evidence(19.3, 0.04, n, tempered=19.3 / deff)
    assert D._evidence(8.58, 0.001, n, tempered=8.58 / deff)
    move = MD.own_evidence_scale("sensor_position")
    assert not D._evidence(14.8, 0.03, n, move, tempered=14.8 / 3.0)
    assert D._evidence(14.8, 0.03, n, move, tempered=14.8)           # no design effect: the scale's bound


def _smooth_cases(rng, cases, m, tau2, k, length):
    """Cases at random places on a unit square; each case's shared error is tau2 white plus a smooth part
    (RBF of `length`, variance k) that neighbouring cases share; drops add unit-variance noise."""
    xy = rng.uniform(0, 1, (cases, 2))
    d2 = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(axis=2)
    Kc = k * np.exp(-0.5 * d2 / length ** 2)
    case = np.repeat(np.arange(cases), m)
    return xy, Kc, case, np.linalg.cholesky(Kc + tau2 * np.eye(cases) + 1e-9 * np.eye(cases))


def test_a_signature_smooth_over_the_cases_carries_the_shared_error_between_cases_in_its_design_effect():
    """The timing design effect of a candidate is the variance of its signature's projection of the error over
    what independent drops would give: 1 + (m - 1) ICC plus the between-case share (off_case_site_cov's part).
    Checked against the projection's variance over 4,000 draws: a signature smooth over the plate (a global
    effect) picks up the shared error between cases; one that alternates between neighbouring cases does not
    (its between-case share is negative; the rule keeps the ICC's design effect)."""
    rng = np.random.default_rng(3)
    cases, m, tau2, k = 40, 3, 0.4, 0.6
    xy, Kc, case, L = _smooth_cases(rng, cases, m, tau2, k, 0.4)
    sigma2 = 1.0 + tau2 + k
    base = 1.0 + (m - 1) * (tau2 + k) / sigma2
    off = np.where(case[:, None] == case[None, :], 0.0, Kc[case][:, case])
    smooth = (xy[:, 0] - 0.5)[case][:, None]                       # a global, smooth signature
    rough = np.where(np.argsort(np.argsort(xy[:, 0])) % 2 == 0, 1.0, -1.0)[case][:, None]
    draws = 4000
    e = (L @ rng.standard_normal((cases, draws)))[case] + rng.standard_normal((cases * m, draws))
    def measured(delta):
        return float(np.var(delta[:, 0] @ e)) / (sigma2 * float(np.sum(delta ** 2)))

    predicted = CC.timing_design_effect(base, smooth, [off], np.sqrt(sigma2))
    assert abs(measured(smooth) - predicted) < 0.1 * predicted, (measured(smooth), predicted)
    assert predicted > 2 * base                                       # the ICC's design effect alone is far short
    # a rough signature: the shared error between cases partly cancels; the rule keeps the ICC's design effect
    # (it never tempers less than before), above what the projection measures
    assert CC.timing_design_effect(base, rough, [off], np.sqrt(sigma2)) == base
    assert measured(rough) < base
    assert CC.timing_design_effect(base, smooth, None, 1.0) == base                      # no site terms: as before
    assert CC.timing_design_effect(base, np.zeros_like(smooth), [off], 1.0) == base
