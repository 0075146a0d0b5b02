"""The position members' weighted sum in place of their mean, when the training drops' out-of-fold positions say
so (host only; models without a site map; docs/method.md "The members' stack").

The reported position is the mean over the members that placed a drop (position_members.joined_position). When
one member is much better than the rest (a travel field's, on a plate whose picks carry a per-site bias), the
mean dilutes it. Here the candidates are the mean itself, each member's corrected position and each member's
base (its position before the forests' correction), the columns of P; their weights w >= 0 with sum 1 are the
non-negative least squares fit of the training drops' out-of-fold positions (scipy's nnls, the sum by a heavily
weighted row). A member that did not place a drop reads the mean there. The stack is kept when its out-of-fold
error, the weights fitted without each of STACK_FOLDS site folds, is below the mean's by more than the
one-standard-error rule (correction_scale.choose_by_gain); its weights are then fitted on every training drop.
"""

from __future__ import annotations

import numpy as np

STACK_FOLDS = 5
MEAN = "mean"
# The sum-to-one row's weight, times the columns' rms deviation from the mean and sqrt(rows): the constraint holds
# to ~1e-3 without swamping the fit.
SUM_WEIGHT = 30.0


def columns(each: dict, mean: np.ndarray) -> tuple[list[str], np.ndarray]:
    """(names, P [R, K, 2]): the mean, then each member's corrected position ("NAME") and base ("NAME@base"), a
    member's NaN rows filled with the mean."""
    names, cols = [MEAN], [mean]
    for name, (corrected, base) in each.items():
        for label, pos in ((name, corrected), (f"{name}@base", base)):
            names.append(label)
            cols.append(np.where(np.isfinite(pos).all(1)[:, None], pos, mean))
    return names, np.stack(cols, 1)


def fit_weights(P: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """w >= 0, sum 1, minimising sum |P w - xy|^2 over rows and both axes (P [R, K, 2], xy [R, 2])."""
    from scipy.optimize import nnls

    D = P - P[:, :1]                        # deviations from the mean (column 0): small numbers, well scaled
    A = np.concatenate([D[..., 0], D[..., 1]])
    t = np.concatenate([xy[:, 0] - P[:, 0, 0], xy[:, 1] - P[:, 0, 1]])
    row = SUM_WEIGHT * np.sqrt(len(A)) * max(float(np.sqrt(np.mean(A ** 2))), 1e-6)
    w = nnls(np.vstack([A, np.full((1, A.shape[1]), row)]), np.append(t, row))[0]
    return w / w.sum() if w.sum() > 0 else np.eye(len(w))[0]


def choose_stack(each: dict, mean: np.ndarray, xy: np.ndarray, sites: np.ndarray) -> dict | None:
    """The members' stack from the training drops' out-of-fold member positions (`each`: name -> (corrected,
    base) [R, 2] at the chosen correction scale; `mean`: their joined mean): {"keep", "out_of_fold_mae_mm":
    [mean, stack], "gain_sigmas", "weights": {column: w}} (weights fitted on all drops, the non-zero ones), or
    None with fewer than STACK_FOLDS sites or no finite row."""
    from sklearn.model_selection import GroupKFold

    from .correction_scale import choose_by_gain

    xy = np.asarray(xy, float)
    ok = np.isfinite(mean).all(1) & np.isfinite(xy).all(1)
    if np.unique(sites[ok]).size < STACK_FOLDS or len(each) < 2:
        return None
    names, P = columns({k: (c[ok], b[ok]) for k, (c, b) in each.items()}, mean[ok])
    y, s = xy[ok], sites[ok]
    stacked = np.full_like(y, np.nan)
    for fit_rows, held in GroupKFold(STACK_FOLDS).split(y, groups=s):
        stacked[held] = np.einsum("rkc,k->rc", P[held], fit_weights(P[fit_rows], y[fit_rows]))
    err = [np.abs(P[:, 0] - y).mean(1), np.abs(stacked - y).mean(1)]
    chosen, mae, z = choose_by_gain(err, s, 0)
    w = fit_weights(P, y)
    return {"keep": bool(chosen == 1), "out_of_fold_mae_mm": [round(m, 3) for m in mae], "gain_sigmas": round(z, 2),
            "folds": STACK_FOLDS, "weights": {n: round(float(v), 4) for n, v in zip(names, w) if v > 1e-4}}


def stacked_position(each: dict, mean: np.ndarray, weights: dict) -> np.ndarray:
    """The weighted sum of choose_stack's columns (each: position_members.each_member_position of the rows, at
    the model's scaled correction; mean: their mean); weights naming a member the rows do not have read the
    mean."""
    names, P = columns(each, mean)
    w = np.array([float(weights.get(n, 0.0)) for n in names])
    missing = sum(float(v) for n, v in weights.items() if n not in names)
    w[0] += missing
    return np.einsum("rkc,k->rc", P, w / w.sum())


def stack_ok(stack, members) -> bool:
    """A model card's member_stack as choose_stack writes it, its weights naming the mean or the model's members
    (and "main")."""
    if not isinstance(stack, dict) or not isinstance(stack.get("keep"), bool) or not isinstance(stack.get("weights"),
                                                                                               dict):
        return False
    known = {MEAN, "main", *members}
    for name, w in stack["weights"].items():
        member = name[:-len("@base")] if name.endswith("@base") else name
        if member not in known or isinstance(w, bool) or not isinstance(w, (int, float)) or not np.isfinite(w) \
                or w < 0:
            return False
    return sum(stack["weights"].values()) > 0
