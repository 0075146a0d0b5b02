"""The position of a drop with one channel without an onset (dead, disconnected), on a model without a site map.

The core then places the drop by the physics localiser on the other three channels' picks (the threshold
picks' position, averaged with the band picks' where those place it too, as on four channels). With three
sensors the localiser has no redundancy: that position is often several times further off than the forests'
four-channel one. At training time, for each channel c, the training drops' own three-sensor position without
c (the core's localiser re-run on their picks with c's left out: edge_travel's localiser, the numbers the core
gives a drop whose channel c has no onset) and a small forest pair learning its correction to the truth from
what a drop with c dead still carries: that position, the arrival time differences and the relative energies
and first peaks among the other three channels (`three_channel_position_inputs`). ImpactModel.predict then
corrects the three-sensor position of a drop by the pair of the channel that is out. Where the training drops'
out-of-fold positions say so, a channel's pair learns on (and corrects) the mean of that position and the
three-sensor positions at the other onset levels instead (three_level_positions.py; card
"three_channel_position_levels"), and / or the positions with edge_travel's correction of the arrival times near
the plate's edges (a model that has it; card "three_channel_position_edge"): with three sensors there is no
redundancy to absorb that travel-time bias, and a drop near an edge or a corner is placed off by the same
centimetres on every repeat.
Last, where the out-of-fold positions say so, the position kept is replaced by a stack (card
"three_channel_position_stack"): a weighted sum of it and each pick set's three-sensor position from its plain
and its corrected picks (pick_correction.py: each pick's error learnt from its own channel's signal), the pair
then learning on that.

The host's forests are the host's only (files "three_channel_position" in the model card, forestfile's plain
arrays). A board model (board.models.board_three_positions) keeps, per channel, boosted shallow trees on the same
inputs where its training drops say so out of fold (card "board_three_position"); `impactsense export` ships
those and the board corrects its three-sensor position with them as the host does. Their gain is in docs/findings.md ("A dead channel
on a model without a site map").
"""

from __future__ import annotations

import numpy as np
from sklearn.ensemble import RandomForestRegressor

from . import _core
from .errors import DataError
from .edge_travel import three_sensor_positions
from .forestfile import load_forest, save_forest
from .pipeline import FEATURE_NAMES, Features

# Small forests: the pair only corrects a position, on the training drops' inputs for one channel out. Leaves of
# a few drops: a three-sensor position's error is mostly its picks' noise, and single-drop leaves learn it.
THREE_POSITION_TREES = 50
FOLD_TREES = 20   # the factor's out-of-fold forests (the choice, not the model)
THREE_POSITION_LEAF = 5
THREE_POSITION_FILE = "forest_d{}_without_{}.npz"
PICK_FILE = "forest_pick_{}.npz"   # the stack's pick corrections (pick_correction.py), per pick set
MIN_DROPS = 10
N_INPUTS = 11   # three_channel_position_inputs: x, y, 3 time differences, 3 energies, 3 first peaks


def three_channel_position_inputs(vector: np.ndarray, position: np.ndarray, channel: int) -> np.ndarray:
    """[R, 11] float32 a drop's inputs without `channel`: the three-sensor position, the three arrival time
    differences among the other channels, their log energies relative to the three's mean and their log first peaks
    (the core's feature vector; none of them reads `channel`): impactcore three_position_inputs, the board's
    numbers bit for bit."""
    v = np.ascontiguousarray(np.asarray(vector, np.float32).reshape(-1, len(FEATURE_NAMES)))
    pos = np.ascontiguousarray(np.asarray(position, np.float32).reshape(-1, 2))
    return np.asarray(_core.three_position_inputs_batch(v, pos, int(channel)))


def _pair(X: np.ndarray, resid: np.ndarray, seed: int, trees: int = THREE_POSITION_TREES) -> tuple:
    return tuple(RandomForestRegressor(trees, min_samples_leaf=THREE_POSITION_LEAF, max_features=1.0,
                                       random_state=seed, n_jobs=1).fit(X, resid[:, k]) for k in range(2))


