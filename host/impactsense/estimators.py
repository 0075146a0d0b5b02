"""scikit-learn estimators over the signal core: `CoreFeatures` (recordings -> the core's feature vectors),
`ImpactLocaliser` (x, y in mm) and `EnergyClassifier` (low/high energy class). They follow scikit-learn's
conventions (fit(X, y), predict, get_params/set_params, clone), so they work in `Pipeline`, `cross_val_score`
and `GridSearchCV`.

X is either recordings, raw ADC counts [R, 4, samples] as in a session's recordings.npz, or the core's
feature vectors [R, len(FEATURE_NAMES)] (`CoreFeatures().fit_transform(recordings, xy)`, or a Features.vector).
The model is the trainer's (models.ImpactModel): the physics localiser's position plus one random forest
per coordinate on the location features; the energy class a forest on the energy features. (The twin's
site-map match, which `impactsense train` adds for the bundled rig, needs the site map and drop heights and
stays with `impactsense.train`.)
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin, RegressorMixin, TransformerMixin

from .models import ENERGY_FEATURES, LOCATION_FEATURES, ForestSettings, columns
from .pipeline import FEATURE_NAMES, SignalConfig, featurize, fit_localiser

_PHYS = columns(["phys_x_mm", "phys_y_mm"])


def _rig(rig):
    from .data import Rig, load_rig, load_session

    if rig is None:
        return load_session(None).rig
    return rig if isinstance(rig, Rig) else load_rig(rig)


class CoreFeatures(TransformerMixin, BaseEstimator):
    """Recordings [R, 4, samples] (raw counts) -> the core's feature vectors [R, n_features] (FEATURE_NAMES).

    rig: a Rig, a rig.json / session folder, or None (the bundled rig): sensors, plate, sample rate.
    fit_localiser: when fit gets positions y [R, 2] (mm), fit the physics localiser's group velocity and
    per-channel delays on them first (as `impactsense train` does); otherwise the rig's defaults."""

    def __init__(self, rig=None, fit_localiser: bool = True):
        self.rig = rig
        self.fit_localiser = fit_localiser

    def fit(self, X, y=None):
        adc = _recordings(X)
        rig = _rig(self.rig)
        cfg = SignalConfig.for_rig(rig)
        if y is not None and self.fit_localiser:
            xy = np.asarray(y, float).reshape(len(adc), -1)[:, :2]
            cfg = fit_localiser(SimpleNamespace(adc=adc, xy_mm=xy, rig=rig), np.arange(len(adc)), cfg)
        self.signal_ = cfg
        self.feature_names_out_ = np.array(FEATURE_NAMES)
        return self

    def transform(self, X):
        return np.asarray(featurize(_recordings(X), self.signal_).vector, dtype=np.float64)

    def get_feature_names_out(self, input_features=None):
        return np.array(FEATURE_NAMES)


def _recordings(X) -> np.ndarray:
    adc = np.asarray(X)
    if adc.ndim != 3 or adc.shape[1] != 4:
        raise ValueError(f"recordings must be raw counts [R, 4, samples], got shape {adc.shape}")
    return adc


class _CoreForest(BaseEstimator):
    """Shared: X as recordings (through CoreFeatures) or feature vectors; the forest settings."""

    def __init__(self, rig=None, n_estimators: int = 100, min_samples_leaf: int = 1, max_depth=None,
                 random_state: int = 0):
        self.rig = rig
        self.n_estimators = n_estimators
        self.min_samples_leaf = min_samples_leaf
        self.max_depth = max_depth
        self.random_state = random_state

    def _settings(self) -> ForestSettings:
        return ForestSettings(n_estimators=self.n_estimators, min_samples_leaf=self.min_samples_leaf,
                              max_depth=self.max_depth, seed=self.random_state)

    def _features(self, X, y=None, fit: bool = False) -> np.ndarray:
        X = np.asarray(X)
        if X.ndim == 3:
            if fit:
                self.core_ = CoreFeatures(self.rig).fit(X, y)
            return self.core_.transform(X)
        if X.ndim != 2 or X.shape[1] != len(FEATURE_NAMES):
            raise ValueError(f"X must be recordings [R, 4, samples] or core features [R, {len(FEATURE_NAMES)}], "
                             f"got shape {X.shape}")
        if fit:
            self.core_ = None
        return X.astype(np.float64)


class ImpactLocaliser(RegressorMixin, _CoreForest):
    """Impact position (x, y in mm): the core's physics localiser plus a random forest per coordinate on the
    location features, as `impactsense train` fits them. y: [R, 2] true positions (mm). Rows the core cannot
    localise (no onset on a channel) are left out of fit; predict gives them the physics position if it has
    one, else the plate's centre (so scorers see no NaN)."""

    def fit(self, X, y):
        y = np.asarray(y, float).reshape(len(X), 2)
        F = self._features(X, y, fit=True)
        use = np.isfinite(F).all(1)
        if use.sum() < 2:
            raise ValueError(f"only {int(use.sum())} recordings the core can localise")
        resid = y[use] - F[use][:, _PHYS]
        loc = F[use][:, columns(LOCATION_FEATURES)]
        self.forests_ = [self._settings().regressor().fit(loc, resid[:, k]) for k in (0, 1)]
        self.centre_ = np.nanmean(y, axis=0)
        return self

    def predict(self, X):
        F = self._features(X)
        out = F[:, _PHYS].copy()
        use = np.isfinite(F).all(1)
        if use.any():
            loc = F[use][:, columns(LOCATION_FEATURES)]
            out[use] += np.stack([f.predict(loc) for f in self.forests_], axis=1)
        bad = ~np.isfinite(out).all(1)
        out[bad] = self.centre_
        return out


class EnergyClassifier(ClassifierMixin, _CoreForest):
    """Energy class of an impact (the labels given, e.g. 0 = low, 1 = high: m g h >= a threshold) from a random
    forest on the energy features (physics position, arrival energy and its difference energies summed over the
    sensors), as `impactsense train --site-map none` fits it. Rows without features predict the most common
    class of the training labels."""

    def fit(self, X, y):
        y = np.asarray(y)
        F = self._features(X, None, fit=True)
        use = np.isfinite(F).all(1)
        self.classes_ = np.unique(y)
        self.forest_ = self._settings().classifier().fit(F[use][:, columns(ENERGY_FEATURES)], y[use])
        values, counts = np.unique(y, return_counts=True)
        self.majority_ = values[np.argmax(counts)]
        return self

    def predict(self, X):
        F = self._features(X)
        out = np.full(len(F), self.majority_, dtype=self.classes_.dtype)
        use = np.isfinite(F).all(1)
        if use.any():
            out[use] = self.forest_.predict(F[use][:, columns(ENERGY_FEATURES)])
        return out
