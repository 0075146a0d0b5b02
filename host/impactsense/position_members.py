"""The forests' position members: the threshold and band picks' own positions (POSITION_MEMBERS) and the
localiser's positions on the arrival times corrected for the edges' images (EDGE_MEMBERS, edge_travel.py), with
the rule that keeps the edge correction. models.ImpactModel trains and runs a forest pair on each member.
"""

from __future__ import annotations

import numpy as np

from .level_members import LEVEL_MEMBERS
from .travel_field import FIELD_MEMBERS
from .pipeline import Features
from .signal import SignalConfig

# With the band picks on (impactcore band_onset) the physics position is the mean of the threshold picks' and
# the band picks' own; two more forest pairs then correct each of those two positions (their x, y in place of
# the mean's in the location features) and the reported position is the mean of the three corrected ones:
# their errors differ, and the mean is closer on every split of both other rigs (docs/findings.md, "Band
# picks on three channels; three corrected positions"). Only the host runs them: the board's models
# (board/models.py) keep one pair.
POSITION_MEMBERS = ("threshold", "band")
# With the edge correction of the arrival times kept (edge_travel.py, chosen by the training drops), three more
# members: the physics, threshold and band positions the localiser gives on the corrected picks, each with its
# forest pair; the reported position is then the mean over every member that placed the drop (docs/findings.md
# "Edge images in the travel time").
EDGE_MEMBERS = ("physics_edge", "threshold_edge", "band_edge")
MEMBER_FILES = {f"{axis}_{name}": f"forest_d{axis}_{name}.npz" for name in POSITION_MEMBERS + EDGE_MEMBERS
                + LEVEL_MEMBERS + FIELD_MEMBERS for axis in "xy"}
# The edge correction is kept when it brings the training drops' physics MAE to this fraction of the core's
# (the rule of pipeline.STARTS_GAIN). It is tried only with drops at this many distinct positions or more (five
# per coefficient of a pick set: its bases change over the plate, near every edge): on fewer the eight numbers
# fitted on the drops that judge them pass the rule by fitting those drops.
EDGE_GAIN = 0.97
EDGE_MIN_SITES = 40


def member_positions(features: Features) -> dict[str, np.ndarray] | None:
    """The threshold picks' and the band picks' own positions [R, 2] (POSITION_MEMBERS; the core's physics
    position is their mean where the band picks placed the drop, the threshold picks' alone elsewhere), NaN
    where the band picks did not place the drop; None when no row has a band position."""
    band = features.raw.get("band_xy_mm")
    if band is None:
        return None
    band = np.asarray(band, float)
    ok = np.isfinite(band).all(1)
    if not ok.any():
        return None
    threshold = np.where(ok[:, None], 2.0 * np.asarray(features.phys_xy_mm, float) - band, np.nan)
    return {"threshold": threshold, "band": np.where(ok[:, None], band, np.nan)}


def threshold_positions(features: Features) -> np.ndarray:
    """The threshold picks' own position of every row [R, 2]: the core's physics position where the band picks
    did not place the drop."""
    positions = member_positions(features)
    phys = np.asarray(features.phys_xy_mm, float)
    if positions is None:
        return phys
    return np.where(np.isfinite(positions["threshold"]).all(1)[:, None], positions["threshold"], phys)


def edge_positions(features: Features, signal: SignalConfig, coefs: dict) -> dict[str, np.ndarray]:
    """EDGE_MEMBERS' positions [R, 2] (NaN where that member did not place the drop): the localiser on the picks
    corrected by edge_travel's coefficients, from the core's own positions."""
    from .edge_travel import positions

    band = member_positions(features)
    out = positions(features.raw, signal, coefs, threshold_positions(features),
                    None if band is None else band["band"])
    return {"physics_edge": out["physics"], "threshold_edge": out["threshold"], "band_edge": out["band"]}


def choose_edge_travel(features: Features, xy_mm: np.ndarray, signal: SignalConfig) -> dict | None:
    """edge_travel's coefficients per pick set fitted on these (training) drops, when the corrected physics
    positions are clearly closer to the truth (EDGE_GAIN), else None (also with drops at fewer than
    EDGE_MIN_SITES positions)."""
    from .edge_travel import fit_correction

    if not features.usable.any() or len(np.unique(np.round(np.asarray(xy_mm, float), 1), axis=0)) < EDGE_MIN_SITES:
        return None
    coefs = {"threshold": fit_correction(features.raw, xy_mm, signal, "threshold"), "band": None}
    if coefs["threshold"] is None:
        return None
    if member_positions(features) is not None and float(signal.band_velocity_mm_per_us) > 0:
        coefs["band"] = fit_correction(features.raw, xy_mm, signal, "band")
    xy = np.asarray(xy_mm, float)
    new = edge_positions(features, signal, coefs)["physics_edge"]
    old = np.asarray(features.phys_xy_mm, float)
    ok = np.isfinite(new).all(1) & np.isfinite(old).all(1)
    if not ok.any():
        return None
    gain = float(np.mean(np.abs(new[ok] - xy[ok]))) < EDGE_GAIN * float(np.mean(np.abs(old[ok] - xy[ok])))
    return coefs if gain else None


def edge_coefficients_ok(edge) -> bool:
    """A model card's edge_travel entry as save writes it: the two pick sets' coefficient lists (band may be None)."""
    from .edge_travel import N_BASES

    def numbers(v) -> bool:
        return (isinstance(v, list) and len(v) == N_BASES
                and all(isinstance(c, (int, float)) and not isinstance(c, bool) and np.isfinite(c) for c in v))

    return (isinstance(edge, dict) and set(edge) == {"threshold", "band"} and numbers(edge["threshold"])
            and (edge["band"] is None or numbers(edge["band"])))