def correction_factor(X: np.ndarray, resid: np.ndarray, xy: np.ndarray, seed: int = 0) -> tuple[float, np.ndarray | None]:
    """correction_scale's rule on one channel's pair: (the CORRECTION_SCALES factor whose out-of-fold positions
    (folds grouped by drop site) are closest to the truth when its gain over the whole correction exceeds
    CORRECTION_GAIN_SIGMAS standard errors of the per-site gains, else 1; each drop's out-of-fold error at that
    factor, mm). With fewer than CORRECTION_MIN_SITES sites (1, None)."""
    from sklearn.model_selection import GroupKFold

    from .correction_scale import CORRECTION_FOLDS, CORRECTION_MIN_SITES, CORRECTION_SCALES, choose_factor, drop_sites

    sites = drop_sites(xy)
    if np.unique(sites).size < CORRECTION_MIN_SITES:
        return 1.0, None
    oof = np.zeros_like(resid)
    for fit_rows, held in GroupKFold(CORRECTION_FOLDS).split(X, groups=sites):
        oof[held] = np.stack([f.predict(X[held]) for f in _pair(X[fit_rows], resid[fit_rows], seed, FOLD_TREES)], 1)
    err = [np.abs(resid - a * oof).mean(1) for a in CORRECTION_SCALES]
    chosen = choose_factor(err, sites)[0]
    return float(CORRECTION_SCALES[chosen]), err[chosen]


def _candidate(train: Features, xy: np.ndarray, base: np.ndarray, c: int, seed: int) -> dict | None:
    """One three-sensor position's pair for channel c: its rows, pair, factor and out-of-fold errors."""
    X = three_channel_position_inputs(train.vector, base, c)
    rows = np.isfinite(X).all(1) & np.isfinite(xy).all(1)
    if rows.sum() < MIN_DROPS:
        return None
    resid = xy[rows] - base[rows]
    factor, err = correction_factor(X[rows], resid, xy[rows], seed)
    return {"rows": rows, "pair": _pair(X[rows], resid, seed), "factor": factor, "err": err}


def _better(kept: dict, other: dict, xy: np.ndarray) -> bool:
    """The other position's out-of-fold errors beat the kept one's by more than CORRECTION_GAIN_SIGMAS standard
    errors of the per-site gains (choose_factor, on the drops both place)."""
    from .correction_scale import choose_factor, drop_sites

    if kept["err"] is None or other["err"] is None or not np.array_equal(kept["rows"], other["rows"]):
        return False
    return choose_factor([other["err"], kept["err"]], drop_sites(xy[kept["rows"]]))[0] == 0


def _candidates(train: Features, signal, c: int, edge: dict | None):
    """(position [R, 2], on the level mean, with the edge correction) of channel c's three-sensor path, in the
    order they are tried: the plain position, its mean over the onset levels (when `train` carries their picks),
    and with edge (a model's edge_travel coefficients) the same two with edge_travel's correction."""
    from .three_level_positions import has_level_picks, level_three_positions

    for coefs in ((None, edge) if edge else (None,)):
        base = three_sensor_positions(train.raw, signal, c, coefs)
        yield base, False, coefs is not None
        if has_level_picks(train.raw):
            yield level_three_positions(train.raw, signal, c, base, coefs), True, coefs is not None


def stack_candidates(raw: dict, signal, channel: int, base: np.ndarray, corrections: dict) -> np.ndarray:
    """[R, K, 2] the positions a channel's stack weighs (`stack_weights`): each pick set's plain three-sensor
    position without `channel`, the same from its corrected picks (pick_correction.py), and `base` (the
    position the three-sensor path keeps without a stack); a row where one is missing is base in every slot."""
    from .edge_travel import _localise
    from .pick_correction import PICK_SETS, corrected_three_positions

    plain = [_localise(raw, signal, ps, 0.0, without=channel) for ps in PICK_SETS if ps in corrections]
    C = np.stack(plain + corrected_three_positions(raw, signal, channel, corrections) + [np.asarray(base, float)], 1)
    missing = ~np.isfinite(C).all((1, 2))
    C[missing] = np.asarray(base, float)[missing][:, None]
    return C


def stacked(C: np.ndarray, weights) -> np.ndarray:
    return np.einsum("rkd,k->rd", C, np.asarray(weights, float))


