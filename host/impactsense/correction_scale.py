"""The forests' correction of the physics position, scaled as the training drops say (models.ImpactModel.fit).

With few training drops on a plate whose physics position is already good, the whole correction adds more
scatter than it removes (docs/findings.md, "What limits a new user's measured-trained position"). Without a site
map, the correction (the main pair's and every position member's) is scaled by the factor of CORRECTION_SCALES
whose out-of-fold positions of the training drops are closest to the truth, when its gain over the whole
correction is clear; the factor multiplies the trees' leaf values, so saved models, the board's pair and the C
export carry it as they are.
"""

from __future__ import annotations

import copy
import hashlib

import numpy as np

from .position_members import (EDGE_MEMBERS, POSITION_MEMBERS, each_member_position, edge_positions,
                               fit_member_pairs, mean_of_members, member_positions)

CORRECTION_SCALES = (0.0, 0.25, 0.5, 0.75, 1.0)
CORRECTION_FOLDS = 5
CORRECTION_MIN_SITES = 10       # fewer drop sites: the whole correction, no choice (5 folds of >= 2 sites)
CORRECTION_MAX_TREES = 50       # the folds' forests (the choice, not the model)
# A smaller factor is taken only when its out-of-fold gain over the whole correction exceeds one standard error
# of the per-site gains (the one-standard-error rule, the whole correction being the default).
CORRECTION_GAIN_SIGMAS = 1.0
# After the members and the factor: their stack (member_stack.py) in place of the mean, when the drops say so.
STACK = True


def position_forests(X_loc: np.ndarray, phys: np.ndarray, positions: dict | None, edges: dict | None,
                     xy: np.ndarray, settings, names: list[str] | None = None) -> tuple:
    """The forest pair correcting the physics position and, with `positions` (member_positions of the same rows),
    the POSITION_MEMBERS' pairs (all or none), with `edges` (edge_positions) the EDGE_MEMBERS' pairs, as
    ImpactModel.fit fits them; names: X_loc's columns (LOCATION_FEATURES unless a channel is left out). Returns
    (forest_dx, forest_dy, {member: (dx, dy)})."""
    from .models import LOCATION_FEATURES

    names = names or LOCATION_FEATURES
    resid = xy - phys
    fx = settings.regressor().fit(X_loc, resid[:, 0])
    fy = settings.regressor().fit(X_loc, resid[:, 1])
    members = {}
    if positions is not None:
        members = fit_member_pairs({n: positions[n] for n in POSITION_MEMBERS}, X_loc, xy, settings.regressor,
                                   names, all_or_none=True)
    if edges is not None:
        members.update(fit_member_pairs(edges, X_loc, xy, settings.regressor, names, all_or_none=False))
    return fx, fy, members


def _out_of_fold(X_loc, phys, positions, edges, xy, settings, names, sites):
    """The training drops' out-of-fold joined positions, their uncorrected bases and each member's out-of-fold
    (corrected, base) positions (position_members.each_member_position; 5 site-grouped folds, every member
    refitted in each fold with at most CORRECTION_MAX_TREES trees)."""
    from sklearn.model_selection import GroupKFold

    from .models import ForestSettings

    fold_settings = ForestSettings(**{**settings.__dict__,
                                      "n_estimators": min(settings.n_estimators, CORRECTION_MAX_TREES)})
    each: dict = {}
    take = lambda d, r: None if d is None else {k: v[r] for k, v in d.items()}  # noqa: E731
    for fit_rows, held in GroupKFold(CORRECTION_FOLDS).split(X_loc, groups=sites):
        fx, fy, members = position_forests(X_loc[fit_rows], phys[fit_rows], take(positions, fit_rows),
                                           take(edges, fit_rows), xy[fit_rows], fold_settings, names)
        main = phys[held] + np.stack([fx.predict(X_loc[held]), fy.predict(X_loc[held])], 1)
        for name, pair in each_member_position(main, phys[held], members, X_loc[held], take(positions, held),
                                               take(edges, held), names).items():
            for k, part in enumerate(each.setdefault(name, (np.full_like(xy, np.nan), np.full_like(xy, np.nan)))):
                part[held] = pair[k]
    oof, base = mean_of_members(each)
    return oof, base, each


