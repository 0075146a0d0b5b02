"""The board's boosted position correction (impactsense.board.boosted): the boosted trees in the forests' form, sized by
the event budget, chosen out of fold, exported whole."""

import io

import numpy as np
from sklearn.ensemble import GradientBoostingRegressor, RandomForestRegressor

from impactsense.board import boosted, cost
from impactsense.forestfile import load_forest, save_forest
from impactsense.models import ForestSettings


def smooth_problem(n=400, seed=0):
    """A position-like correction: a smooth function of the inputs plus noise, the drops in groups of 4."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1, 1, size=(n, 6)).astype(np.float32)
    resid = np.c_[8 * X[:, 0] + 4 * np.tanh(3 * X[:, 1]), -6 * X[:, 2] + 3 * X[:, 0] * X[:, 3]]
    resid += rng.normal(scale=1.0, size=resid.shape)
    return X, resid, np.arange(n) // 4


def test_the_forest_form_is_the_boosted_prediction_and_survives_the_model_file():
    """The mean over the converted trees equals scikit-learn's boosted prediction (float rounding), and after the
    model folder's forest file (no pickle) too."""
    X, resid, _ = smooth_problem()
    for stages in (2, 9):
        rf = boosted.boosted_regressor(X, resid[:, 0], stages, seed=3)
        gb = GradientBoostingRegressor(n_estimators=stages, max_depth=boosted.BOOST_DEPTH,
                                       learning_rate=boosted.learning_rate(stages), subsample=boosted.BOOST_SUBSAMPLE,
                                       loss="huber", random_state=3).fit(X, resid[:, 0])
        assert len(rf.estimators_) == stages
        np.testing.assert_allclose(rf.predict(X), gb.predict(X), atol=1e-9)
        buf = io.BytesIO()
        save_forest(buf, rf)
        back = load_forest("boosted.npz", buf.getvalue())
        np.testing.assert_allclose(back.predict(X), gb.predict(X), atol=1e-9)
        assert max(t.tree_.max_depth for t in back.estimators_) <= boosted.BOOST_DEPTH


def test_stages_and_prefix_stay_within_the_instructions():
    """stages_within and prefix_within spend at most what they are given (board.cost rates), more never fewer."""
    X, resid, _ = smooth_problem()
    pair = [RandomForestRegressor(n_estimators=20, random_state=c).fit(X, resid[:, c]) for c in (0, 1)]
    nodes = sum(cost.forest_nodes(f, X) for f in pair)
    last = (0, 0)
    for left in (0, 500, 2000, 5000, 10**6):
        s, k = boosted.stages_within(left), boosted.prefix_within(pair, X, left)
        if left >= 2 * boosted.STAGE_INSTRUCTIONS:
            assert 2 * s * boosted.STAGE_INSTRUCTIONS <= left
        spent = cost.FOREST_PER_NODE * nodes[:k].sum(0).max() + 2 * cost.FOREST_PER_TREE * k
        assert k == 1 or spent <= left
        assert s >= last[0] and k >= last[1] and 1 <= s <= boosted.BOOST_MAX_STAGES
        last = (s, k)
    assert last == (boosted.BOOST_MAX_STAGES, 20)


def test_the_out_of_fold_choice_prefers_boosting_over_a_one_tree_prefix():
    """On a smooth correction a one-tree random forest prefix is noisy; boosted stages of the same budget place the
    held-out folds clearly better, and the choice says so."""
    X, resid, groups = smooth_problem()
    rec = boosted.choose_board_forests(X, resid, groups, ForestSettings(n_estimators=20), prefix=1, stages=4)
    mae = rec["out_of_fold_mae_mm"]
    assert rec["use_boosted"] and mae["boosted"] < 0.8 * mae["forest_prefix"]
    assert rec["stages"] == 4 and rec["learning_rate"] == boosted.learning_rate(4)


def test_select_trees_exports_every_boosted_tree():
    """A boosted pair is no prefix: export.select_trees keeps all its trees at any budget (the energy forest's prefix
    is what it fits), and their cost is the nodes they walk."""
    from sklearn.ensemble import RandomForestClassifier

    from impactsense.export import ModelSet, select_trees

    X, resid, _ = smooth_problem()
    fx, fy = (boosted.boosted_regressor(X[:300], resid[:300, c], 6) for c in (0, 1))
    fe = RandomForestClassifier(n_estimators=10, random_state=2).fit(X[:300], X[:300, 2] > 0)
    inputs = {r: list(range(6)) for r in ("x", "y", "energy")}
    models = ModelSet(fx, fy, fe, {"board_forests": {"use_boosted": True}}, 6, inputs, False, {})
    small = big = None
    for left in (0, 10**7):
        k, rows = select_trees(models, X[300:], None, resid[300:], max_instructions=left)
        assert k == 6 and len(rows) == 1 and rows[0]["trees"] == 6
        small, big = (rows[0], big) if left == 0 else (small, rows[0])
    assert small["energy_trees"] == 1 and big["energy_trees"] == 10 and big["within_budgets"]


def test_no_correction_when_the_physics_position_beats_the_budgets_correction():
    """A learnable correction is kept (the smooth problem); residuals that the features do not explain (noise about
    0, as on a plate whose physics position is as good as its picks allow) are left uncorrected: a one-tree prefix
    or two boosted stages fitted to noise add scatter out of fold, and the record says so."""
    X, resid, groups = smooth_problem()
    rec = boosted.choose_board_forests(X, resid, groups, ForestSettings(n_estimators=20), prefix=1, stages=4)
    assert not rec["no_correction"]
    rng = np.random.default_rng(5)
    noise = rng.normal(0.0, 10.0, resid.shape)
    rec = boosted.choose_board_forests(X, noise, groups, ForestSettings(n_estimators=20), prefix=1, stages=2)
    mae = rec["out_of_fold_mae_mm"]
    assert rec["no_correction"] and mae["none"] < min(mae["forest_prefix"], mae["boosted"])