def stack_weights(C: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The weights (summing to 1) of C's positions [R, K, 2] whose weighted sum is closest to xy (least mean
    absolute error, Powell from equal weights)."""
    from scipy.optimize import minimize

    k = C.shape[1]
    rows = np.isfinite(C).all((1, 2)) & np.isfinite(xy).all(1)

    def full(w):
        return np.r_[w, 1.0 - w.sum()]

    res = minimize(lambda w: np.abs(stacked(C[rows], full(w)) - xy[rows]).mean(), np.full(k - 1, 1.0 / k),
                   method="Powell")
    return full(res.x)


def _stack_candidate(train: Features, xy: np.ndarray, signal, c: int, base: np.ndarray, oof_corrections: dict,
                     seed: int) -> tuple[dict | None, np.ndarray | None]:
    """Channel c's stack on the training drops: (its pair's candidate (`_candidate`) on the drops' out-of-fold
    stacked positions (weights fitted on the other sites' drops, the picks' corrections out of fold too), the
    weights on all drops)."""
    from sklearn.model_selection import GroupKFold

    from .correction_scale import CORRECTION_FOLDS, drop_sites

    C = stack_candidates(train.raw, signal, c, base, oof_corrections)
    sites = drop_sites(xy)
    oof = np.array(base, float, copy=True)
    for fit_rows, held in GroupKFold(CORRECTION_FOLDS).split(C, groups=sites):
        oof[held] = stacked(C[held], stack_weights(C[fit_rows], xy[fit_rows]))
    oof[~np.isfinite(base).all(1)] = np.nan
    return _candidate(train, xy, oof, c, seed), stack_weights(C, xy)


def fit_three_channel_positions(train: Features, xy_mm: np.ndarray, signal, seed: int = 0,
                                edge: dict | None = None) -> tuple[dict, dict, list, list, dict]:
    """(channel -> (forest dx, forest dy) correcting the three-sensor position without that channel, fitted on
    the training drops (`train`: usable rows, every channel with an onset) and scaled by `correction_factor`;
    channel -> that factor; the channels whose position is the mean over the onset levels
    (three_level_positions.py); the channels whose position takes edge_travel's correction of the arrival
    times (edge: the model's coefficients; three_sensor_positions); the stack: {"forests": pick_correction's
    forests, "weights": channel -> stack_weights} for the channels whose position is the stack of the plain and
    pick-corrected positions (empty without the level picks)). The candidates (`_candidates`, then the stack
    on the one kept) are tried in turn; one replaces the position kept so far when its out-of-fold positions
    are better (`_better`). A channel the localiser places fewer than MIN_DROPS of them without is left out."""
    from .correction_scale import drop_sites, scale_forests
    from .pick_correction import fit_pick_corrections
    from .three_level_positions import has_level_picks

    xy = np.asarray(xy_mm, float)
    out, factors, levels, edges, weights = {}, {}, [], [], {}
    picks, oof_corrections = {}, {}
    if has_level_picks(train.raw) and len(np.unique(drop_sites(xy))) >= 2 * MIN_DROPS:
        picks, oof_corrections = fit_pick_corrections(train.raw, xy, signal, train.phys_xy_mm, drop_sites(xy), seed)
    for c in range(4):
        best, kind, best_pos = None, (False, False), None
        for position, on_levels, with_edge in _candidates(train, signal, c, edge):
            cand = _candidate(train, xy, position, c, seed)
            if best is None and not (on_levels or with_edge):
                best, best_pos = cand, position
                if best is None:
                    break
            elif cand is not None and _better(best, cand, xy):
                best, kind, best_pos = cand, (on_levels, with_edge), position
        if best is None:
            continue
        if oof_corrections:
            cand, w = _stack_candidate(train, xy, signal, c, best_pos, oof_corrections, seed)
            if cand is not None and _better(best, cand, xy):
                best, weights[c] = cand, w
        levels += [c] if kind[0] else []
        edges += [c] if kind[1] else []
        out[c], factors[c] = best["pair"], best["factor"]
        scale_forests(out[c], factors[c])
    stack = {"forests": picks, "weights": weights} if weights else {}
    return out, factors, levels, edges, stack


def stacked_positions(model, features: Features, rows: np.ndarray, out_channel: np.ndarray, xy: np.ndarray) -> None:
    """xy (in place) of `rows` whose channel out (out_channel) the model places by its stack (card
    "three_channel_position_stack"): the weighted sum of the plain and pick-corrected three-sensor positions and
    xy's own (the position kept before the stack). Features without the level picks keep xy."""
    from .pick_correction import pick_corrections
    from .three_level_positions import has_level_picks

    stack = model.three_channel_stack
    if not stack or not has_level_picks(features.raw):
        return
    rows, out_channel = np.asarray(rows), np.asarray(out_channel)
    for c, w in stack["weights"].items():
        sel = rows[out_channel == c]
        if sel.size:
            raw = {k: v[sel] for k, v in features.raw.items()}
            corr = pick_corrections(stack["forests"], raw, model.signal, xy[sel])
            new = stacked(stack_candidates(raw, model.signal, int(c), xy[sel], corr), w)
            ok = np.isfinite(new).all(1)
            xy[sel[ok]] = new[ok]


