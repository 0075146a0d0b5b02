"""How much the drops of one case share their error under the reference, and what that does to a held-out
likelihood ratio (the design effect of the evidence rule's Markov half, docs/method.md section 6 (f)).

The likelihood the selection scores candidates on treats every drop as independent. The repeated drops of one
case share the reference's error at that position (its site terms are smooth functions learned at other
positions) and their landing, so a candidate's held-out gain on those drops moves together. For a Gaussian
error with a shared part of variance tau^2 and a drop part omega^2 (sigma^2 = tau^2 + omega^2, m drops a
case), a held-out log-likelihood ratio S of a shift that is not there has E[exp(S / deff)] = 1 with the
design effect deff = 1 + (m - 1) ICC, ICC = tau^2 / sigma^2, where Markov's bound (E[exp(S)] <= 1) needs the
drops independent (deff 1). The intra-case correlation is measured on the reference session's own
cross-fitted residuals (`site_reference.cross_fitted`: each half's site terms learned on the other half, the
reference at positions it did not learn), per group of features the reference predicts by position."""

from __future__ import annotations

import numpy as np

from . import residuals as R

# the groups whose residuals depend on where the ball hit (the others - noise, hum, clipping - do not: ICC 0)
POSITION_GROUPS = ("timing", "energy", "band")


def intra_case_correlation(r: np.ndarray, case_id: np.ndarray) -> float:
    """One-way random-effects ICC of a per-drop residual [R, C] with drops grouped by case (the ANOVA
    estimator with unequal group sizes), pooled over the columns as the mean of their ICCs (each >= 0); NaN
    entries are left out; 0 when no column has two cases of two drops."""
    r = np.asarray(r, float)
    r = r[:, None] if r.ndim == 1 else r
    out = []
    for c in range(r.shape[1]):
        ok = np.isfinite(r[:, c])
        ids, g = np.unique(np.asarray(case_id)[ok], return_inverse=True)
        y = r[ok, c]
        n, G = y.size, ids.size
        if G < 2 or n - G < 1:
            continue
        m = np.bincount(g).astype(float)
        means = np.bincount(g, weights=y) / m
        msb = float(np.sum(m * (means - y.mean()) ** 2) / (G - 1))
        msw = float(np.sum((y - means[g]) ** 2) / (n - G))
        m0 = (n - np.sum(m ** 2) / n) / (G - 1)
        den = msb + (m0 - 1.0) * msw
        if den > 0:
            out.append(max(0.0, (msb - msw) / den))
    return float(np.mean(out)) if out else 0.0


def reference_icc(ref: R.Reference, Fx: R.Features) -> dict:
    """Per position group, the ICC of the reference's drop-centred residuals on cross-fitted features Fx
    (timing: ToA; energy: log-energy, clipped channels out; band: the band picks where the reference has them)."""
    from .band_timing import band_resid

    out = {"timing": intra_case_correlation(ref.toa_resid(Fx), Fx.case_id),
           "energy": intra_case_correlation(np.where(ref.clip_mask(Fx), np.nan, ref.energy_resid(Fx)),
                                            Fx.case_id)}
    rb = band_resid(ref, Fx) if getattr(ref, "band", None) else None
    if rb is not None:
        out["band"] = intra_case_correlation(rb, Fx.case_id)
    return out


def drops_per_case(case_id: np.ndarray) -> float:
    """The mean number of drops a case of the session has."""
    case_id = np.asarray(case_id)
    return float(case_id.size / max(np.unique(case_id).size, 1))


def design_effects(icc: dict | None, case_id: np.ndarray) -> dict:
    """Per group, deff = 1 + (m - 1) ICC with m the session's drops per case (groups without an ICC: 1)."""
    m = drops_per_case(case_id)
    return {g: 1.0 + (m - 1.0) * float(v) for g, v in (icc or {}).items()}


def tempered(gain_groups: dict, deff: dict) -> np.ndarray:
    """The per-drop held-out gain with each group's part divided by its design effect."""
    return sum(v / deff.get(g, 1.0) for g, v in gain_groups.items())


def off_case_site_cov(site, F: R.Features) -> list | None:
    """Per channel, the site terms' posterior covariance of the ToA between drops of different cases ([R, R] µs²,
    `site_reference.SiteTerms.toa_cov`; the same case's blocks zero: that share is in the ICC): how the reference's
    error at the session's positions is shared between neighbouring cases. None without site terms."""
    if site is None:
        return None
    case = np.asarray(F.case_id)
    same = case[:, None] == case[None, :]
    return [np.where(same, 0.0, site.toa_cov(F, c)) for c in range(4)]


def timing_design_effect(base: float, delta: np.ndarray, cov: list | None, sigma_us: float) -> float:
    """A candidate's timing design effect: base (1 + (m - 1) ICC) plus its signature's share of the reference's
    error shared between cases, sum_c delta_c' K_c delta_c / (sigma^2 |delta|^2), with delta [R, 4] the candidate's
    change of the drop-centred ToA residual at the session's drops (NaN rows left out) and K_c the off-case
    posterior covariance of channel c (`off_case_site_cov`). Gaussian, linear signature: the held-out ratio S of a
    candidate that is not there has E[exp(S / deff)] = 1 at deff = delta' Sigma delta / (sigma^2 |delta|^2)."""
    if cov is None:
        return base
    d = np.where(np.isfinite(delta), delta, 0.0)
    dd = float(np.sum(d * d))
    if dd <= 0.0 or not sigma_us > 0:
        return base
    shared = sum(float(d[:, c] @ cov[c] @ d[:, c]) for c in range(d.shape[1]))
    return base + max(shared, 0.0) / (sigma_us ** 2 * dd)


def candidate_design_effects(deff: dict | None, before: R.Reference, after: R.Reference | None, F: R.Features,
                             shared: list | None) -> dict | None:
    """The design effects a candidate's held-out gain is tempered by (`diagnose.select`): the groups' (`design_effects`)
    with the timing group's raised by the candidate's own signature's share of the error shared between cases
    (`timing_design_effect`; delta = the change of the drop-centred ToA residual from `before` to `after`, the
    reference with the candidate added at its fit on all drops; docs/method.md section 6 (g))."""
    if not deff or shared is None or after is None or "timing" not in deff:
        return deff
    delta = before.toa_resid(F) - after.toa_resid(F)
    return {**deff, "timing": timing_design_effect(deff["timing"], delta, shared, before.sigma["timing"])}


def session_design_effects(ref: R.Reference, F: R.Features) -> tuple[dict | None, list | None]:
    """(`design_effects` of ref's ICC at F's drops per case, `off_case_site_cov` of ref's site terms at F's drops);
    (None, None) without an ICC (the plain bound)."""
    if not ref.case_icc:
        return None, None
    return design_effects(ref.case_icc, F.case_id), off_case_site_cov(ref.site, F)
