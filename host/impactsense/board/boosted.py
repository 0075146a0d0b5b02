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

The pair gets as many stages as the event budget leaves it (board.cost: the signal's cost, the forests' fixed
share, the energy model's) and the same instructions bound the random forests' prefix it is compared with. Which
one the board keeps is chosen on the training drops out of fold (grouped by position): the boosted pair
replaces the forests' budget-sized prefix when its mean absolute error per axis is below BOOST_GAIN x the
prefix's (docs/findings.md "Session 19: boardgap").
"""

from __future__ import annotations

import numpy as np
from sklearn.ensemble import GradientBoostingRegressor, RandomForestRegressor
from sklearn.model_selection import GroupKFold

from .cost import FOREST_PER_NODE, FOREST_PER_TREE, deepest_walks

# Stages: as many as the event budget leaves the pair (stages_within), at most BOOST_MAX_STAGES; the learning rate
# BOOST_SHRINK / stages (at most BOOST_MAX_RATE): fewer stages, each one a larger step.
BOOST_MAX_STAGES = 20
BOOST_DEPTH = 3
BOOST_SHRINK = 1.8
BOOST_MAX_RATE = 0.6
BOOST_SUBSAMPLE = 0.7
BOOST_GAIN = 0.97
# one boosted tree's cost on the board, per coordinate: BOOST_DEPTH + 1 nodes and the tree's own (board.cost rates)
STAGE_INSTRUCTIONS = FOREST_PER_NODE * (BOOST_DEPTH + 1) + FOREST_PER_TREE


def stages_within(instructions: float) -> int:
    """Boosted stages a coordinate pair affords in `instructions` (at least 1)."""
    return int(max(1, min(BOOST_MAX_STAGES, instructions // (2 * STAGE_INSTRUCTIONS))))


def learning_rate(stages: int) -> float:
    return float(min(BOOST_MAX_RATE, BOOST_SHRINK / max(1, stages)))


def prefix_within(forests, X: np.ndarray, instructions: float) -> int:
    """The random forests' (x, y) longest prefix whose nodes, each tree walked to its deepest leaf (board.cost
    deepest_walks; X is not read), cost at most `instructions` (board.cost rates; at least 1)."""
    nodes = sum(deepest_walks(f) for f in forests)          # [trees, 1], both coordinates
    cost = FOREST_PER_NODE * np.cumsum(nodes, axis=0).max(axis=1) + 2 * FOREST_PER_TREE * np.arange(1, len(nodes) + 1)
    return int(max(1, np.sum(cost <= instructions)))


def boosted_regressor(X: np.ndarray, y: np.ndarray, stages: int, seed: int = 0) -> RandomForestRegressor:
    """Gradient-boosted trees (Huber loss, depth BOOST_DEPTH, learning_rate(stages)) fitted to y, returned as a
    RandomForestRegressor whose mean over its trees is the boosted prediction (each leaf init + stages * lr * value)."""
    gb = GradientBoostingRegressor(n_estimators=stages, max_depth=BOOST_DEPTH, learning_rate=learning_rate(stages),
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


def choose_board_forests(X: np.ndarray, resid: np.ndarray, groups: np.ndarray, settings, prefix: int, stages: int,
                         n_folds: int = 5) -> dict:
    """Out of fold on the training drops (X the location features, resid the truth minus the physics position,
    groups the drops' positions): the random forests' `prefix`-tree prefix against the boosted pair of `stages`
    (both what the event budget affords), and the kept one against no correction (the physics position, "none":
    kept when below BOOST_GAIN x the kept one's); the record {"out_of_fold_mae_mm": {"forest_prefix", "boosted",
    "none"}, "use_boosted", "no_correction", ...} for the card."""
    k = min(n_folds, int(np.max(groups)) + 1)
    err = {"forest_prefix": [], "boosted": []}
    if k >= 2:
        for tr, va in GroupKFold(k).split(X, groups=groups):
            for c in (0, 1):
                rf = settings.regressor().fit(X[tr], resid[tr, c])
                err["forest_prefix"].append(np.abs(_prefix_predict(rf, X[va], prefix) - resid[va, c]))
                gb = boosted_regressor(X[tr], resid[tr, c], stages, settings.seed)
                err["boosted"].append(np.abs(gb.predict(X[va]) - resid[va, c]))
    mae = {n: float(np.mean(np.concatenate(v))) if v else float("nan") for n, v in err.items()}
    use = bool(np.isfinite(mae["boosted"]) and mae["boosted"] < BOOST_GAIN * mae["forest_prefix"])
    # no correction (the physics position): what the budget's correction has to beat
    mae["none"] = float(np.mean(np.abs(resid))) if k >= 2 else float("nan")
    kept = mae["boosted"] if use else mae["forest_prefix"]
    none = bool(np.isfinite(mae["none"]) and np.isfinite(kept) and mae["none"] < BOOST_GAIN * kept)
    return {"out_of_fold_mae_mm": {n: round(v, 3) for n, v in mae.items()}, "forest_prefix": prefix,
            "stages": stages, "depth": BOOST_DEPTH, "learning_rate": learning_rate(stages), "subsample": BOOST_SUBSAMPLE,
            "loss": "huber", "use_boosted": use, "no_correction": none}
