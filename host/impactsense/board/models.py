"""Models trained on the firmware's own inputs: the captures the firmware app takes from the board-rate
stream (4 x 50 kHz, SAADC scan delays included), through `impactsense train`'s own model code.

The trainer (impactsense.workflow.train) fits on the lab's 100 kHz recordings; the board samples 4 x 50 kHz,
where the onset picks scatter more and energies and sample counts differ, so a 100 kHz model loses most of
its accuracy on the board. Until sessions are recorded on the board (`impactsense record`), this trains the
same model type, with the same split and settings, on what the emulated board captures: the recordings
resampled onto the scan grid, channel c read c x 5 us after channel 0 (board.capture.board_samples),
triggered and cut by the firmware app itself. `impactsense export` ships such models by default.

A model with the twin's site map (`impactsense train --site-map`: position and energy class from the twin's
match) needs the map as the board sees it too: the twin's simulated drops taken the same way (board_site_map; ~3,500 drops for a 5 mm
grid, a few minutes on 2 cores, cached in the export folder).
"""

from __future__ import annotations

import hashlib
from dataclasses import replace
from functools import partial
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from sklearn.model_selection import GroupKFold

from ..correction_scale import scale_forests
from ..data import Session, load_session
from ..edge_travel import three_sensor_positions
from ..errors import DataError
from ..modelfolder import read_card, verified_path
from ..models import LOCATION_FEATURES, SITE_MAP_FILE, ForestSettings, ImpactModel, columns
from ..pipeline import featurize, fit_localiser
from ..signal import BOND_INVERSE_FIELDS, with_channel_delays
from ..sim.params import SimParams
from ..sitemap import SiteMap, build_site_map, twin_features
from ..split import case_split
from ..three_channel_position import MIN_DROPS, three_channel_position_inputs
from ..twin import TwinFit, estimate, fit_twin, position_groups
from ..zeroshot import calibration_twins, fit_on_calibration_drops
from .boosted import BOOST_DEPTH, BOOST_GAIN, boosted_regressor, choose_board_forests, prefix_within, stages_within
from .capture import (TRIGGER_KEY, board_anti_alias, board_capture, board_captures, board_signal, board_view,
                      front_end_card, signal_for_board, trigger_record)
from .trigger import captures_at_chosen_trigger
from .cost import (CLASS_FOREST_FIXED, EVENT_BUDGET, FOREST_FIXED, FOREST_PER_INPUT, FOREST_PER_NODE, FOREST_PER_TREE,
                   LOCALISER_EVALUATIONS, linear_instructions, signal_fits, signal_instructions)

BOARD_SITE_MAP = "board-site-map.npz"   # the cached board-rate site map in an export folder


def board_site_map(source, rig, fs_hz: int = 50000, cache=None, workers: int = 2, progress: bool = True,
                   step_mm: float | None = None):
    """The twin's site map as the board sees it (sitemap.SiteMap): the grid and reference height of `source`
    (a site map made at the rig's rate), drops simulated with the twin it was made with
    (source.source["sim_params"]), taken by the board (board_capture) and featurized with the board's signal
    (the source map's settings at fs_hz, scan delays, the rig's declared front-end low-pass). Read from /
    written to `cache` (reused when made from the same source map, rate and front end). step_mm: another grid
    step than the source's (coarse maps for tests)."""
    step = float(step_mm or source.step_mm)
    aa = board_anti_alias(rig, fs_hz)   # the board's front end (None: none; a cache made before it: none)
    key = {"from_site_map_sha": source.fingerprint(), "board_fs_hz": int(fs_hz), "step_mm": step,
           "board_anti_alias": None if aa is None else list(aa)}
    if cache is not None and Path(cache).is_file():
        try:
            cached = SiteMap.load(cache)
        except DataError:
            cached = None
        if cached is not None and all(cached.source.get(k) == v for k, v in key.items()):
            return cached
    raw = source.source.get("sim_params")
    if not raw:
        raise DataError("site map", "source.sim_params", "missing: the board's map needs the twin the map was made with")
    params = SimParams.from_dict(raw, "site map source.sim_params")
    src_signal = source.source.get("signal") or None
    board = build_site_map(params, rig, signal_for_board(rig, src_signal, fs_hz), step_mm=step,
                           margin_mm=source.x0_mm, ref_height_mm=source.ref_height_mm, workers=workers,
                           progress=progress, capture=board_capture(rig, fs_hz, src_signal))
    if step == source.step_mm and (board.nx, board.ny, board.y0_mm) != (source.nx, source.ny, source.y0_mm):
        raise DataError("site map", "grid", "the source map's grid is not one build_site_map makes (x0 != y0?)")
    board.source.update(key, calibration=source.source.get("calibration"))
    if cache is not None:
        board.save(cache)
    return board


