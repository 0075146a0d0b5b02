"""The twin's figures out of fold on the training drops: its reported position (the uncertainty's calibration,
models.ImpactModel.fit) and, for a measured session's calibrated twin, whether it earns its place against the
forests and the measured classifier (twin_choice; docs/findings.md "The calibrated twin's site map on a
measured-trained model")."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from sklearn.model_selection import GroupKFold

from .errors import DataError
from .sitemap import SiteMap
from .twin import estimate as twin_estimate
from .twin import fit_twin

if TYPE_CHECKING:
    from .models import ForestSettings


def out_of_fold_twin(X_loc: np.ndarray, phys_xy_mm: np.ndarray, xy_mm: np.ndarray, height_mm: np.ndarray,
                     feats: np.ndarray, usable: np.ndarray, site_map: SiteMap, settings: ForestSettings,
                     n_folds: int = 5, X_energy: np.ndarray | None = None, energy_j: np.ndarray | None = None,
                     twin_classifier=None) -> dict:
    """The twin's reported position of every training drop as a new drop would get it: forests and twin fit
    on the other folds, then the match around the forests' position. Folds group the drops by position (a
    case's repetitions share one), so no drop is matched by forests that saw its case; in-sample the
    forests start the twin at almost the true position and its errors read 20 % small. Returns error_mm,
    spread_mm, misfit, log10_height_mm (the height estimate) per drop (NaN where the twin gives no estimate), and
    the folds' forest_xy_mm and twin_xy_mm.
    With X_energy (MEASURED_ENERGY_FEATURES columns), energy_j and twin_classifier (the ForestSettings of the
    twin's stumps, models.TWIN_CLASSIFIER) also each drop's out-of-fold energy class
    both ways (measured_class: the classifier without a site map, twin_class: the twin's stumps; -1 none) and
    its label (class_label, the folds' own 75th-percentile threshold): what `twin_choice` compares."""
    xy = np.asarray(xy_mm, float)
    groups = np.unique(np.round(xy, 1), axis=0, return_inverse=True)[1].ravel()
    k = min(n_folds, int(groups.max()) + 1)
    if k < 2:
        raise DataError("training data", "x_mm, y_mm", "the uncertainty's calibration needs drops at >= 2 positions")
    out = {key: np.full(len(xy), np.nan) for key in ("error_mm", "spread_mm", "misfit", "log10_height_mm")}
    out["forest_xy_mm"] = np.full((len(xy), 2), np.nan)
    out["twin_xy_mm"] = np.full((len(xy), 2), np.nan)
    classes = X_energy is not None and energy_j is not None and twin_classifier is not None
    if classes:
        for key in ("measured_class", "twin_class", "class_label"):
            out[key] = np.full(len(xy), -1)
    resid = xy - phys_xy_mm
    for tr, va in GroupKFold(k).split(xy, groups=groups):
        start = phys_xy_mm[va] + np.stack([settings.regressor().fit(X_loc[tr], resid[tr, c]).predict(X_loc[va])
                                           for c in (0, 1)], axis=1)
        out["forest_xy_mm"][va] = start
        fit = fit_twin(feats[tr], usable[tr], site_map, xy[tr], height_mm[tr])
        est = twin_estimate(site_map, fit, feats[va], usable[va], start)
        ok = np.asarray(est["status"]) == 0
        rows = va[ok]
        out["twin_xy_mm"][rows] = np.asarray(est["xy_mm"], float)[ok]
        out["error_mm"][rows] = np.linalg.norm(np.asarray(est["xy_mm"], float)[ok] - xy[rows], axis=1)
        out["spread_mm"][rows] = np.asarray(est["spread_mm"], float)[ok]
        out["misfit"][rows] = np.asarray(est["misfit"], float)[ok]
        out["log10_height_mm"][rows] = np.asarray(est["log10_height_mm"], float)[ok]
        if classes:
            # as ImpactModel.fit trains each classifier, on this fold's training drops only
            threshold = float(np.percentile(energy_j[tr], 75))
            label = (np.asarray(energy_j) >= threshold).astype(int)
            out["class_label"][va] = label[va]
            if np.unique(label[tr]).size < 2:
                continue
            clf = settings.classifier().fit(X_energy[tr], label[tr])
            out["measured_class"][va] = clf.predict(X_energy[va])
            own = twin_estimate(site_map, fit, feats[tr], usable[tr], phys_xy_mm[tr])["log10_height_mm"]
            fine = np.isfinite(own)
            if np.unique(label[tr][fine]).size < 2:
                continue
            stumps = twin_classifier.classifier().fit(own[fine, None], label[tr][fine])
            est_h = np.asarray(est["log10_height_mm"], float)
            good = ok & np.isfinite(est_h)
            out["twin_class"][va[good]] = stumps.predict(est_h[good, None])
    return out


def twin_choice(oof: dict, xy_mm: np.ndarray) -> dict:
    """Whether a site map's twin earns its place in a measured-trained model, from the training drops' out-of-fold
    figures (out_of_fold_twin with classes): the twin replaces both the reported position (its match around the
    forests') and the energy class (its height estimate), so it is kept when, over the drops both place, its
    position's MAE per axis is not above the forests' and its class accuracy not below the measured classifier's
    (a drop the twin cannot match counts as a wrong class). Returns the record for the model card (use_twin and
    the four figures)."""
    xy = np.asarray(xy_mm, float)
    both = np.isfinite(oof["forest_xy_mm"]).all(1) & np.isfinite(oof["twin_xy_mm"]).all(1)
    if not both.any():
        return {"use_twin": False, "reason": "the twin matched no training drop out of fold"}
    forest = float(np.mean(np.abs(oof["forest_xy_mm"][both] - xy[both])))
    twin = float(np.mean(np.abs(oof["twin_xy_mm"][both] - xy[both])))
    label = oof["class_label"]
    right_measured = oof["measured_class"] == label
    right_twin = oof["twin_class"] == label
    measured_acc, twin_acc = float(np.mean(right_measured)), float(np.mean(right_twin))
    # the paired difference's standard error (McNemar: the drops one gets right and the other wrong)
    se = float(np.sqrt(np.sum(right_measured != right_twin))) / len(label)
    use = twin <= forest and twin_acc >= measured_acc - 2.0 * se
    return {"use_twin": bool(use), "rule": "out of fold on the training drops (position-grouped folds): the twin's "
            "MAE <= the forests' and its class accuracy not below the measured classifier's by more than two "
            "standard errors of the paired difference",
            "forest_mae_mm": forest, "twin_mae_mm": twin, "measured_class_accuracy": measured_acc,
            "twin_class_accuracy": twin_acc, "class_difference_se": se, "n_drops": int(both.sum())}