def _per_site(err: np.ndarray, sites: np.ndarray) -> np.ndarray:
    """The mean of err over each site's drops (a site's drops share their error)."""
    inverse = np.unique(sites, return_inverse=True)[1].ravel()
    return np.bincount(inverse, err) / np.bincount(inverse)


def _gain_sigmas(gain: np.ndarray) -> float:
    """The mean per-site gain in its standard errors (0 when the gains do not vary)."""
    return float(gain.mean() / (gain.std(ddof=1) / np.sqrt(gain.size))) if gain.std() > 0 else 0.0


def drop_sites(xy: np.ndarray) -> np.ndarray:
    """Each drop's site index: drops at the same declared position (0.1 mm) share one."""
    return np.unique(np.round(xy, 1), axis=0, return_inverse=True)[1].ravel()


def choose_by_gain(err: list[np.ndarray], sites: np.ndarray, default: int) -> tuple[int, list[float], float]:
    """(the option chosen, the MAE per option, the best option's gain in standard errors) from each option's
    out-of-fold per-drop error err[k] (the same drops): the lowest MAE when its per-site gain over err[default]
    exceeds CORRECTION_GAIN_SIGMAS standard errors, else the default (the one-standard-error rule, written once:
    the correction's factor, the level members, the band picks: band_forests.py)."""
    mae = [float(e.mean()) for e in err]
    best = int(np.argmin(mae))
    z = _gain_sigmas(_per_site(err[default] - err[best], sites))
    return (best if z > CORRECTION_GAIN_SIGMAS else default), mae, z


def choose_factor(err: list[np.ndarray], sites: np.ndarray) -> tuple[int, list[float], float]:
    """(the index into CORRECTION_SCALES chosen, the MAE per factor, the best factor's gain in standard errors)
    from each factor's per-drop error err[k]: the lowest MAE when its gain over the whole correction (the last
    factor), per site, exceeds CORRECTION_GAIN_SIGMAS, else the whole (choose_by_gain)."""
    return choose_by_gain(err, sites, len(err) - 1)


# The last few scale_choice answers by a digest of their inputs: band_forests scores the band picks with the
# same folds the model then runs on the chosen features (the same drops, members and settings: computed once).
_RECENT: dict[str, tuple] = {}
_RECENT_MAX = 4


def _digest(*parts) -> str:
    h = hashlib.sha1()
    for part in parts:
        items = sorted(part.items()) if isinstance(part, dict) else [("", part)]
        for key, value in items:
            h.update(repr(key).encode())
            if isinstance(value, np.ndarray):
                h.update(repr((value.dtype.str, value.shape)).encode())
                h.update(np.ascontiguousarray(value).tobytes())
            else:
                h.update(repr(value).encode())
        h.update(b"|")
    return h.hexdigest()


def scale_choice(X_loc: np.ndarray, phys: np.ndarray, positions: dict | None, edges: dict | None, xy: np.ndarray,
                 settings, names: list[str]) -> tuple[dict, np.ndarray, np.ndarray, dict] | None:
    """choose_correction_scale's choice, the out-of-fold error of each drop at the chosen factor, the drops'
    sites and each member's out-of-fold (corrected, base) positions at that factor; None with fewer than
    CORRECTION_MIN_SITES drop sites. The same inputs again: the same answer (a copy),
    not computed twice."""
    key = _digest(X_loc, phys, positions, edges, np.asarray(xy, float), settings.__dict__, list(names))
    if key not in _RECENT:
        if len(_RECENT) >= _RECENT_MAX:
            _RECENT.pop(next(iter(_RECENT)))
        _RECENT[key] = _scale_choice(X_loc, phys, positions, edges, xy, settings, names)
    return copy.deepcopy(_RECENT[key])


