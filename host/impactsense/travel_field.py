"""Each channel's travel-time residual as a smooth field over the plate, learnt from the training drops, and the
physics positions it gives (host-side position members; docs/findings.md "Session 19: anyrig").

The core's travel model (one velocity, an ellipse's metric, the picked cycle's dispersion) leaves a residual at the
training drops' true positions that repeats from drop to drop at a site: on the synthetic rigs its part shared by a
site's two drops is 1.3-3 x the part that differs between them (the picks' own noise). It differs per channel (a
disc's own near field, the reflections that reach that disc, the dispersion over its paths), so edge_travel's bases,
shared by every channel, take little of it. Here each pick set's centred residual r_ik (ToA less the travel model at
p_k, less the drop's mean over its four channels) is fitted per channel i by a Gaussian process over the position
(scikit-learn: a constant x RBF kernel plus white noise, hyperparameters by marginal likelihood). The field at a
position is the GP's mean; the localiser (edge_travel._localise, the core's) runs on the picks less the field at its
last position, PASSES times, from the core's own position.

A field fitted on the drops it places would place them too well: the training drops' positions (what the forests
of its members learn from, and what correction_scale's out-of-fold rule judges) come from fields fitted without
their site's fold (FOLDS, grouped by drop site).
"""

from __future__ import annotations

import warnings

import numpy as np

from .edge_travel import _localise, _metric, pick_set_arrivals
from .travel import travel_distances

FIELD_MEMBERS = ("threshold_field", "band_field")
PICK_SETS = ("threshold", "band")
PASSES = 3
FOLDS = 5
MIN_SITES = 20        # fewer training sites: no field (a smooth map of four channels from fewer is guesswork)
LENGTH_BOUNDS_MM = (20.0, 500.0)
MAX_SITES = 400       # more sites are thinned (the GP's cost grows as their number cubed)
KEYS = ("sites_mm", "alpha", "length_mm", "amplitude", "mean_us", "scale_us")


def _residuals(raw: dict, xy_mm: np.ndarray, signal, pick_set: str):
    toa, use, scale, v = pick_set_arrivals(raw, signal, pick_set)
    resid = toa - travel_distances(np.asarray(xy_mm, float), signal.sensor_xy_mm, _metric(signal, pick_set)) * scale / v
    rows = use.all(1) & np.isfinite(resid).all(1)
    r = resid[rows] - resid[rows].mean(1, keepdims=True)
    return r, rows


def fit_field(raw: dict, xy_mm: np.ndarray, signal, pick_set: str) -> dict | None:
    """A pick set's field (plain numbers, KEYS) from drops at known positions with four picks, or None with fewer
    than MIN_SITES distinct positions."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    xy = np.asarray(xy_mm, float)
    r, rows = _residuals(raw, xy, signal, pick_set)
    # one point per drop site: the mean residual of its drops (the GP's cost grows as the points cubed)
    X, site = np.unique(np.round(xy[rows], 1), axis=0, return_inverse=True)
    site = np.ravel(site)
    if len(X) < MIN_SITES:
        return None
    r = np.stack([np.bincount(site, r[:, c]) for c in range(r.shape[1])], 1) / np.bincount(site)[:, None]
    if len(X) > MAX_SITES:
        keep = np.linspace(0, len(X) - 1, MAX_SITES).round().astype(int)
        X, r = X[keep], r[keep]
    out = {k: [] for k in KEYS}
    out["sites_mm"] = X.tolist()
    for c in range(r.shape[1]):
        kernel = ConstantKernel(1.0) * RBF(100.0, LENGTH_BOUNDS_MM) + WhiteKernel(0.5)
        with warnings.catch_warnings():   # a length at its bound is a fit, not a fault the user can act on
            warnings.simplefilter("ignore", ConvergenceWarning)
            gp = GaussianProcessRegressor(kernel, normalize_y=True).fit(X, r[:, c])
        k = gp.kernel_
        out["alpha"].append([float(a) for a in np.ravel(gp.alpha_)])
        out["length_mm"].append(float(k.k1.k2.length_scale))
        out["amplitude"].append(float(k.k1.k1.constant_value))
        out["mean_us"].append(float(np.ravel(gp._y_train_mean)[0]))
        out["scale_us"].append(float(np.ravel(gp._y_train_std)[0]))
    return out


def field_at(field: dict, xy_mm: np.ndarray) -> np.ndarray:
    """[R, 4] the field's travel-time correction (us) at positions xy_mm [R, 2] (0 where a position is NaN)."""
    xy = np.asarray(xy_mm, float).reshape(-1, 2)
    ok = np.isfinite(xy).all(1)
    p = np.where(ok[:, None], xy, 0.0)
    sites = np.asarray(field["sites_mm"], float)
    d2 = ((p[:, None, :] - sites[None]) ** 2).sum(2)
    cols = []
    for c in range(len(field["alpha"])):
        k = field["amplitude"][c] * np.exp(-0.5 * d2 / field["length_mm"][c] ** 2)
        cols.append(field["mean_us"][c] + field["scale_us"][c] * (k @ np.asarray(field["alpha"][c], float)))
    return np.where(ok[:, None], np.stack(cols, 1), 0.0)