# The board's onset threshold: the carried-over one (the rig's model's, chosen on its own rate's picks) or a lower
# one, kept when the training drops' physics MAE on the board's captures falls below BOARD_THRESHOLD_GAIN x the
# carried one's. At 4 x 50 kHz the threshold crossing is one coarse sample: a lower threshold catches the arrival's
# first cycle a sample earlier on a slow plate (docs/findings.md "Session 18: boardband").
BOARD_THRESHOLD_FACTORS = (1.0, 0.6, 0.4)
BOARD_THRESHOLD_GAIN = 0.97


def choose_board_threshold(board, rows: np.ndarray, sig, fits=signal_fits):
    """(the fitted signal, record): fit_localiser on the board's captures `board` (adc, xy_mm, rig) of the
    training rows at each of BOARD_THRESHOLD_FACTORS x sig's onset threshold (the AIC blend kept), the carried
    threshold (the first) unless another's training-drop physics MAE per axis is below BOARD_THRESHOLD_GAIN x
    its own. record: {"factors", "physics_mae_mm" per factor, "chosen"} for the model card."""
    base = float(sig.onset_threshold_counts)
    xy = np.asarray(board.xy_mm, float)[rows]
    fitted, mae = [], []
    for f in BOARD_THRESHOLD_FACTORS:
        trial = replace(sig, onset_threshold_counts=base * f)
        try:
            out = fit_localiser(board, rows, trial, choose_threshold=False, fits=fits)
        except (DataError, ValueError):   # no onset on every channel of enough drops at this threshold
            fitted.append(None)
            mae.append(float("inf"))
            continue
        phys = np.asarray(featurize(board.adc[rows], out).phys_xy_mm, float)
        ok = np.isfinite(phys).all(1)
        fitted.append(out)
        mae.append(float(np.abs(phys[ok] - xy[ok]).mean()) if ok.mean() > 0.9 else float("inf"))
    best = int(np.argmin(mae))
    chosen = best if fitted[best] is not None and mae[best] < BOARD_THRESHOLD_GAIN * mae[0] else 0
    if fitted[chosen] is None:
        raise DataError("training drops", "adc", "the board's captures give no onset at the carried threshold")
    record = {"factors": list(BOARD_THRESHOLD_FACTORS), "physics_mae_mm": [round(m, 3) for m in mae],
              "chosen": BOARD_THRESHOLD_FACTORS[chosen]}
    return fitted[chosen], record