def corrected_positions(pairs: dict, vector: np.ndarray, rows: np.ndarray, out_channel: np.ndarray,
                        xy: np.ndarray) -> None:
    """xy (in place) of `rows` (indices; xy holds their three-sensor position) corrected by the pair of the
    channel that is out (out_channel[k] for rows[k]; vector: the core's feature vectors of all rows); rows whose
    channel has no pair, or whose inputs are not finite, keep it."""
    rows, out_channel = np.asarray(rows), np.asarray(out_channel)
    for c, pair in pairs.items():
        sel = rows[out_channel == c]
        if not sel.size:
            continue
        X = three_channel_position_inputs(vector[sel], xy[sel], c)
        ok = np.isfinite(X).all(1)
        if ok.any():
            xy[sel[ok]] = xy[sel[ok]] + np.stack([f.predict(X[ok]) for f in pair], 1)


def level_mean_positions(model, features: Features, rows: np.ndarray, out_channel: np.ndarray, xy: np.ndarray) -> None:
    """xy (in place) of `rows` whose channel out (out_channel) the model places by the mean over the onset levels
    (card "three_channel_position_levels"; three_level_positions.py): that mean of their three-sensor position
    in xy and the levels'. Features without the level picks (featurize alone; ImpactModel.featurize adds them)
    keep xy."""
    from .three_level_positions import has_level_picks, level_three_positions

    chosen = model.card.get("three_channel_position_levels") or []
    if not chosen or not has_level_picks(features.raw):
        return
    rows, out_channel = np.asarray(rows), np.asarray(out_channel)
    with_edge = model.card.get("three_channel_position_edge") or []
    for c in chosen:
        sel = rows[out_channel == c]
        if sel.size:
            raw = {k: v[sel] for k, v in features.raw.items()}
            xy[sel] = level_three_positions(raw, model.signal, int(c), xy[sel],
                                            model.edge_travel if c in with_edge else None)


def edge_corrected_positions(model, features: Features, rows: np.ndarray, out_channel: np.ndarray,
                             xy: np.ndarray) -> None:
    """xy (in place) of `rows` whose channel out (out_channel) the model places with edge_travel's correction
    (card "three_channel_position_edge"): the three-sensor position without that channel, corrected; rows the
    corrected localiser does not place keep xy."""
    chosen = model.card.get("three_channel_position_edge") or []
    if not chosen or not model.edge_travel:
        return
    rows, out_channel = np.asarray(rows), np.asarray(out_channel)
    for c in chosen:
        sel = rows[out_channel == c]
        if sel.size:
            raw = {k: v[sel] for k, v in features.raw.items()}
            new = three_sensor_positions(raw, model.signal, int(c), model.edge_travel)
            ok = np.isfinite(new).all(1)
            xy[sel[ok]] = new[ok]


