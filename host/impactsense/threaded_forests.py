"""Random forests that fit and predict on every core (n_jobs=-1) and leave the process's warning filters as
they found them.

scikit-learn runs each threaded forest task inside `warnings.catch_warnings()` with the caller's filters
re-applied. Before Python 3.14 `catch_warnings` is not thread-safe: two worker threads entering and leaving it
at once can leave the process's filter list empty or partial. From then on every joblib task of every later
forest (threaded or not) sees no filters and prints "`sklearn.utils.parallel.delayed` should be used with
`sklearn.utils.parallel.Parallel`", thousands of times in one command. These subclasses run each threaded
call inside one `catch_warnings()` of the calling thread, so whatever the workers do to the list, the caller's
list is put back when the call returns (`benchmarks/bench_warning_filters.py` counts the corrupted lists).
"""

from __future__ import annotations

import warnings

from sklearn.ensemble import RandomForestClassifier, RandomForestRegressor


class ThreadedForestRegressor(RandomForestRegressor):
    def fit(self, X, y, sample_weight=None):
        with warnings.catch_warnings():
            return super().fit(X, y, sample_weight=sample_weight)

    def predict(self, X):
        with warnings.catch_warnings():
            return super().predict(X)


class ThreadedForestClassifier(RandomForestClassifier):
    def fit(self, X, y, sample_weight=None):
        with warnings.catch_warnings():
            return super().fit(X, y, sample_weight=sample_weight)

    def predict_proba(self, X):
        with warnings.catch_warnings():
            return super().predict_proba(X)