# More localiser starts within one start's bound (board.cost): n starts at LOCALISER_EVALUATIONS // n normal-equation
# evaluations each (impactcore.h localiser_evaluation_cap) cost what one start at the core's cap costs in the
# estimate. Export does not use it: measured for a model without a twin, two starts helped one held-out split and
# hurt two, and the slowest qemu event went over the budget (docs/findings.md "Session 21: boardgap").
def capped_starts(sig, starts: int):
    """sig with `starts` localiser starts at one start's evaluation bound (board.cost.LOCALISER_EVALUATIONS //
    starts evaluations each)."""
    return replace(sig, localiser_starts=int(starts), localiser_evaluation_cap=LOCALISER_EVALUATIONS // int(starts))


def choose_twin_search(model: ImpactModel, features, xy_mm, height_mm, settings: ForestSettings,
                       n_folds: int = 5) -> dict:
    """How the board's twin searches the site map, chosen on the training drops out of fold (forests and twin fit
    on the other folds, the drops grouped by position): one match within cutoff_mm of the forests' position, or
    coarse to fine (twin.h coarse_cutoff_mm: every other grid point within 4 grid steps, then the match within 2
    steps around that estimate; as many points as one match, so the same cost). At the board's rate the forests'
    position is several millimetres off (coarser onset picks), often outside the one match's reach, where the
    wider coarse pass still finds the impact. Sets model.twin_fit's search; returns the out-of-fold MAE per axis
    of each and the choice."""
    use = np.asarray(features.usable, bool)
    X = features.vector[use][:, columns(LOCATION_FEATURES)]
    phys = features.phys_xy_mm[use]
    xy = np.asarray(xy_mm, float)[use]
    h = np.asarray(height_mm, float)[use]
    feats, usable = twin_features(features.take(np.flatnonzero(use)))
    step = float(model.site_map.step_mm)
    searches = {"one": {"coarse_cutoff_mm": 0.0, "cutoff_mm": model.twin_fit.cutoff_mm},
                "coarse_to_fine": {"coarse_cutoff_mm": 4 * step, "cutoff_mm": 2 * step}}
    groups = position_groups(xy)
    k = min(n_folds, int(groups.max()) + 1)
    err = {name: [] for name in searches}
    if k >= 2:
        for tr, va in GroupKFold(k).split(xy, groups=groups):
            start = phys[va] + np.stack([settings.regressor().fit(X[tr], xy[tr, c] - phys[tr, c]).predict(X[va])
                                         for c in (0, 1)], axis=1)
            fit = fit_twin(feats[tr], usable[tr], model.site_map, xy[tr], h[tr])
            for name, search in searches.items():
                e = estimate(model.site_map, TwinFit.from_dict({**fit.to_dict(), **search}), feats[va], usable[va],
                             start)
                p = np.asarray(e["xy_mm"], float)
                p[np.asarray(e["status"]) != 0] = np.nan
                err[name].append(np.abs(p - xy[va]))
    mae = {name: float(np.nanmean(np.concatenate(v))) if v else float("nan") for name, v in err.items()}
    best = "coarse_to_fine" if mae["coarse_to_fine"] < mae["one"] else "one"
    for key, value in searches[best].items():
        setattr(model.twin_fit, key, value)
    return {"out_of_fold_mae_mm": mae, "chosen": best}


def board_position_forests(model: ImpactModel, features, xy_mm, settings: ForestSettings,
                           front_end=None) -> dict:
    """The board's position correction (board.boosted): the boosted pair replaces the model's forests when the
    training drops say so out of fold (choose_board_forests), and no correction (the trees' leaves 0) when the
    physics position beats the one kept; returns the record for the card. front_end: the
    captures' analog front end (forests_budget)."""
    use = np.asarray(features.usable, bool)
    X = features.vector[use][:, columns(model.location_features)]
    xy = np.asarray(xy_mm, float)[use]
    resid = xy - np.asarray(features.phys_xy_mm, float)[use]
    left = forests_budget(model, X.shape[1], front_end)
    record = choose_board_forests(X, resid, position_groups(xy), settings,
                                  prefix_within((model.forest_dx, model.forest_dy), X, left), stages_within(left))
    record["instructions_left"] = int(left)
    if record["use_boosted"]:
        model.forest_dx, model.forest_dy = (boosted_regressor(X, resid[:, c], record["stages"], settings.seed)
                                            for c in (0, 1))
    if record["no_correction"]:   # the exported trees' leaves 0: the board reports its physics position
        scale_forests((model.forest_dx, model.forest_dy), 0.0)
    return record


# The three-sensor position's pairs (board_three_positions): at most BOARD_THREE_STAGES boosted stages per
# coordinate (flash: ~100 B a depth-3 tree, 8 pairs), kept per channel when their out-of-fold MAE per axis on the
# training drops with that channel left out is below BOOST_GAIN x the plain three-sensor position's.
BOARD_THREE_STAGES = 12


def board_three_positions(model: ImpactModel, features, xy_mm, settings: ForestSettings, n_folds: int = 5,
                          front_end=None) -> dict:
    """Per channel c the pair correcting the three-sensor position of a drop without c, as the board runs it: the
    training drops' own three-sensor position without c (edge_travel.three_sensor_positions, the core's numbers
    for a drop whose channel c has no onset), boosted depth-BOOST_DEPTH trees (board.boosted) learning the truth
    minus it from three_channel_position_inputs (none read c). Kept (model.three_channel_position) where the
    out-of-fold positions (folds grouped by drop position) beat the plain three-sensor ones by BOOST_GAIN; returns
    the card's record {"stages", "depth", "channels": {c: {"out_of_fold_mae_mm": {"three_sensor", "corrected"},
    "drops", "kept"}}}."""
    use = np.flatnonzero(np.asarray(features.usable, bool))
    train = features.take(use)
    xy = np.asarray(xy_mm, float)[use]
    stages = min(BOARD_THREE_STAGES, stages_within(forests_budget(model, len(model.location_features), front_end)))
    pairs, record = {}, {}
    for c in range(4):
        base = three_sensor_positions(train.raw, model.signal, c, None)
        X = three_channel_position_inputs(train.vector, base, c)
        ok = np.isfinite(X).all(1) & np.isfinite(xy).all(1)
        rec = {"drops": int(ok.sum()), "kept": False}
        record[str(c)] = rec
        if ok.sum() < MIN_DROPS:
            continue
        Xc, resid = X[ok], xy[ok] - base[ok]
        groups = position_groups(xy[ok])
        k = min(n_folds, int(groups.max()) + 1)
        if k < 2:
            continue
        oof = np.zeros_like(resid)
        for tr, va in GroupKFold(k).split(Xc, groups=groups):
            for a in (0, 1):
                oof[va, a] = boosted_regressor(Xc[tr], resid[tr, a], stages, settings.seed).predict(Xc[va])
        plain, corrected = float(np.abs(resid).mean()), float(np.abs(resid - oof).mean())
        rec["out_of_fold_mae_mm"] = {"three_sensor": round(plain, 3), "corrected": round(corrected, 3)}
        if corrected < BOOST_GAIN * plain:
            rec["kept"] = True
            pairs[c] = tuple(boosted_regressor(Xc, resid[:, a], stages, settings.seed) for a in (0, 1))
    model.three_channel_position = pairs
    return {"stages": stages, "depth": BOOST_DEPTH, "channels": record}


def board_corrections(model: ImpactModel, features, xy_mm, settings: ForestSettings, left_out: bool,
                      front_end=None) -> dict:
    """A model without a twin: the position correction the event budget affords (boosted trees or a prefix,
    board_position_forests) and, on a four-channel model with the three-channel classes, per channel the
    three-sensor position's correction the board runs with that channel out (board_three_positions); the card's
    records."""
    out = {"board_forests": board_position_forests(model, features, xy_mm, settings, front_end)}
    if not left_out and model.three_channel_class:
        out["board_three_position"] = board_three_positions(model, features, xy_mm, settings, front_end=front_end)
    return out


def follow_flagged_choice(model: ImpactModel, three_sensor_position) -> None:
    """A board model with the channel check and without a twin takes the rig's model's per-channel choice of a
    flagged drop's position (its card's channel_check["three_sensor_position"], flagged_position.py; None: the
    board model's own default, the three-sensor path): one source, so board and host place a flagged drop alike."""
    check = model.card.get("channel_check")
    if check and model.site_map is None and three_sensor_position is not None:
        check["three_sensor_position"] = [bool(v) for v in three_sensor_position]


def forests_budget(model: ImpactModel, n_inputs: int, front_end=None) -> float:
    """What the event budget leaves the position pair's trees (board.cost): the budget less the signal's cost, the
    forests' fixed share and inputs, and the energy model's (its linear terms, or one tree of its forest); the
    signal's cost on captures through front_end (board.cost.base_instructions)."""
    energy = model.forest_energy
    if hasattr(energy, "estimators_"):
        tree = energy.estimators_[0].tree_
        e_cost = (FOREST_PER_TREE + FOREST_PER_NODE * (tree.max_depth + 1) + CLASS_FOREST_FIXED
                  + FOREST_PER_INPUT * len(model.energy_class_features))
    else:
        e_cost = linear_instructions(len(energy.terms))
    return (EVENT_BUDGET - signal_instructions(model.signal, front_end=front_end)["total"] - FOREST_FIXED - FOREST_PER_INPUT * 2 * n_inputs
            - e_cost)


def train_board_models(session, out_dir, n_trees: int = 30, seed: int = 0, fs_hz: int = 50000,
                       test_fraction: float = 0.2, max_depth: int | None = None, settings=None,
                       exclude_rows=None, train_rows=None, extra_card: dict | None = None,
                       site_map=None, onset_threshold_counts: float | None = None, channel_gain=None,
                       weak_channel: int = -1, choose_class: bool = False, channel_left_out=None,
                       simulated_rows=None, three_sensor_position=None, picks_delay_us=None, bond_inverse=None) -> Path:
    """Writes a MODEL_DIR (impactsense.models.ImpactModel) trained on the board's captures of the training drops of
    `session`: the physics localiser (group velocity, the rig's channel delays) fitted on the board-rate picks, then
    the forests on the board-rate features. The split is the trainer's (split.case_split with test_fraction, seed,
    exclude_rows) unless train_rows (row indices) is given; the card lists the held-out recording ids
    (`test_recording_ids`, and `split` as `impactsense train` writes it). settings (models.ForestSettings) overrides
    n_trees/seed/max_depth. site_map: a board-rate site map (board_site_map): the energy class then reads the twin's
    estimate. The card's rig_delay_us are the rig's own (plus picks_delay_us, a retrained model's diagnosed delays:
    card retrain.picks_delay_us); its capture_delay_us the scan's (the firmware sets its own). The band picks and
    localiser starts are chosen among those within the board's event budget (board.cost.signal_fits).
    onset_threshold_counts: the picks' onset threshold (default: the board's configured one); retrain_for_board passes
    the one the rig's own model chose; choose_board_threshold keeps it or lowers it (the card's "board_threshold").
    three_sensor_position: follow_flagged_choice's. channel_gain, bond_inverse (signal.BOND_INVERSE_FIELDS: values)
    and weak_channel: a retrained model's (a debonded disc, `impactsense retrain`), kept. choose_class: without a
    site map, the energy class by the out-of-fold rule on the board's features (ImpactModel.fit). channel_left_out:
    a retrained model's (a change the models cannot absorb): trained on all four channels as `impactsense retrain`
    trains, then set on the model's signal, so the board's core leaves the channel out as the host's does (the
    physics three-sensor position, the three-channel class or the twin's match without it). simulated_rows: row
    indices of the twin's own drops (a retrained model's, `loop.measured_training_session`): the forests learn from
    them, the site map's twin fit does not (ImpactModel.fit twin_rows)."""
    if train_rows is None:
        train_rows, _ = case_split(session.case_id, test_fraction, seed, exclude_rows)
    train_rows = np.asarray(train_rows, int)
    excluded = np.isin(np.arange(len(session)), np.asarray([] if exclude_rows is None else exclude_rows, int))
    # at the board's trigger threshold (board.trigger): the default unless a lower one takes more drops on time
    caps, rows, sig, chosen, trigger_choice = captures_at_chosen_trigger(session, train_rows[~excluded[train_rows]], fs_hz,
                                                                         board_captures)
    if onset_threshold_counts is not None:
        sig.onset_threshold_counts = float(onset_threshold_counts)
    is_train = np.isin(rows, train_rows)
    is_test = ~is_train & ~excluded[rows]
    kept = {**({"channel_gain": channel_gain} if channel_gain is not None else {}), **(bond_inverse or {})}
    sig = replace(sig, **{name: [float(v) for v in values] for name, values in kept.items()})
    left_out = [int(bool(v)) for v in channel_left_out or []]
    if any(left_out):   # trained as the host's left-out model is (the forests read none of its arrival times)
        sig = replace(sig, channel_left_out=left_out)
    board = SimpleNamespace(adc=caps, xy_mm=session.xy_mm[rows], rig=session.rig)
    # the rig's delays (the scan's are the capture's); the onset threshold as given (the threshold is in ADC
    # counts, above the channels' noise and offsets, which the board's resampling keeps: the rig's model's
    # choice carries over, the AIC blend stays the board's) or, where the board's coarser picks place the training
    # drops clearly better with it, a lower one (choose_board_threshold); the band picks and localiser starts only
    # where the event budget affords them (board.cost)
    front_end = board_anti_alias(session.rig, fs_hz)   # the captures' front end: the features' cost (board.cost)
    sig, threshold_record = choose_board_threshold(board, np.flatnonzero(is_train), sig, partial(signal_fits, front_end=front_end))
    extra_card = {**(extra_card or {}), "board_threshold": threshold_record}
    feats = featurize(caps, sig)
    settings = settings or ForestSettings(n_estimators=n_trees, seed=seed, max_depth=max_depth)
    model = ImpactModel.fit(feats.take(np.flatnonzero(is_train)), session.xy_mm[rows][is_train],
                            session.height_mm[rows][is_train], session.rig.ball_mass_g, sig, settings,
                            site_map=site_map, members=False, choose_class=choose_class,
                            twin_rows=None if simulated_rows is None else
                            ~np.isin(rows, np.asarray(simulated_rows, int))[is_train])
    follow_flagged_choice(model, three_sensor_position)
    if model.site_map is None:
        extra_card = {**extra_card, **board_corrections(model, feats.take(np.flatnonzero(is_train)),
                                                         session.xy_mm[rows][is_train], settings, any(left_out), front_end)}
    model.signal = with_channel_delays(replace(model.signal, channel_left_out=left_out) if any(left_out)
                                       else model.signal, picks_delay_us or [0.0] * 4)
    if model.twin_fit is not None:
        model.twin_fit.weak_channel = int(weak_channel)
        extra_card = {**(extra_card or {}), "twin_search": choose_twin_search(
            model, feats.take(np.flatnonzero(is_train)), session.xy_mm[rows][is_train],
            session.height_mm[rows][is_train], settings)}
    ids = session.recording_id
    split = {
        "data_path": str(session.path), "data_hash": session.fingerprint(), "test_fraction": test_fraction, "seed": seed,
        "train_recordings": ids[rows[is_train]].tolist(),
        "test_recordings": ids[rows[is_test]].tolist(),
        "excluded_recordings": ids[excluded].tolist(),
        "not_captured_recordings": ids[np.setdiff1d(np.arange(len(session)), rows)].tolist(),
    }
    card = {"board_fs_hz": int(fs_hz), "data": str(session.path), "split": split, **front_end_card(session.rig, fs_hz),
            "test_recording_ids": split["test_recordings"], "board_trigger": {**trigger_record(session, caps, feats, sig, excluded, chosen), "choice": trigger_choice},
            **(extra_card or {})}
    return Path(model.save(out_dir, extra_card=card))


def reports_twin_position(card: dict) -> bool:
    """Whether the board's model matches the twin: only where the host model reports the twin's position. A
    class-only twin (twin_role.py: the position is the model's own) is exported as the model without it, so the
    board reports the position the host does; its class is then the board's own classifier's."""
    return "twin" in card and card.get("position_source") != "forest"


def retrain_for_board(model_dir, out_dir, fs_hz: int = 50000, site_map_cache=None) -> Path:
    """The model of MODEL_DIR (a 100 kHz `impactsense train` model) trained again on the board's captures of
    the same training drops, with the same forest settings; the held-out drops stay held out. A model with
    the twin's site map gets the board's site map (board_site_map, cached in site_map_cache; a class-only twin's
does not: reports_twin_position). A model whose
    energy class was chosen by the out-of-fold rule (card "energy_class_choice") has it chosen again on the
    board's features. A channel the model leaves out (card signal.channel_left_out) stays left out."""
    card, card_path = read_card(model_dir)
    if "zero_shot" in card:   # sim-trained: the virtual drops, then the calibration drops' fits, at the board rate
        return sim_trained_for_board(model_dir, out_dir, fs_hz, site_map_cache=site_map_cache)
    split = card.get("split")
    if not split or "train_recordings" not in split:
        raise DataError(card_path, "split", "missing key (needed to retrain on the same drops at the board rate)")
    data = split.get("data_path")
    if not data or not Path(data).is_dir():
        raise DataError(card_path, "split.data_path", f"session folder {data!r} not found")
    session = load_session(data)
    if split.get("data_hash") and split["data_hash"] != session.fingerprint():
        raise DataError(card_path, "split.data_hash", f"{data} changed since the model was trained")
    index = {int(r): k for k, r in enumerate(session.recording_id)}
    rows = lambda key: np.asarray([index[int(r)] for r in split.get(key, [])], int)  # noqa: E731
    forest = {k: v for k, v in (card.get("forest") or {}).items() if k in ForestSettings.__dataclass_fields__}
    board_map = None
    if reports_twin_position(card):
        source = SiteMap.load(verified_path(model_dir, card, card_path, card["twin"].get("site_map", SITE_MAP_FILE),
                                            "twin.site_map"))
        board_map = board_site_map(source, session.rig, fs_hz, cache=site_map_cache)
    threshold = (card.get("signal") or {}).get("onset_threshold_counts")
    return train_board_models(session, out_dir, fs_hz=fs_hz, settings=ForestSettings(**forest), site_map=board_map,
                              onset_threshold_counts=None if threshold is None else float(threshold),
                              exclude_rows=rows("excluded_recordings"), train_rows=rows("train_recordings"),
                              test_fraction=float(split.get("test_fraction", 0.2)), seed=int(split.get("seed", 0)),
                              extra_card={"retrained_from": str(Path(model_dir).resolve())},
                              channel_gain=(card.get("signal") or {}).get("channel_gain"),
                              bond_inverse={k: v for k, v in (card.get("signal") or {}).items()
                                            if k in BOND_INVERSE_FIELDS},
                              weak_channel=int((card.get("twin") or {}).get("weak_channel", -1)),
                              choose_class="energy_class_choice" in card,
                              channel_left_out=(card.get("signal") or {}).get("channel_left_out"),
                              simulated_rows=rows("simulated_recordings") if "simulated_recordings" in split else None,
                              three_sensor_position=(card.get("channel_check") or {}).get("three_sensor_position"),
                              picks_delay_us=(card.get("retrain") or {}).get("picks_delay_us"))


def _card_session(card_path: Path, field: str, record: dict) -> Session:
    path = record.get("data_path")
    if not path or not Path(path).is_dir():
        raise DataError(card_path, f"{field}.data_path", f"session folder {path!r} not found")
    session = load_session(path)
    if record.get("data_hash") and record["data_hash"] != session.fingerprint():
        raise DataError(card_path, f"{field}.data_hash", f"{path} changed since the model was trained")
    return session


def _card_rows(card_path: Path, field: str, session: Session, ids) -> np.ndarray:
    index = {int(r): k for k, r in enumerate(session.recording_id)}
    if ids is None or any(int(r) not in index for r in ids):
        raise DataError(card_path, field, f"missing, or names recordings {session.path} does not have")
    return np.asarray([index[int(r)] for r in ids], int)


def sim_trained_for_board(model_dir: str | Path, out_dir: str | Path, fs_hz: int = 50000, site_map_cache=None,
                          board_map=None, workers: int = 2) -> Path:
    """The sim-trained model of MODEL_DIR (run_zero_shot's model-sim) made again for the board, with all the
    calibration drops taught it: the virtual drops' localiser, forests and twin fit trained on the board's
    captures of the virtual drops (train_board_models, with the twin's board-rate site map,
    board_site_map, cached in site_map_cache; board_map: one made already), then fit_on_calibration_drops
    on the board's captures of the calibration drops and of their simulated twins (board_view), exactly as
    run_zero_shot does at the rig's rate. Written to out_dir; the card keeps the zero-shot record (the
    measured test split, on which `impactsense export` scores the emulated board)."""
    model_dir = Path(model_dir)
    card, card_path = read_card(model_dir)
    zs = card.get("zero_shot")
    if not isinstance(zs, dict):
        raise DataError(card_path, "zero_shot", "missing key (not a sim-trained model of `impactsense demo "
                        "--zero-shot`, or one made before the card recorded its calibration: run it again)")
    cal_path = Path(str(zs.get("calibration")))
    if not cal_path.is_file():
        raise DataError(card_path, "zero_shot.calibration", f"calibration file {str(cal_path)!r} not found")
    if hashlib.sha256(cal_path.read_bytes()).hexdigest() != zs.get("calibration_sha256"):
        raise DataError(card_path, "zero_shot.calibration_sha256", f"{cal_path} changed since the model was trained")
    params = SimParams.from_json(cal_path)
    session = _card_session(card_path, "zero_shot", zs)
    split = card.get("split") or {}
    virtual = _card_session(card_path, "split", split)
    cal_rows = _card_rows(card_path, "zero_shot.calibration_recordings", session, zs.get("calibration_recordings"))
    train_rows = _card_rows(card_path, "split.train_recordings", virtual, split.get("train_recordings"))
    if "twin" not in card:
        board_map = None
    elif board_map is None:
        source = SiteMap.load(verified_path(model_dir, card, card_path, card["twin"].get("site_map", SITE_MAP_FILE),
                                            "twin.site_map"))
        board_map = board_site_map(source, session.rig, fs_hz, cache=site_map_cache, workers=workers)
    forest = {k: v for k, v in (card.get("forest") or {}).items() if k in ForestSettings.__dataclass_fields__}
    # The virtual drops as the board captures them: localiser, forests, the twin's fit (the virtual set's card).
    train_board_models(virtual, out_dir, fs_hz=fs_hz, settings=ForestSettings(**forest), site_map=board_map,
                       train_rows=train_rows, test_fraction=0.0, seed=int(split.get("seed", 0)))
    model = ImpactModel.load(out_dir)
    model.card = {k: v for k, v in model.card.items() if k not in ("signal", "energy_threshold_j", "created_utc")}
    # The calibration drops and their twins as the board captures them (both with the scan delays), at the trigger
    # chosen on the virtual drops (board.trigger; None: the default)
    trig = {k: v for k, v in board_signal(model.card).items() if k == TRIGGER_KEY} or None
    meas = board_view(session.subset(cal_rows), fs_hz, trig)
    sim = board_view(replace(session.subset(cal_rows), adc=calibration_twins(params, session, cal_rows,
                                                                              int(zs.get("seed", 0)), workers)), fs_hz, trig)
    both = np.intersect1d(meas.recording_id, sim.recording_id)
    meas = meas.subset(np.flatnonzero(np.isin(meas.recording_id, both)))
    sim_adc = sim.adc[np.isin(sim.recording_id, both)]
    # The fits read the captures with the core's configuration as the firmware sets it (the scan's capture delays).
    model.signal = signal_for_board(session.rig, model.signal.to_dict(), fs_hz)
    # the virtual drops as the board captures them: the classifier's fits read them (without a twin always;
    # with one when the host model's boundary sits in the calibrated session's gap between heights)
    needs_virtual = board_map is None or card.get("energy_class_boundary_j") is not None
    virtual_board = board_view(virtual.subset(train_rows), fs_hz, trig) if needs_virtual else None
    fits = fit_on_calibration_drops(model, meas, np.arange(len(meas)), sim_adc, board_map, virtual_board,
                                    class_heights_mm=session.height_mm)
    fits.pop("_virtual_twin")
    return Path(model.save(out_dir, extra_card={
        **fits, "calibration": str(cal_path), "zero_shot": {**zs, "calibration_drops_on_the_board": len(meas)},
        "retrained_from": str(model_dir.resolve())}))