def three_sensor_path(model, features: Features, use: np.ndarray, out: dict) -> None:
    """ImpactModel.predict without a site map, on the rows without the forests' position (out["three_channel"]:
    one channel without an onset, xy the core's three-sensor position): adds those the model's channel check
    flags (a channel that disagrees with the other three, e.g. a debonded disc: its three-sensor position
    without that channel, channel_check.py), corrects their positions by the pair of the channel out
    (`corrected_positions`; none on the board) and gives them the class from the other three channels' energies
    (height_class's three-channel classes; a model without them, trained before: no class). A flagged drop on a
    channel whose three-sensor position the card's check does not keep (flagged_position.py) keeps the four
    channels' position, flagged, with the three-channel class. In place in out."""
    from .channel_check import flag_events
    from .flagged_position import keeps_four_channels
    from .height_class import three_channel_inputs

    xy, three = out["xy_mm"], out["three_channel"]
    three_xy = features.phys_xy_mm
    left_out = np.argmax(features.no_onset, axis=1)
    classed = three
    if model.card.get("channel_check") and use.any():
        flagged, three_xy, left_out = flag_events(features.raw, features.phys_xy_mm, use, left_out, model.signal,
                                                  model.card["channel_check"])
        out["forest_xy_mm"] = xy.copy()   # the forests' own position stays there
        out["bad_channel"] = np.where(flagged, left_out, -1)
        classed = three | flagged
        flagged &= ~keeps_four_channels(model.card["channel_check"], out["bad_channel"])   # flagged_position.py
        xy[flagged] = three_xy[flagged]
        out["spread_mm"][flagged] = np.nan
        three = three | flagged
    out["three_channel"] = three
    if model.three_channel_position:
        edge_corrected_positions(model, features, np.flatnonzero(three), left_out[three], xy)
        level_mean_positions(model, features, np.flatnonzero(three), left_out[three], xy)
        stacked_positions(model, features, np.flatnonzero(three), left_out[three], xy)
        corrected_positions(model.three_channel_position, features.vector, np.flatnonzero(three), left_out[three], xy)
    for c, estimate in model.three_channel_class.items():
        rows = np.flatnonzero(classed & (left_out == c))
        if rows.size:
            out["energy_class"][rows] = estimate.predict(three_channel_inputs(
                {k: v[rows] for k, v in features.raw.items()}, three_xy[rows], c))


def left_out_class(model, features: Features, use: np.ndarray, energy_class: np.ndarray) -> None:
    """A model trained with a channel left out (signal.channel_left_out) places its drops by forests that read
    none of that channel's arrival times (`use`: the rows they placed); their class (in place in energy_class) is
    the three-channel one from the other three channels' energies, as a dead channel's: the left-out channel's own
    energy is not trusted (a loose or dead disc). The board does the same (impactapp TableModels)."""
    from .height_class import three_channel_inputs

    no_onset = features.no_onset.sum(1) == 1
    for c, estimate in model.three_channel_class.items():
        rows = np.flatnonzero(use & no_onset & features.no_onset[:, int(c)] & np.isfinite(features.phys_xy_mm).all(1))
        if rows.size and model.signal.channel_left_out[int(c)]:
            energy_class[rows] = estimate.predict(three_channel_inputs(
                {k: v[rows] for k, v in features.raw.items()}, features.phys_xy_mm[rows], int(c)))


def save_three_channel_positions(stage, pairs: dict, stack: dict | None = None) -> tuple[dict, dict]:
    """Writes the pairs (and the stack's pick forests) into a model's staging folder; returns the card's
    "three_channel_position" entry ({"c": {"x": file, "y": file}}) and its "three_channel_position_stack"
    ({"forests": {pick set: file}, "weights": {"c": [numbers]}}; empty without a stack)."""
    stack_entry = {}
    if stack:
        stack_entry = {"forests": {}, "weights": {str(c): [float(v) for v in w] for c, w in sorted(stack["weights"].items())}}
        for ps, forest in stack["forests"].items():
            save_forest(stage / PICK_FILE.format(ps), forest)
            stack_entry["forests"][ps] = PICK_FILE.format(ps)
    entry = {}
    for c, pair in sorted(pairs.items()):
        entry[str(c)] = {}
        for axis, forest in zip("xy", pair):
            name = THREE_POSITION_FILE.format(axis, c)
            save_forest(stage / name, forest)
            entry[str(c)][axis] = name
    return entry, stack_entry


def _load_stack(model_dir, card: dict, card_path, pairs: dict) -> dict:
    """The card's "three_channel_position_stack" ({"forests": {pick set: forest}, "weights": channel ->
    weights}; empty when absent), each forest file checked against the card's sha256."""
    from .modelfolder import read_verified
    from .pick_correction import N_INPUTS as PICK_INPUTS, PICK_SETS

    entry = card.get("three_channel_position_stack", {})
    if not entry:
        return {}
    forests, weights = entry.get("forests") if isinstance(entry, dict) else None, \
        entry.get("weights") if isinstance(entry, dict) else None
    if not isinstance(forests, dict) or not forests or any(k not in PICK_SETS or not isinstance(v, str)
                                                           for k, v in forests.items()):
        raise DataError(card_path, "three_channel_position_stack.forests", f"must map pick sets {list(PICK_SETS)} "
                                                                           "to file names")
    k = 2 * len(forests) + 1
    if not isinstance(weights, dict) or any(c not in pairs for c in map(_channel, weights)) or any(
            not isinstance(w, list) or len(w) != k or not all(isinstance(v, (int, float)) for v in w)
            for w in weights.values()):
        raise DataError(card_path, "three_channel_position_stack.weights", f"must map channels that have a "
                                                                           f"position pair to {k} numbers")
    out = {"forests": {}, "weights": {int(c): np.asarray(w, float) for c, w in weights.items()}}
    for ps, name in forests.items():
        path, data = read_verified(model_dir, card, card_path, name, f"three_channel_position_stack.{ps}")
        forest = load_forest(path, data)
        if getattr(forest, "n_features_in_", None) != PICK_INPUTS:
            raise DataError(path, None, f"reads {getattr(forest, 'n_features_in_', '?')} inputs, not {PICK_INPUTS}")
        out["forests"][ps] = forest
    return out


