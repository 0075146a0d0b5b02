"""Surrogate models for the PZT design (`design`) and their hyper-parameter search (docs/method.md ranges).

Four families: random forest, Gaussian process (Kriging), neural network (scikit-learn) and an SVD
polynomial (numpy least squares via the SVD, `np.linalg.lstsq` with a relative singular-value cut-off).
Tuning: a seeded random search inside docs/method.md's ranges, each candidate fitted on the training split and
scored by R2 on the validation split (an equivalent of the seed's Bayesian optimisation at this budget);
the winner's R2 on the untouched test split is reported.

Every fit and prediction runs with one BLAS/OpenMP thread (`SingleThread`): the problems are tiny (tens of
points), and two BLAS threads on two cores shared with other work spend their time waiting on each other
(a 3 x 250-unit network fitted 30x slower with two threads than with one on the loaded 2-core machine).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from itertools import combinations_with_replacement

import numpy as np
from sklearn.ensemble import RandomForestRegressor
from sklearn.metrics import r2_score
from sklearn.utils.validation import check_is_fitted

MODELS = ("RF", "GPR", "NN", "SVD")

_THREADS = None


def one_thread():
    """A context in which BLAS and OpenMP run one thread (threadpoolctl, a scikit-learn dependency)."""
    global _THREADS
    if _THREADS is None:
        from threadpoolctl import ThreadpoolController
        _THREADS = ThreadpoolController()
    return _THREADS.limit(limits=1)


class SingleThread:
    """An estimator whose fit and predict run in `one_thread()`; `estimator` is the wrapped model."""

    def __init__(self, estimator):
        self.estimator = estimator

    def fit(self, x, y):
        with one_thread():
            self.estimator.fit(x, y)
        return self

    def predict(self, x):
        with one_thread():
            return self.estimator.predict(x)


class SVDPolynomial:
    """Full polynomial of degree `degree` in the inputs, fitted by SVD least squares (rcond = tol)."""

    def __init__(self, degree=2, tol=1e-6, standardise=True):
        self.degree, self.tol, self.standardise = int(degree), float(tol), bool(standardise)

    def _terms(self, d):
        out = [()]
        for k in range(1, self.degree + 1):
            out += list(combinations_with_replacement(range(d), k))
        return out

    def _design(self, x):
        x = (x - self.mu_) / self.sd_
        cols = [np.ones(len(x))]
        for t in self.terms_[1:]:
            cols.append(np.prod(x[:, list(t)], axis=1))
        return np.stack(cols, axis=1)

    def fit(self, x, y):
        x = np.asarray(x, float)
        self.mu_ = x.mean(0) if self.standardise else np.zeros(x.shape[1])
        self.sd_ = x.std(0) + 1e-12 if self.standardise else np.ones(x.shape[1])
        self.terms_ = self._terms(x.shape[1])
        self.coef_, *_ = np.linalg.lstsq(self._design(x), np.asarray(y, float), rcond=self.tol)
        return self

    def predict(self, x):
        return self._design(np.asarray(x, float)) @ self.coef_


def _n_terms(d, degree):
    from math import comb
    return comb(d + degree, degree)


def sample_config(kind: str, rng: np.random.Generator, n_train: int, d: int) -> dict:
    if kind == "RF":
        return {"min_samples_leaf": int(rng.integers(1, max(2, min(150, n_train // 2)) + 1)),
                "n_estimators": int(np.exp(rng.uniform(np.log(5), np.log(500))))}
    if kind == "SVD":
        # degree 2..6, but no more terms than the solver can handle at this size (the cut-off regularises)
        degrees = [g for g in range(2, 7) if _n_terms(d, g) <= 6000] or [2]
        return {"degree": int(rng.choice(degrees)), "tol": float(10 ** rng.uniform(-12, -3)),
                "standardise": bool(rng.integers(0, 2))}
    if kind == "GPR":
        return {"kernel": str(rng.choice(["RQ", "SE", "exponential", "matern32", "matern52"])),
                "standardise": bool(rng.integers(0, 2))}
    if kind == "NN":
        layers = int(rng.integers(1, 4))
        return {"hidden": [int(rng.integers(1, 301)) for _ in range(layers)],
                "activation": str(rng.choice(["relu", "tanh", "logistic", "identity"])),
                "standardise": bool(rng.integers(0, 2))}
    raise ValueError(kind)


def hidden_layers(cfg: dict) -> tuple:
    """The network's hidden layer sizes: as drawn, except that identity-activation layers compose to one
    linear map whose rank is at most the narrowest layer's width, so they are fitted as that one layer (the
    same family of functions; a deep linear network costs up to 15x more L-BFGS time for it)."""
    hidden = tuple(int(h) for h in cfg["hidden"])
    return (min(hidden),) if cfg["activation"] == "identity" else hidden


def build(kind: str, cfg: dict, seed: int) -> SingleThread:
    """The surrogate of family `kind` with the settings `cfg` (as drawn by `sample_config`), unfitted."""
    return SingleThread(_estimator(kind, cfg, seed))


def _estimator(kind: str, cfg: dict, seed: int):
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    if kind == "RF":
        return SerialForest(n_estimators=cfg["n_estimators"], min_samples_leaf=cfg["min_samples_leaf"],
                            random_state=seed, n_jobs=1)
    if kind == "SVD":
        return SVDPolynomial(cfg["degree"], cfg["tol"], cfg["standardise"])
    if kind == "GPR":
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process import kernels as K
        base = {"RQ": K.RationalQuadratic(), "SE": K.RBF(), "exponential": K.Matern(nu=0.5),
                "matern32": K.Matern(nu=1.5), "matern52": K.Matern(nu=2.5)}[cfg["kernel"]]
        if cfg["kernel"] != "RQ":      # anisotropic (ARD) length scales: one per input
            ls = np.ones(cfg.get("d", 1))
            base = K.RBF(ls, (1e-2, 1e3)) if cfg["kernel"] == "SE" else K.Matern(ls, (1e-2, 1e3), nu=base.nu)
        kern = K.ConstantKernel(1.0) * base + K.WhiteKernel(1e-3, (1e-8, 1e1))
        gp = GaussianProcessRegressor(kern, normalize_y=True, random_state=seed, n_restarts_optimizer=1)
        return make_pipeline(StandardScaler(), gp) if cfg["standardise"] else gp
    if kind == "NN":
        from sklearn.neural_network import MLPRegressor
        nn = MLPRegressor(hidden_layer_sizes=hidden_layers(cfg), activation=cfg["activation"], solver="lbfgs",
                          max_iter=1500, alpha=1e-4, random_state=seed)
        return make_pipeline(StandardScaler(), nn) if cfg["standardise"] else nn
    raise ValueError(kind)


class SerialForest(RandomForestRegressor):
    """A random forest whose predict sums its trees' predictions in a plain loop: the same sum in the same
    order as scikit-learn's (so the same floats), without its per-tree job dispatch, which costs ~8x the
    trees' own work on the optimiser's small batches."""

    def predict(self, X):
        check_is_fitted(self)
        x = np.ascontiguousarray(X, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != self.n_features_in_:
            raise ValueError(f"expected {self.n_features_in_} features, got shape {x.shape}")
        y = np.zeros((x.shape[0], self.n_outputs_) if self.n_outputs_ > 1 else x.shape[0])
        for tree in self.estimators_:
            y += tree.predict(x, check_input=False)
        y /= len(self.estimators_)
        return y


@dataclass
class Fitted:
    kind: str
    config: dict
    model: object
    r2_val: float
    r2_test: float
    trials: int

    def predict(self, x):
        return self.model.predict(x)


def _r2(y, p):
    if not np.all(np.isfinite(p)):
        return -np.inf
    return float(r2_score(y, p))


def tune(kind, x_tr, y_tr, x_va, y_va, x_te, y_te, *, trials=10, seed=0) -> Fitted:
    """Random search within docs/method.md's ranges; best validation R2 wins; test R2 of the winner."""
    rng = np.random.default_rng(seed)
    best = None
    for k in range(trials):
        cfg = dict(sample_config(kind, rng, len(x_tr), x_tr.shape[1]), d=int(x_tr.shape[1]))
        model = build(kind, cfg, seed + k)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                model.fit(x_tr, y_tr)
                r2v = _r2(y_va, model.predict(x_va))
            except (np.linalg.LinAlgError, ValueError, MemoryError):
                continue
        if best is None or r2v > best[0]:
            best = (r2v, cfg, model)
    if best is None:
        raise RuntimeError(f"no {kind} surrogate could be fitted")
    r2v, cfg, model = best
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r2t = _r2(y_te, model.predict(x_te))
    return Fitted(kind, cfg, model, r2v, r2t, trials)


def split_indices(n: int, seed: int, fractions=(0.70, 0.15, 0.15)):
    rng = np.random.default_rng(seed)
    perm = rng.permutation(n)
    n_tr = int(round(fractions[0] * n))
    n_va = int(round(fractions[1] * n))
    return perm[:n_tr], perm[n_tr:n_tr + n_va], perm[n_tr + n_va:]
