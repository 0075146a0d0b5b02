"""The energy class from a linear estimate of the drop's log energy, and the rule that chooses it over the
classifier forest per training set.

`LinearHeightClass` estimates log(m g h) as a linear function of the core's summed arrival energies, their
channel mean and a cubic in the physics position (LINEAR_CLASS_FEATURES; docs/findings.md "Late energy, a
learnt field, the heights": on some plates better than the forest, on others not) and calls a drop
"high" when the estimate is above the boundary between the training drops' energies either side of their 75th
percentile. Its form is the board's too (impactapp::linear_terms): each input standardised,
z_i = (x_i - offset_i) * scale_i, then score = bias + sum_k coef_k * prod(z of term k's factors) and class 1
when score > 0 (the boundary is folded into the bias). A handful of float32 numbers, saved as plain arrays
(`.npz`, read with allow_pickle=False), exported in the forests' node-table arrays (linear_tables).

`energy_class_choice` is the rule `impactsense train` applies on a measured session without a site map: the
training drops' position-grouped out-of-fold accuracy of both (as twin_oof.twin_choice does for the twin); the
linear estimate replaces the forest when it classifies more of them right. The card's "energy_class_choice"
records the figures.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from itertools import combinations_with_replacement

import numpy as np

from .errors import DataError
from .forestfile import read_arrays

FORMAT = "impactsense-linear-class-1"
LINEAR_ENERGY_FILE = "linear_energy.npz"
# The inputs, in this order: four summed arrival energies and the channels' mean log energy enter linearly, the
# physics position (the last two) through a cubic.
LINEAR_CLASS_FEATURES = ["log_arrival_energy_sum", "log_diff1_energy_sum", "log_diff2_energy_sum",
                         "log_diff3_energy_sum", "log_energy_mean", "phys_x_mm", "phys_y_mm"]
POSITION_DEGREE = 3
MAX_FACTORS = 3          # the board's terms hold up to three factors (the cubic's)
NO_FACTOR = 255          # a term's unused factor slot (impactapp's kLeaf)


def design_terms(n_inputs: int = len(LINEAR_CLASS_FEATURES), n_position: int = 2,
                 degree: int = POSITION_DEGREE) -> np.ndarray:
    """The terms [T, MAX_FACTORS] (input positions, NO_FACTOR where unused): each non-position input alone,
    then every monomial of the position inputs of degree 1..degree."""
    energy = [[i] for i in range(n_inputs - n_position)]
    pos = list(range(n_inputs - n_position, n_inputs))
    poly = [list(c) for d in range(1, degree + 1) for c in combinations_with_replacement(pos, d)]
    return np.array([t + [NO_FACTOR] * (MAX_FACTORS - len(t)) for t in energy + poly], np.uint8)


def _products(Z: np.ndarray, terms: np.ndarray) -> np.ndarray:
    out = np.ones((len(Z), len(terms)))
    for k, t in enumerate(terms):
        for f in t:
            if f != NO_FACTOR:
                out[:, k] *= Z[:, f]
    return out


@dataclass
class LinearHeightClass:
    """score(x) = bias + sum_k coef[k] * prod_f z[terms[k, f]], z = (x - offset) * scale; class 1 when score > 0.
    log_energy(x) = score(x) + cut_log_energy_j (the estimate of log(m g h / J))."""

    offset: np.ndarray      # [n_inputs]
    scale: np.ndarray       # [n_inputs]
    terms: np.ndarray       # [T, MAX_FACTORS] uint8
    coef: np.ndarray        # [T]
    bias: float             # the estimate's intercept minus the cut
    cut_log_energy_j: float

    classes_ = np.array([0, 1])

    @property
    def n_features_in_(self) -> int:
        return int(len(self.offset))

    def score(self, X: np.ndarray) -> np.ndarray:
        Z = (np.asarray(X, float) - self.offset) * self.scale
        return self.bias + _products(Z, self.terms) @ self.coef

    def log_energy(self, X: np.ndarray) -> np.ndarray:
        return self.score(X) + self.cut_log_energy_j

    def predict(self, X: np.ndarray) -> np.ndarray:
        return (self.score(X) > 0).astype(int)

    # ----- file (plain arrays, no code) -----
    def save(self, target) -> None:
        meta = {"format": FORMAT, "n_inputs": self.n_features_in_, "n_terms": int(len(self.terms))}
        np.savez(target, meta=np.array(json.dumps(meta)), offset=np.asarray(self.offset, float),
                 scale=np.asarray(self.scale, float), terms=np.asarray(self.terms, np.uint8),
                 coef=np.asarray(self.coef, float), bias=np.array([self.bias, self.cut_log_energy_j], float))

    @classmethod
    def load(cls, path, data: bytes | None = None) -> "LinearHeightClass":
        """The model in `path` (or in `data`, its bytes already read and checked by the caller); a damaged or
        crafted file is a DataError naming it."""
        a = read_arrays(path, data, "linear class file")
        try:
            meta = json.loads(str(a["meta"][()]))
            if not isinstance(meta, dict) or meta.get("format") != FORMAT:
                raise ValueError(f"meta: not a {FORMAT} file")
            n, t = int(meta["n_inputs"]), int(meta["n_terms"])
            offset, scale, coef, bias = (np.asarray(a[k], float) for k in ("offset", "scale", "coef", "bias"))
            terms = np.asarray(a["terms"])
            if (offset.shape != (n,) or scale.shape != (n,) or coef.shape != (t,) or bias.shape != (2,)
                    or terms.shape != (t, MAX_FACTORS) or terms.dtype != np.uint8 or not 0 < n < NO_FACTOR):
                raise ValueError("array shapes disagree with meta")
            if not all(np.isfinite(v).all() for v in (offset, scale, coef, bias)):
                raise ValueError("non-finite values")
            if np.any((terms != NO_FACTOR) & (terms >= n)):
                raise ValueError("a term reads an input beyond n_inputs")
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise DataError(path, None, f"not a valid linear class file ({type(exc).__name__}: {exc})") from None
        return cls(offset, scale, terms, coef, float(bias[0]), float(bias[1]))


# A model without a site map also keeps one linear estimate per channel left out (`three_channel_inputs`): a
# drop with one channel without an onset (dead, disconnected) gets its class from the other three channels'
# energies and the physics localiser's three-sensor position, as its position comes from that localiser.
THREE_CHANNEL_FILE = "linear_energy_without_{}.npz"


def three_channel_inputs(raw: dict, phys_xy_mm: np.ndarray, left_out: int) -> np.ndarray:
    """LINEAR_CLASS_FEATURES over the three channels other than `left_out`, from the core's per-channel
    energies (raw window_energy, diff_energy, energy): the summed arrival energy, the three difference energies
    summed, the channels' mean log energy, then the physics position. [R, 7], computed by the core
    (impactcore three_channel_inputs: the board's numbers, bit for bit)."""
    from . import _core

    f32 = lambda a: np.ascontiguousarray(np.asarray(a, np.float32))  # noqa: E731
    return np.asarray(_core.three_channel_inputs_batch(f32(raw["window_energy"]), f32(raw["diff_energy"]),
                                                       f32(raw["energy"]), f32(phys_xy_mm), int(left_out)), float)


def class_cut(energy_j: np.ndarray, threshold_j: float) -> float:
    """log of the boundary between the two classes: the geometric mean of the lowest "high" energy and the
    highest "low" one (the drops' energies are a few discrete heights; any value between them labels the
    training drops alike, the middle is the farthest from both)."""
    e = np.asarray(energy_j, float)
    lo, hi = e[e < threshold_j], e[e >= threshold_j]
    if not lo.size or not hi.size:
        raise DataError("training data", "height_mm", "all drops fall in one energy class")
    return float(0.5 * (np.log(lo.max()) + np.log(hi.min())))


def fit_linear_height_class(X: np.ndarray, energy_j: np.ndarray, threshold_j: float) -> LinearHeightClass:
    """Ridge (alpha by leave-one-out over 1e-3..1e3, standardised terms) of log(m g h) on X's
    LINEAR_CLASS_FEATURES columns; the standardisations folded into coef and bias, the cut into the bias."""
    from sklearn.linear_model import RidgeCV

    X = np.asarray(X, float)
    offset = X.mean(0)
    sd = X.std(0)
    scale = 1.0 / np.where(sd > 0, sd, 1.0)
    terms = design_terms(X.shape[1])
    D = _products((X - offset) * scale, terms)
    mu, dsd = D.mean(0), D.std(0)
    dsd = np.where(dsd > 0, dsd, 1.0)
    fit = RidgeCV(alphas=np.logspace(-3, 3, 13)).fit((D - mu) / dsd, np.log(energy_j))
    coef = fit.coef_ / dsd
    cut = class_cut(energy_j, threshold_j)
    return LinearHeightClass(offset, scale, terms, coef, float(fit.intercept_ - coef @ mu - cut), cut)


def fit_three_channel_classes(raw: dict, phys_xy_mm: np.ndarray, energy_j: np.ndarray, threshold_j: float) -> dict:
    """Channel -> the linear estimate of log m g h on the other three channels' energies and the physics position
    (`three_channel_inputs` of the training drops' raw core features, all channels with an onset), fitted as the
    four-channel one with the model's class boundary (threshold_j). {} when the drops hold one class only."""
    try:
        class_cut(energy_j, threshold_j)
    except DataError:
        return {}
    return {c: fit_linear_height_class(three_channel_inputs(raw, phys_xy_mm, c), energy_j, threshold_j)
            for c in range(np.asarray(raw["energy"]).shape[1])}


def position_groups(xy_mm: np.ndarray) -> np.ndarray:
    """One group per drop position (a case's repetitions share one), as twin_oof's folds."""
    return np.unique(np.round(np.asarray(xy_mm, float), 1), axis=0, return_inverse=True)[1].ravel()


def out_of_fold_classes(X_forest: np.ndarray, X_linear: np.ndarray, energy_j: np.ndarray, xy_mm: np.ndarray,
                        settings, n_folds: int = 5) -> dict:
    """Each training drop's energy class out of fold, by the classifier forest (settings.classifier() on
    X_forest) and by the linear estimate (on X_linear), both fitted on the other folds with their own
    75th-percentile threshold; folds grouped by position. Returns forest_class, linear_class and class_label
    (-1: none)."""
    from sklearn.model_selection import GroupKFold

    groups = position_groups(xy_mm)
    k = min(n_folds, int(groups.max()) + 1)
    out = {key: np.full(len(energy_j), -1) for key in ("forest_class", "linear_class", "class_label")}
    if k < 2:
        return out
    for tr, va in GroupKFold(k).split(X_forest, groups=groups):
        threshold = float(np.percentile(energy_j[tr], 75))
        label = (np.asarray(energy_j) >= threshold).astype(int)
        out["class_label"][va] = label[va]
        if np.unique(label[tr]).size < 2:
            continue
        out["forest_class"][va] = settings.classifier().fit(X_forest[tr], label[tr]).predict(X_forest[va])
        out["linear_class"][va] = fit_linear_height_class(X_linear[tr], energy_j[tr], threshold).predict(X_linear[va])
    return out


def energy_class_choice(oof: dict) -> dict:
    """Whether the linear estimate replaces the classifier forest, from out_of_fold_classes: when it classifies
    more of the training drops right out of fold (a drop without a class counts as wrong for both). The record
    for the model card."""
    label = oof["class_label"]
    scored = label >= 0
    if not scored.any():
        return {"use_linear": False, "reason": "no out-of-fold class (too few positions)"}
    right_forest = oof["forest_class"][scored] == label[scored]
    right_linear = oof["linear_class"][scored] == label[scored]
    forest, linear = float(np.mean(right_forest)), float(np.mean(right_linear))
    se = float(np.sqrt(np.sum(right_forest != right_linear))) / int(scored.sum())
    return {"use_linear": bool(linear > forest),
            "rule": "out of fold on the training drops (position-grouped folds): the linear estimate of log m g h "
                    "replaces the classifier forest when its class accuracy is higher",
            "forest_class_accuracy": forest, "linear_class_accuracy": linear, "class_difference_se": se,
            "n_drops": int(scored.sum())}


def linear_tables(model: LinearHeightClass) -> dict:
    """The board's form of the model in the node-table arrays (impactapp::linear_terms): roots [T] = each term's
    first factor in `feature` (3 k), feature [3 T] = the factors' input positions (255: none), value = [coef
    (T), bias, offset_0, scale_0, offset_1, scale_1, ...]; no skip, leaf or leaf_value (impactapp's are null)."""
    T = len(model.terms)
    value = np.concatenate([model.coef, [model.bias], np.c_[model.offset, model.scale].ravel()])
    return {"roots": (np.arange(T) * MAX_FACTORS).astype(np.int32),
            "feature": np.asarray(model.terms, np.uint8).ravel(),
            "value": value.astype(np.float32)}


def linear_tables_score(tables: dict, inputs: np.ndarray) -> np.ndarray:
    """linear_tables' arithmetic in float32 as the board runs it (the emulator's check of the export)."""
    x = np.asarray(inputs, np.float32)
    roots, feature, value = tables["roots"], tables["feature"], np.asarray(tables["value"], np.float32)
    T = len(roots)
    s = np.full(len(x), value[T], np.float32)
    for k in range(T):
        p = np.full(len(x), value[k], np.float32)
        for f in feature[roots[k]:roots[k] + MAX_FACTORS]:
            if f != NO_FACTOR:
                p = p * ((x[:, f] - value[T + 1 + 2 * f]) * value[T + 2 + 2 * f])
        s = s + p
    return s


def linear_c(model: LinearHeightClass, name: str) -> str:
    """The model as one C function (the m2cgen form's counterpart): 0.5 + score in float32, so the caller's
    `> 0.5` is the class."""
    n = model.n_features_in_
    t = linear_tables(model)
    v = t["value"]
    T = len(model.terms)
    lines = [f"float {name}(const float* input) {{"]
    lines += [f"  const float z{i} = (input[{i}] - {float(v[T + 1 + 2 * i])!r}f) * {float(v[T + 2 + 2 * i])!r}f;"
              for i in range(n)]
    lines.append(f"  float s = {float(v[T])!r}f;")
    for k, term in enumerate(model.terms):
        factors = " * ".join(f"z{f}" for f in term if f != NO_FACTOR)
        lines.append(f"  s += {float(v[k])!r}f * {factors};")
    lines += ["  return 0.5f + s;", "}", ""]
    return "\n".join(lines)