def _scale_choice(X_loc, phys, positions, edges, xy, settings, names):
    xy = np.asarray(xy, float)
    sites = drop_sites(xy)
    if np.unique(sites).size < CORRECTION_MIN_SITES:
        return None
    oof, base, each = _out_of_fold(X_loc, phys, positions, edges, xy, settings, names, sites)
    ok = np.isfinite(oof).all(1) & np.isfinite(base).all(1)
    err = [np.abs(base[ok] + a * (oof[ok] - base[ok]) - xy[ok]).mean(1) for a in CORRECTION_SCALES]
    chosen, mae, z = choose_factor(err, sites[ok])
    drop_err = np.full(len(xy), np.nan)
    drop_err[ok] = err[chosen]
    a = CORRECTION_SCALES[chosen]
    each = {k: (b + a * (c - b), b) for k, (c, b) in each.items()}
    return ({"scale": float(a), "scales": list(CORRECTION_SCALES),
             "out_of_fold_mae_mm": [round(m, 3) for m in mae], "best_gain_sigmas": round(z, 2),
             "folds": CORRECTION_FOLDS}, drop_err, sites, each)


def choose_correction_scale(X_loc: np.ndarray, phys: np.ndarray, positions: dict | None, edges: dict | None,
                            xy: np.ndarray, settings, names: list[str] | None = None) -> dict | None:
    """The CORRECTION_SCALES factor whose out-of-fold positions of the training drops (every member refitted in
    each fold) have the lowest MAE per axis when its gain over the whole correction is clear
    (CORRECTION_GAIN_SIGMAS), else 1, with the MAE per factor; None with fewer than CORRECTION_MIN_SITES drop
    sites. The folds group the drops by their declared position (a case's repetitions stay together), so the
    figure is that of an unseen site, as the held-out drops are. A factor a puts a drop at b + a (corrected - b),
    b the mean of its members' uncorrected positions: what scale_forests(a) makes the model predict. edges:
    name -> base position of the members beyond the POSITION_MEMBERS (the EDGE_MEMBERS, the level members)."""
    from .models import LOCATION_FEATURES

    out = scale_choice(X_loc, phys, positions, edges, xy, settings, names or LOCATION_FEATURES)
    return None if out is None else out[0]


def level_choice(X_loc: np.ndarray, phys: np.ndarray, positions: dict | None, edges: dict | None,
                 levels: dict, xy: np.ndarray, settings, names: list[str]) -> tuple[dict, np.ndarray] | None:
    """choose_level_members' choice and the out-of-fold error of each drop with the members it keeps (at their
    chosen factor), or None."""
    without = scale_choice(X_loc, phys, positions, edges, xy, settings, names)
    if without is None:
        return None
    return with_or_without(without, scale_choice(X_loc, phys, positions, {**(edges or {}), **levels}, xy, settings,
                                                 names))


def with_or_without(without: tuple, with_it: tuple) -> tuple[dict, np.ndarray] | None:
    """The one-standard-error rule between two scale_choice answers on the same drops, the simpler model
    (`without`) the default: ({"keep", "out_of_fold_mae_mm": [without, with], "gain_sigmas", "without": its scale
    choice, "with": its scale choice}, the kept answer's per-drop error), or None when no drop has both."""
    ok = np.isfinite(without[1]) & np.isfinite(with_it[1])
    if not ok.any():
        return None
    z = _gain_sigmas(_per_site(without[1][ok] - with_it[1][ok], without[2][ok]))
    keep = bool(z > CORRECTION_GAIN_SIGMAS)
    return ({"keep": keep, "out_of_fold_mae_mm": [round(float(np.mean(without[1][ok])), 3),
                                                  round(float(np.mean(with_it[1][ok])), 3)],
             "gain_sigmas": round(z, 2), "without": without[0], "with": with_it[0]},
            (with_it if keep else without)[1])


def choose_extra_inputs(X_loc: np.ndarray, X_more: np.ndarray, phys: np.ndarray, positions: dict | None,
                        edges: dict | None, xy: np.ndarray, settings, names: list[str],
                        more_names: list[str]) -> dict | None:
    """Whether the position forests read more location inputs (X_more, columns more_names: X_loc's columns
    `names` and more after them): the training drops' out-of-fold positions (every member refitted in each fold)
    with and without them, each at its own chosen factor; kept when the per-site gain exceeds
    CORRECTION_GAIN_SIGMAS standard errors (with_or_without). Returns {"keep", "out_of_fold_mae_mm": [without,
    with], "gain_sigmas", "without", "with"}, or None with too few sites."""
    without = scale_choice(X_loc, phys, positions, edges, xy, settings, names)
    if without is None:
        return None
    out = with_or_without(without, scale_choice(X_more, phys, positions, edges, xy, settings, more_names))
    return None if out is None else out[0]