def fit_fields(raw: dict, xy_mm: np.ndarray, signal) -> dict:
    """{pick set: field} for the pick sets the signal runs (the band picks when on) that could be fitted."""
    out = {}
    for ps in PICK_SETS:
        if ps == "band" and not (float(signal.band_pick_hz) > 0 and float(signal.band_velocity_mm_per_us) > 0):
            continue
        field = fit_field(raw, xy_mm, signal, ps)
        if field is not None:
            out[ps] = field
    return out


def field_positions(raw: dict, signal, fields: dict) -> dict[str, np.ndarray]:
    """{member name: [R, 2] the localiser's position on the picks less the pick set's field} (NaN where the
    localiser did not place the drop)."""
    out = {}
    for ps, field in fields.items():
        n = len(np.asarray(raw["toa_us"]))
        p = _localise(raw, signal, ps, np.zeros((n, 4)))
        for _ in range(PASSES):
            p = _localise(raw, signal, ps, field_at(field, p))
        out[f"{ps}_field"] = p
    return out


def out_of_fold_positions(raw: dict, xy_mm: np.ndarray, signal, sites: np.ndarray) -> dict[str, np.ndarray]:
    """field_positions of the (training) drops, each from fields fitted without its site's fold (FOLDS grouped by
    site); a member whose field could not be fitted in some fold is left out."""
    from sklearn.model_selection import GroupKFold

    xy = np.asarray(xy_mm, float)
    n = len(xy)
    sets = list(fit_fields(raw, xy, signal))
    out = {f"{ps}_field": np.full((n, 2), np.nan) for ps in sets}
    for fit_rows, held in GroupKFold(FOLDS).split(xy, groups=sites):
        sub = {k: np.asarray(v)[fit_rows] for k, v in raw.items()}
        fields = {ps: f for ps, f in fit_fields(sub, xy[fit_rows], signal).items() if ps in sets}
        if set(fields) != set(sets):
            return {}
        held_raw = {k: np.asarray(v)[held] for k, v in raw.items()}
        for name, pos in field_positions(held_raw, signal, fields).items():
            out[name][held] = pos
    return out


def training_fields(raw: dict, xy_mm: np.ndarray, signal) -> tuple[dict, dict | None]:
    """(fit_fields of the training drops, their out_of_fold_positions; None without a field or when a fold could
    not fit one): what models.ImpactModel.fit hands correction_scale's rule."""
    from .correction_scale import drop_sites

    fields = fit_fields(raw, xy_mm, signal)
    oof = out_of_fold_positions(raw, xy_mm, signal, drop_sites(np.asarray(xy_mm, float))) if fields else None
    return fields, (oof or None)


def member_field_positions(raw: dict, signal, card: dict, members) -> dict[str, np.ndarray]:
    """field_positions from a model card's fields when the model's members include a field member, else {}."""
    return field_positions(raw, signal, card["travel_field"]) if any(n in members for n in FIELD_MEMBERS) else {}


def check_card_fields(card: dict, card_path, names) -> None:
    """Raises DataError naming the card's travel_field when a field member is listed and the fields are not as
    fit_fields writes them."""
    from .errors import DataError

    if any(n in FIELD_MEMBERS for n in names) and not fields_ok(card.get("travel_field")):
        raise DataError(card_path, "travel_field", "the field members need fields per pick set (travel_field.KEYS, "
                                                   "numbers)")


def fields_ok(fields) -> bool:
    """A model card's travel_field entry as fit_fields writes it."""
    if not isinstance(fields, dict) or not fields or any(k not in PICK_SETS for k in fields):
        return False
    for f in fields.values():
        if not isinstance(f, dict) or set(f) != set(KEYS):
            return False
        try:
            sites = np.asarray(f["sites_mm"], float)
            alpha = np.asarray(f["alpha"], float)
            per = [np.asarray(f[k], float) for k in ("length_mm", "amplitude", "mean_us", "scale_us")]
        except (TypeError, ValueError):
            return False
        n_ch = len(per[0])
        if sites.ndim != 2 or sites.shape[1] != 2 or alpha.shape != (n_ch, len(sites)) \
                or any(p.shape != (n_ch,) for p in per) or not all(np.isfinite(a).all() for a in (sites, alpha, *per)) \
                or (per[0] <= 0).any():
            return False
    return True
