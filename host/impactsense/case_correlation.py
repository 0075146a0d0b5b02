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