def check_card_members(card: dict, card_path, names: list[str]) -> dict:
    """The card's edge_travel entry ({} when absent); raises DataError when the card lists an edge member without
    edge_coefficients_ok coefficients, a field member without travel_field.fields_ok fields or a member_stack
    that is not member_stack.stack_ok."""
    from .errors import DataError
    from .member_stack import stack_ok
    from .travel_field import check_card_fields

    edge = card.get("edge_travel", {})
    if any(n in EDGE_MEMBERS for n in names) and not edge_coefficients_ok(edge):
        raise DataError(card_path, "edge_travel", "the edge members need {\"threshold\": [numbers], \"band\": "
                                                  "[numbers] or null} (edge_travel.N_BASES each)")
    check_card_fields(card, card_path, names)
    if "member_stack" in card and not stack_ok(card["member_stack"], names):
        raise DataError(card_path, "member_stack", "must be {\"keep\": true/false, \"weights\": {name: weight >= 0}} "
                                                   "naming \"mean\", \"main\" or the position_members")
    return edge


def member_inputs(X_loc: np.ndarray, base: np.ndarray, names: list[str]) -> np.ndarray:
    """The location features (columns `names`) with the physics position's columns replaced by a member's
    position."""
    out = np.array(X_loc, float, copy=True)
    out[:, [names.index("phys_x_mm"), names.index("phys_y_mm")]] = base
    return out


def fit_member_pairs(bases: dict, X_loc: np.ndarray, xy: np.ndarray, regressor, names: list[str],
                     all_or_none: bool) -> dict:
    """A forest pair (regressor(): a new regressor) per member position (name -> base [R, 2], NaN where the
    member did not place the drop) on the rows it placed, learning the correction to the truth from the location
    features (columns `names`) with the member's x, y; a member on fewer than 10 rows is left out (all_or_none:
    then none is kept)."""
    out = {}
    for name, base in bases.items():
        rows = np.isfinite(base).all(1)
        if rows.sum() < 10:
            if all_or_none:
                return {}
            continue
        Xm = member_inputs(X_loc[rows], base[rows], names)
        out[name] = tuple(regressor().fit(Xm, xy[rows, k] - base[rows, k]) for k in range(2))
    return out


def each_member_position(main_xy: np.ndarray, phys: np.ndarray, members: dict, X_loc: np.ndarray,
                         positions: dict | None, edges: dict | None, names: list[str]) -> dict[str, tuple]:
    """Each member's corrected position and its base [R, 2] (NaN on the rows it did not place): "main" the main
    pair's (main_xy, phys), the POSITION_MEMBERS where the band picks placed the drop, `edges` (name -> base: the
    EDGE_MEMBERS, the level and field members) where they did. X_loc: the rows' location features, columns
    `names`."""
    n = len(phys)
    out = {"main": (np.array(main_xy, float, copy=True), np.array(phys, float, copy=True))}

    def one(name, rows, base):
        corrected, at = np.full((n, 2), np.nan), np.full((n, 2), np.nan)
        out[name] = (corrected, at)
        if not np.any(rows):    # no drop of these rows placed by the member (a fold of few sites): NaN
            return
        at[rows] = base
        corrected[rows] = base + np.stack([f.predict(member_inputs(X_loc[rows], base, names))
                                           for f in members[name]], 1)

    if positions is not None and all(n in members for n in POSITION_MEMBERS):
        placed = np.isfinite(positions["band"]).all(1)
        for name in POSITION_MEMBERS:
            one(name, placed, positions[name][placed])
    for name, base in (edges or {}).items():   # the EDGE_MEMBERS, the level and field members
        ok = np.isfinite(base).all(1)
        if name in members and ok.any():
            one(name, ok, base[ok])
    return out


def mean_of_members(each: dict) -> tuple[np.ndarray, np.ndarray]:
    """(the mean of each_member_position's corrected positions, the mean of their bases) over the members that
    placed each row."""
    corrected = np.stack([c for c, _ in each.values()])
    base = np.stack([b for _, b in each.values()])
    placed = np.isfinite(corrected).all(2)
    count = placed.sum(0)[:, None]
    return (np.where(placed[..., None], corrected, 0.0).sum(0) / count,
            np.where(placed[..., None], base, 0.0).sum(0) / count)


def joined_position(main_xy: np.ndarray, phys: np.ndarray, members: dict, X_loc: np.ndarray,
                    positions: dict | None, edges: dict | None, names: list[str],
                    stack: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The reported position of rows (the model's forests' position): the mean of the main pair's position
    (main_xy) and every member's corrected position where that member placed the drop (the POSITION_MEMBERS
    where the band picks did; `edges`: name -> base, the EDGE_MEMBERS, level and field members, where they did);
    and the mean of the same positions before correction (phys and the members' own). stack (a model card's
    "member_stack" that was kept, member_stack.py): the first is the stack's weighted sum instead. X_loc: the
    rows' location features, columns `names`."""
    each = each_member_position(main_xy, phys, members, X_loc, positions, edges, names)
    mean, base = mean_of_members(each)
    if stack and stack.get("keep"):
        from .member_stack import stacked_position

        mean = stacked_position(each, mean, stack["weights"])
    return mean, base
