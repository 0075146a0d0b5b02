"""The public API (impactsense.load_session/train/predict/evaluate/export_for_board) and the scikit-learn
estimators: they behave as scikit-learn expects (clone, get_params, Pipeline, cross-validation) and the
forests learn something the physics localiser alone does not."""

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.model_selection import GroupKFold, cross_val_predict, cross_val_score
from sklearn.pipeline import Pipeline

import impactsense as isn
from impactsense.metrics import localisation_metrics


@pytest.fixture(scope="module")
def session():
    return isn.load_session()


def test_version_is_the_installed_metadata():
    from importlib.metadata import version

    assert isn.__version__ == version("impactsense")


def test_localiser_cross_validates_and_beats_the_physics_localiser(session):
    rows = np.arange(0, len(session), 2)  # every other drop: ~385, the split by case below
    adc, xy, groups = session.adc[rows], session.xy_mm[rows], session.case_id[rows]
    est = isn.ImpactLocaliser(n_estimators=20)
    cv = GroupKFold(3)
    pred = cross_val_predict(est, adc, xy, groups=groups, cv=cv)
    err = np.hypot(*(pred - xy).T)
    core = isn.CoreFeatures().fit(adc, xy)
    phys = core.transform(adc)[:, [core.feature_names_out_.tolist().index(n) for n in ("phys_x_mm", "phys_y_mm")]]
    ok = np.isfinite(phys).all(1)
    phys_err = np.hypot(*(phys[ok] - xy[ok]).T)
    # held-out cases: a few mm, and within 5 % of the physics position with the physics localiser's constants
    # fitted on every drop (in-sample, in its favour). Since the dispersive localiser (docs/findings.md, "The
    # picked cycle's frequency") the physics position on PMMA is as good as 20-tree forests on 385 drops
    # (out of fold: 3.56 vs 3.59 mm); before it the forests beat it by > 3 %.
    assert np.median(err) < 6.0 and np.mean(err[ok]) < 1.05 * np.mean(phys_err)
    scores = cross_val_score(est, adc, xy, groups=groups, cv=cv)  # R2 of x, y
    assert scores.shape == (3,) and scores.min() > 0.95


def test_pipeline_of_core_features_equals_the_localiser_on_recordings(session):
    adc, xy = session.adc[:200], session.xy_mm[:200]
    direct = isn.ImpactLocaliser(n_estimators=5, random_state=3).fit(adc, xy).predict(adc[:40])
    pipe = Pipeline([("core", isn.CoreFeatures()), ("loc", isn.ImpactLocaliser(n_estimators=5, random_state=3))])
    np.testing.assert_allclose(pipe.fit(adc, xy).predict(adc[:40]), direct, atol=1e-9)
    est = isn.ImpactLocaliser(n_estimators=7)
    twin = clone(est).set_params(max_depth=4)
    assert est.get_params()["n_estimators"] == 7 and twin.get_params()["max_depth"] == 4
    with pytest.raises(ValueError, match="recordings"):
        isn.ImpactLocaliser().fit(np.zeros((3, 5)), np.zeros((3, 2)))


def test_energy_classifier_beats_the_majority_class(session):
    rows = np.arange(0, len(session), 2)
    energy = session.height_mm[rows]
    label = (energy >= np.percentile(energy, 75)).astype(int)
    acc = cross_val_score(isn.EnergyClassifier(n_estimators=30), session.adc[rows], label,
                          groups=session.case_id[rows], cv=GroupKFold(3))
    majority = max(label.mean(), 1 - label.mean())
    assert acc.mean() > majority + 0.05, (acc, majority)


def test_train_predict_evaluate_export(session, tmp_path):
    # one forest pair (no position members), so the native export below takes it as it is
    model = isn.train(session, out=tmp_path / "m", trees=10, site_map="none", members=False)
    assert not model.members
    rep = isn.evaluate(model, session)
    assert rep["scope"].startswith("held-out") and rep["all"]["mae_mm"] < 5.0
    held = np.asarray(model.card["split"]["test_recordings"])
    pred = isn.predict(model, session.adc[held])
    ok = np.isfinite(pred["xy_mm"]).all(1)
    again = localisation_metrics(session.xy_mm[held][ok], pred["xy_mm"][ok])
    assert again["mae_mm"] == pytest.approx(rep["all"]["mae_mm"], rel=1e-9)  # the same numbers, one path
    assert set(np.unique(pred["energy_class"][ok])) <= {0, 1}
    loaded = isn.load_model(tmp_path / "m")
    np.testing.assert_allclose(isn.predict(loaded, session.adc[held[:10]])["xy_mm"], pred["xy_mm"][:10])
    summary = isn.export_for_board(tmp_path / "m", tmp_path / "out", trees=4, rate=None, m2cgen=False)
    assert summary["trees"]["x"] == summary["trees"]["y"] == 4 and (tmp_path / "out" / "forest_tables.npz").is_file()