def choose_level_members(X_loc: np.ndarray, phys: np.ndarray, positions: dict | None, edges: dict | None,
                         levels: dict, xy: np.ndarray, settings, names: list[str]) -> dict | None:
    """Whether the level members (level_members.py; `levels`: name -> base) join: the training drops' out-of-fold
    positions with and without them, each at its own chosen factor; kept when the per-site gain exceeds
    CORRECTION_GAIN_SIGMAS standard errors. Returns {"keep", "out_of_fold_mae_mm": [without, with],
    "gain_sigmas", "without": scale choice, "with": scale choice}, or None with too few sites."""
    out = level_choice(X_loc, phys, positions, edges, levels, xy, settings, names)
    return None if out is None else out[0]


def scale_forests(forests, scale: float) -> None:
    """Every tree's leaf values times `scale` (the forests' prediction times scale, exported as it is)."""
    if scale == 1.0:
        return
    for forest in forests:
        for tree in forest.estimators_:
            tree.tree_.value[:] *= scale


def scale_model_correction(card: dict, X_loc: np.ndarray, xy: np.ndarray, train, signal, edge: dict,
                           fx, fy, members: dict, settings, levels: dict | None = None,
                           fields: tuple | None = None, names: list[str] | None = None) -> None:
    """ImpactModel.fit's step without a site map: the training drops' (`train`, their Features) choice of the
    factor, recorded in the card ("correction_scale") and applied to the main pair and every member's pair.
    levels (level_members.level_positions of train, or None): the level members join `members` (in place) when
    the out-of-fold rule keeps them (choose_level_members; the card's "level_members"). fields
    (travel_field.training_fields of train: the fields and the members' out-of-fold positions, or None): the same
    rule decides whether the field members join after the level members (the card's "travel_field_members"; kept,
    the fields in "travel_field"). names: X_loc's columns (None: the core's location features)."""
    from .models import LOCATION_FEATURES
    from .pipeline import columns_reading

    names = names or columns_reading(signal.channel_left_out, LOCATION_FEATURES)   # X_loc's columns
    phys = np.asarray(train.phys_xy_mm, float)
    positions = member_positions(train) if any(n in members for n in POSITION_MEMBERS) else None
    edges = edge_positions(train, signal, edge) if edge and any(n in members for n in EDGE_MEMBERS) else None
    level_choice = (choose_level_members(X_loc, phys, positions, edges, levels, xy, settings, names)
                    if levels else None)
    final = dict(edges or {})   # the members beyond the POSITION_MEMBERS the model ends with
    if level_choice is None:
        choice = choose_correction_scale(X_loc, phys, positions, edges, xy, settings, names)
    else:
        card["level_members"] = {k: v for k, v in level_choice.items() if k not in ("with", "without")}
        choice = level_choice["with" if level_choice["keep"] else "without"]
        if level_choice["keep"]:
            final.update(levels)
            members.update(fit_member_pairs(levels, X_loc, xy, settings.regressor, names, all_or_none=False))
    if fields and fields[1]:   # the travel field's members (travel_field.py), by the same rule
        field_choice = choose_level_members(X_loc, phys, positions, dict(final), fields[1], xy, settings, names)
        if field_choice is not None:
            card["travel_field_members"] = {k: v for k, v in field_choice.items() if k not in ("with", "without")}
            if field_choice["keep"]:
                choice, card["travel_field"] = field_choice["with"], fields[0]
                final.update(fields[1])
                members.update(fit_member_pairs(fields[1], X_loc, xy, settings.regressor, names, all_or_none=False))
    if choice is not None:
        card["correction_scale"] = choice
        scale_forests([fx, fy, *(f for pair in members.values() for f in pair)], choice["scale"])
        if STACK and members:   # the members' weighted sum in place of their mean (member_stack.py)
            from .member_stack import choose_stack

            _, _, sites, each = scale_choice(X_loc, phys, positions, final or None, xy, settings, names)  # cached
            stack = choose_stack(each, mean_of_members(each)[0], xy, sites)
            if stack is not None:
                card["member_stack"] = stack