def _channel(key) -> int:
    return int(key) if str(key) in ("0", "1", "2", "3") else -1


def load_three_sensor_path(model_dir, card: dict, card_path) -> tuple[dict, dict, dict]:
    """The card's "three_channel_class" (channel -> height_class.LinearHeightClass), "three_channel_position"
    (channel -> forest pair) and "three_channel_position_stack" (`_load_stack`), each file checked against the
    card's sha256 (modelfolder.read_verified)."""
    from .height_class import LINEAR_CLASS_FEATURES, LinearHeightClass
    from .modelfolder import read_verified

    classes = card.get("three_channel_class", {})
    if not isinstance(classes, dict) or any(k not in ("0", "1", "2", "3") or not isinstance(v, str)
                                            for k, v in classes.items()):
        raise DataError(card_path, "three_channel_class", "must map channels 0-3 to file names")
    entry = card.get("three_channel_position", {})
    if not isinstance(entry, dict) or any(k not in ("0", "1", "2", "3") or not isinstance(v, dict)
                                          or set(v) != {"x", "y"} for k, v in entry.items()):
        raise DataError(card_path, "three_channel_position", "must map channels 0-3 to {\"x\": file, \"y\": file}")
    levels = card.get("three_channel_position_levels", [])
    if not isinstance(levels, list) or any(str(c) not in entry for c in levels):
        raise DataError(card_path, "three_channel_position_levels", "must list channels that have a position pair")
    edge = card.get("three_channel_position_edge", [])
    if not isinstance(edge, list) or any(str(c) not in entry for c in edge) or (edge and not card.get("edge_travel")):
        raise DataError(card_path, "three_channel_position_edge", "must list channels that have a position pair "
                                                                  "(and the model an edge_travel correction)")
    three_class, pairs = {}, {}
    for c, name in classes.items():
        path, data = read_verified(model_dir, card, card_path, name, f"three_channel_class.{c}")
        three_class[int(c)] = LinearHeightClass.load(path, data)
        if three_class[int(c)].n_features_in_ != len(LINEAR_CLASS_FEATURES):
            raise DataError(path, None, f"reads {three_class[int(c)].n_features_in_} inputs, not "
                                        f"{len(LINEAR_CLASS_FEATURES)}")
    for c, files in entry.items():
        pair = []
        for axis in "xy":
            path, data = read_verified(model_dir, card, card_path, files[axis], f"three_channel_position.{c}.{axis}")
            forest = load_forest(path, data)
            if getattr(forest, "n_features_in_", None) != N_INPUTS:
                raise DataError(path, None, f"reads {getattr(forest, 'n_features_in_', '?')} inputs, not {N_INPUTS}")
            pair.append(forest)
        pairs[int(c)] = tuple(pair)
    return three_class, pairs, _load_stack(model_dir, card, card_path, pairs)


def load_board_pairs(model_dir, card: dict, card_path) -> dict:
    """The card's three-sensor position pairs the board keeps (channel -> pair): those of "three_channel_position"
    whose channel the card's "board_three_position" record kept (a board model's boosted pairs,
    board.models.board_three_positions; a host model's forests are not the board's: none)."""
    record = card.get("board_three_position")
    if not isinstance(record, dict) or not isinstance(record.get("channels"), dict):
        return {}
    kept = [int(c) for c, rec in record["channels"].items() if isinstance(rec, dict) and rec.get("kept")]
    pairs = load_three_sensor_path(model_dir, card, card_path)[1]
    if any(c not in pairs for c in kept):
        raise DataError(card_path, "board_three_position.channels", "keeps a channel three_channel_position has no "
                                                                    "pair for")
    return {c: pairs[c] for c in kept}
