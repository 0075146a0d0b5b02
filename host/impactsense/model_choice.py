"""The model retrain keeps: the candidates (the retrained model, the reference model as it serves DATA_NEW, and
for a bond the model with its channel left out) placed on DATA_NEW's own labelled drops, the lowest MAE per axis
kept (ties: the candidates' order).

The loop's new session is labelled (diagnose reads it at its declared positions), so a retrained model that
places it worse than the reference model is seen there: the diagnosed effects, as sized, do not describe the
session (a move sized a few mm off, an effect the signal model only approximates). The choice is made on the same
drops it is scored on, so it is optimistic; the cross-fitted figure is the honest one: each half of DATA_NEW's
cases (two seeded halves) placed by the model the other half chose. Measured: docs/findings.md (issue 16)."""

from __future__ import annotations

import numpy as np


def drop_errors(model, session) -> np.ndarray:
    """|predicted - declared| per drop and axis [n, 2] (mm; NaN where the model gives no position)."""
    return np.abs(model.predict(model.featurize(session.adc))["xy_mm"] - session.xy_mm)


def _mae(err: np.ndarray) -> float:
    return float(np.nanmean(err)) if np.isfinite(err).any() else float("inf")


def choose_model(models: dict, data, seed: int = 0, errs: dict | None = None) -> dict:
    """{"chosen": the name of the model in `models` (name -> model or None: left out) with the lowest MAE per axis
    on DATA_NEW's drops, "mae_mm": each candidate's, "cross_fitted_mae_mm": the rule's cross-fitted MAE}.
    errs: the candidates' drop_errors on `data` when already computed."""
    errs = errs or {k: drop_errors(m, data) for k, m in models.items() if m is not None}
    if not errs:
        raise ValueError("choose_model: no candidate model")
    mae = {k: _mae(e) for k, e in errs.items()}
    chosen = min(errs, key=lambda k: mae[k])   # ties: the candidates' order
    cases = np.unique(data.case_id)
    half = np.isin(data.case_id, np.random.default_rng(seed).permutation(cases)[: cases.size // 2])
    crossed = np.full_like(errs[chosen], np.nan)
    half_choice = []
    for rows, other in ((half, ~half), (~half, half)):
        pick = min(errs, key=lambda k: _mae(errs[k][other]))
        crossed[rows] = errs[pick][rows]
        half_choice.append(pick)
    return {"chosen": chosen, "mae_mm": mae, "cross_fitted_mae_mm": _mae(crossed), "half_choice": half_choice}


def paired_lead(errs_a: np.ndarray, errs_b: np.ndarray, case_id: np.ndarray) -> dict:
    """How much better model b places a session's cases than model a: the mean over the cases of the per-case
    difference of MAE per axis (a - b, mm; positive: b the better) and its standard error over the cases (the
    paired difference's noise; NaN with fewer than two cases both models place)."""
    cases = np.unique(case_id)
    d = np.array([_mae(errs_a[case_id == c]) - _mae(errs_b[case_id == c]) for c in cases])
    d = d[np.isfinite(d)]
    se = float(np.std(d, ddof=1) / np.sqrt(d.size)) if d.size > 1 else float("nan")
    return {"lead_mm": float(np.mean(d)) if d.size else float("nan"), "lead_se_mm": se, "cases": int(d.size)}


def keep_retrained_or_reference(retrained, reference, data, seed: int = 0) -> dict:
    """choose_model between the retrained model and the reference model (retrain with no bond choice), the
    reference kept only when it is the better on all of DATA_NEW's drops and on each half of its cases (the
    choice does not turn on a few cases: where the two are within the scatter of the cases, the retrained model,
    which carries the diagnosed change, is kept).
    The record also gives the reference's paired lead over the retrained model per case and its standard error
    (`paired_lead`: how far the choice stands from the cases' scatter); it does not enter the choice: a one-SE
    rule measured against drops the choice did not see kept the worse model where this one did not
    (docs/findings.md, issue 16 gainkeep)."""
    errs = {"retrained": drop_errors(retrained, data), "reference": drop_errors(reference, data)}
    got = choose_model({"retrained": retrained, "reference": reference}, data, seed, errs)
    stable = got["chosen"] == "reference" and got["half_choice"] == ["reference", "reference"]
    lead = paired_lead(errs["retrained"], errs["reference"], np.asarray(data.case_id))
    return {"chosen": "reference" if stable else "retrained", "retrained_mae_mm": got["mae_mm"]["retrained"],
            "reference_mae_mm": got["mae_mm"]["reference"], "cross_fitted_mae_mm": got["cross_fitted_mae_mm"],
            "reference_lead_mm": lead["lead_mm"], "reference_lead_se_mm": lead["lead_se_mm"]}
