"""The board's position correction as boosted shallow trees, in the forests' own form.

Within the board's event budget a random forest keeps one to five of its trees (board.cost, export.select_trees):
a deep tree grown on a bootstrap sample with half the features is a noisy correction on its own. Gradient-boosted
trees of depth BOOST_DEPTH visit BOOST_DEPTH + 1 nodes each, so the same instructions buy a dozen stages that
each fit what the previous ones left. They reach the board unchanged in form: boosting predicts
init + lr * sum_k v_k(x), which is the mean over the n trees of init + n * lr * v_k(x); with each tree's leaf
values set so, the boosted model is a forest (scikit-learn's RandomForestRegressor, mean over trees) for every
path that reads one (the model folder's forest files, ImpactModel.predict, the export's node tables, the
firmware's forest_mean). Unlike a random forest's, a prefix of its trees is not the model: the export keeps
all of them (the card's "board_forests").

Which one the board keeps is chosen on the training drops out of fold (grouped by position): the boosted pair
replaces the forests' budget-sized prefix when its mean absolute error per axis is below BOOST_GAIN x the
prefix's (docs/findings.md "Session 19: boardgap").
"""

from __future__ import annotations

import numpy as np
from sklearn.ensemble import GradientBoostingRegressor, RandomForestRegressor
from sklearn.model_selection import GroupKFold

BOOST_STAGES = 12
BOOST_DEPTH = 3
BOOST_RATE = 0.15
BOOST_SUBSAMPLE = 0.7
BOOST_GAIN = 0.97
# The random forest's prefix the board affords when the boosted pair is not kept (the export's usual choice
# within the event budget on a rig without the twin; the figure it is compared against).
FOREST_PREFIX = 5


def boosted_regressor(X: np.ndarray, y: np.ndarray, seed: int = 0, stages: int = BOOST_STAGES) -> RandomForestRegressor:
    """Gradient-boosted trees (Huber loss, depth BOOST_DEPTH) fitted to y, returned as a RandomForestRegressor whose
    mean over its trees is the boosted prediction (each leaf init + stages * lr * value)."""
    gb = GradientBoostingRegressor(n_estimators=stages, max_depth=BOOST_DEPTH, learning_rate=BOOST_RATE,
                                   subsample=BOOST_SUBSAMPLE, loss="huber", random_state=seed).fit(X, y)
    init = float(np.ravel(gb.init_.predict(X[:1]))[0]) if hasattr(gb.init_, "predict") else 0.0
    trees = [est[0] for est in gb.estimators_]
    for t in trees:
        t.tree_.value[:] = init + stages * gb.learning_rate * t.tree_.value
    rf = RandomForestRegressor(n_estimators=stages, max_depth=BOOST_DEPTH, random_state=seed)
    rf.estimators_ = trees
    rf.n_features_in_ = X.shape[1]
    rf.n_outputs_ = 1
    rf.estimator_ = trees[0]
    return rf


def _prefix_predict(forest, X: np.ndarray, k: int) -> np.ndarray:
    return np.mean([t.predict(X) for t in forest.estimators_[:k]], axis=0)


def choose_board_forests(X: np.ndarray, resid: np.ndarray, groups: np.ndarray, settings,
                         n_folds: int = 5) -> dict:
    """Out of fold on the training drops (X the location features, resid the truth minus the physics position,
    groups the drops' positions): the random forests' FOREST_PREFIX-tree prefix against the boosted pair; the
    record {"out_of_fold_mae_mm": {"forest_prefix", "boosted"}, "use_boosted", ...} for the card."""
    k = min(n_folds, int(np.max(groups)) + 1)
    err = {"forest_prefix": [], "boosted": []}
    if k >= 2:
        for tr, va in GroupKFold(k).split(X, groups=groups):
            for c in (0, 1):
                rf = settings.regressor().fit(X[tr], resid[tr, c])
                err["forest_prefix"].append(np.abs(_prefix_predict(rf, X[va], FOREST_PREFIX) - resid[va, c]))
                gb = boosted_regressor(X[tr], resid[tr, c], settings.seed)
                err["boosted"].append(np.abs(gb.predict(X[va]) - resid[va, c]))
    mae = {n: float(np.mean(np.concatenate(v))) if v else float("nan") for n, v in err.items()}
    use = bool(np.isfinite(mae["boosted"]) and mae["boosted"] < BOOST_GAIN * mae["forest_prefix"])
    return {"out_of_fold_mae_mm": {n: round(v, 3) for n, v in mae.items()}, "forest_prefix": FOREST_PREFIX,
            "stages": BOOST_STAGES, "depth": BOOST_DEPTH, "learning_rate": BOOST_RATE, "subsample": BOOST_SUBSAMPLE,
            "loss": "huber", "use_boosted": use}
