"""The training forests put the caller's warning filters back whatever their worker threads do to them."""

import warnings

import numpy as np
from sklearn.ensemble import RandomForestClassifier, RandomForestRegressor

from impactsense.models import ForestSettings
from impactsense.threaded_forests import ThreadedForestClassifier, ThreadedForestRegressor


def _wipes_filters(method):
    def call(self, *args, **kwargs):
        out = method(self, *args, **kwargs)
        warnings.resetwarnings()          # what a lost race between two workers' catch_warnings leaves
        return out
    return call


def test_filters_survive_a_wipe_inside_fit_and_predict(monkeypatch):
    rng = np.random.default_rng(1)
    X, y = rng.random((60, 3)), rng.random(60)
    for base, name in ((RandomForestRegressor, "fit"), (RandomForestRegressor, "predict"),
                       (RandomForestClassifier, "fit"), (RandomForestClassifier, "predict_proba")):
        monkeypatch.setattr(base, name, _wipes_filters(getattr(base, name)))
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="a filter the caller set")
        before = list(warnings.filters)
        reg = ThreadedForestRegressor(5, n_jobs=2, random_state=0).fit(X, y)
        assert list(warnings.filters) == before
        reg.predict(X)
        assert list(warnings.filters) == before
        clf = ThreadedForestClassifier(5, n_jobs=2, random_state=0).fit(X, y > 0.5)
        assert list(warnings.filters) == before
        assert clf.predict(X).shape == (60,)      # predict goes through predict_proba
        assert list(warnings.filters) == before
        RandomForestRegressor(5, random_state=0).fit(X, y)        # the plain forest: the wipe stays
        assert list(warnings.filters) == []


def test_training_forests_are_the_guarded_kind_and_predict_as_sklearn():
    s = ForestSettings(n_estimators=8, seed=3)
    assert isinstance(s.regressor(), ThreadedForestRegressor)
    assert isinstance(s.classifier(), ThreadedForestClassifier)
    rng = np.random.default_rng(2)
    X, y = rng.random((80, 4)), rng.random(80)
    ours = s.regressor().fit(X, y).predict(X)
    plain = RandomForestRegressor(**s.regressor().get_params()).fit(X, y).predict(X)
    np.testing.assert_allclose(ours, plain, rtol=1e-12)   # threads sum the trees in any order
