"""features -> model: the localisation forests and the energy classifier, saved with a model card.

Localisation is physics first, learning second: the core's TDOA localiser gives (x, y); one random forest
per coordinate (one regressor each, so the C export is exact) learns the correction from the core's
feature vector. The energy classifier is a random forest on the energy features; "high" means m g h at or
above the 75th percentile of the training drops. With the twin's site map (sitemap.py) the classifier reads
the twin's height estimate instead (twin.py, the core's twin_estimate), and the reported position is the twin's
matched position around the forests' (or the class only: twin_role.py), its uncertainty a calibrated 1-sigma
radial error fitted on out-of-fold errors of the training drops (out_of_fold_twin)."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from sklearn.ensemble import RandomForestClassifier, RandomForestRegressor

from . import __version__, _core
from .channel_check import fit_channel_check
from .correction_scale import scale_model_correction
from .errors import DataError
from .forestfile import save_forest
from .height_class import (LINEAR_CLASS_FEATURES, LINEAR_ENERGY_FILE, THREE_CHANNEL_FILE, LinearHeightClass,
                           energy_class_choice, fit_linear_height_class, fit_three_channel_classes,
                           out_of_fold_classes)
from .level_members import LEVEL_MEMBERS, add_level_positions, level_positions
from .travel_field import FIELD_MEMBERS, member_field_positions, training_fields
from .three_level_positions import add_level_picks
from .threaded_forests import ThreadedForestClassifier, ThreadedForestRegressor
from .modelfolder import file_hashes, load_forests, read_card, verified_path
from .pipeline import FEATURE_NAMES, Features, featurize
from .host_columns import HOST_LOCATION_FEATURES, chosen_location_names, location_matrix, location_names
from .position_members import (EDGE_MEMBERS, MEMBER_FILES, POSITION_MEMBERS, check_card_members, choose_edge_travel,
                               edge_positions, fit_member_pairs, joined_position, member_positions)
from .signal import SignalConfig
from .sitemap import SiteMap, twin_features
from .three_channel_position import (fit_three_channel_positions, left_out_class, load_three_sensor_path,
                                     save_three_channel_positions, three_sensor_path)
from .twin import TwinFit, calibrated_uncertainty, fit_twin, fit_uncertainty, twin_match
from .twin import estimate as twin_estimate
from .twin_oof import out_of_fold_twin, twin_choice  # noqa: F401 (twin_choice: models' API)
from .twin_role import choose_twin_role
from .twin_edge import refit_class

G_M_S2 = 9.80665
# The forests' inputs: arrival times, the physics position, the channels' relative energies and their first
# peaks. The first peak says which cycle of a slowly growing, dispersive arrival the onset threshold caught (a
# late pick lands on a larger lobe): on a stiff metal or a laminate adding it lowers the held-out MAE on every
# split tried (docs/findings.md, "Other rigs ..."). A model folder keeps the list it was trained with
# (card "location_features"), so models trained before it still load.
LOCATION_FEATURES = [n for n in FEATURE_NAMES if n.startswith(("dtoa_", "rel_toa_", "phys_x", "phys_y",
                                                                "log_energy_rel_", "log_first_peak_"))]
# What a card without "location_features" was trained on (models from before the first peaks were inputs).
LEGACY_LOCATION_FEATURES = [n for n in LOCATION_FEATURES if not n.startswith("log_first_peak_")]
# Where the plate was hit and how much energy, and how much high-frequency energy, reached the sensors
# during the arrival (spectral moments, see impactcore.h): the per-channel energies and first peaks carry
# the site's modal colouring, which the sums over channels and the difference energies average out.
ARRIVAL_ENERGY_FEATURES = ["log_arrival_energy_sum", "log_diff1_energy_sum", "log_diff2_energy_sum",
                           "log_diff3_energy_sum"]
ENERGY_FEATURES = ["phys_x_mm", "phys_y_mm", *ARRIVAL_ENERGY_FEATURES]
# What the measured-trained classifier without a site map reads: ENERGY_FEATURES plus each channel's relative
# energy, their mean and first peaks (the site's colouring per channel): on an aluminium rig it lifts the held-out
# class accuracy on every split it moves, a laminate's little (docs/findings.md, "Other rigs: picks in one
# band ..."). Sim-trained classifiers (zeroshot.py) keep ENERGY_FEATURES; a card without "energy_features"
# was trained on ENERGY_FEATURES.
MEASURED_ENERGY_FEATURES = ENERGY_FEATURES + [n for n in FEATURE_NAMES if n.startswith(
    ("log_energy_rel_", "log_energy_mean", "log_first_peak_"))]
MODEL_FILES = {"x": "forest_dx.npz", "y": "forest_dy.npz", "energy": "forest_energy.npz"}   # forestfile.py
SITE_MAP_FILE = "site_map.npz"
# With a site map the energy classifier reads the twin's height estimate only (twin.py): bagged stumps,
# i.e. a threshold on log10 height learned with its uncertainty.
TWIN_ENERGY_FEATURES = ["twin_log10_height_mm"]
from .modelfolder import CARD_FILE  # noqa: E402


def impact_energy_j(height_mm: np.ndarray, ball_mass_g: float) -> np.ndarray:
    """E = m g h of the ball at release (the class label's quantity)."""
    return ball_mass_g * 1e-3 * G_M_S2 * np.asarray(height_mm, float) * 1e-3


def columns(names: list[str]) -> np.ndarray:
    return np.array([FEATURE_NAMES.index(n) for n in names])


@dataclass
class ForestSettings:
    n_estimators: int = 100
    min_samples_leaf: int = 1
    max_features: float | str = 0.5
    max_depth: int | None = None
    seed: int = 0
    balanced: bool = True     # classifier: class weights inverse to the class sizes

    def regressor(self) -> RandomForestRegressor:
        return ThreadedForestRegressor(n_estimators=self.n_estimators, min_samples_leaf=self.min_samples_leaf,
                                     max_features=self.max_features, max_depth=self.max_depth,
                                     random_state=self.seed, n_jobs=-1)

    def classifier(self) -> RandomForestClassifier:
        return ThreadedForestClassifier(n_estimators=self.n_estimators, min_samples_leaf=self.min_samples_leaf,
                                      max_features="sqrt", max_depth=self.max_depth,
                                      random_state=self.seed, n_jobs=-1,
                                      class_weight="balanced" if self.balanced else None)


# Unweighted: the boundary between two drop heights, not shifted toward the rarer "high" class.
TWIN_CLASSIFIER = ForestSettings(n_estimators=25, max_depth=1, balanced=False)


def fit_energy_classifier(X: np.ndarray, energy_j: np.ndarray,
                          settings: ForestSettings | None = None) -> tuple[RandomForestClassifier, float]:
    """The energy classifier on ENERGY_FEATURES columns; "high" = m g h >= the drops' 75th percentile."""
    threshold = float(np.percentile(energy_j, 75))
    label = (np.asarray(energy_j) >= threshold).astype(int)
    if np.unique(label).size < 2:
        raise DataError("training data", "height_mm", "all drops fall in one energy class")
    return (settings or ForestSettings()).classifier().fit(X, label), threshold


def three_channel_rows(features: Features) -> np.ndarray:
    """Rows the core processed with exactly one channel without an onset and a physics position from the
    other three."""
    return ((features.status == _core.STATUS_OK) & (features.no_onset.sum(1) == 1)
            & np.isfinite(features.phys_xy_mm).all(1))


def _fit_site_twin(features, use, twin_rows, X_loc, xy, height_mm, energy_j, site_map, settings, choose_twin,
                   card, signal=None) -> tuple:
    """ImpactModel.fit's twin: (site_map, twin_fit, energy classifier, threshold) fitted on the used rows among
    twin_rows; with choose_twin also the card's "twin_choice" figures (twin_role.choose_twin_role decides)."""
    # The twin's height estimate of each training drop at its physics position (an error like the
    # forests' at test time), from offsets/slopes/weights fitted at the drops' true positions.
    tw = np.flatnonzero(use) if twin_rows is None else np.flatnonzero(use & np.asarray(twin_rows, bool))
    sel = np.isin(np.flatnonzero(use), tw)   # those rows among the used ones
    t_xy, t_h, t_phys = xy[sel], np.asarray(height_mm, float)[tw], features.phys_xy_mm[tw]
    feats, usable = twin_features(features.take(tw))
    twin_fit = fit_twin(feats, usable, site_map, t_xy, t_h)
    est = twin_estimate(site_map, twin_fit, feats, usable, t_phys)["log10_height_mm"]
    ok = np.isfinite(est)
    fe, threshold = fit_energy_classifier(est[ok, None], energy_j[sel][ok], TWIN_CLASSIFIER)
    compare = dict(X_energy=features.vector[use][sel][:, columns(MEASURED_ENERGY_FEATURES)], energy_j=energy_j[sel],
                   twin_classifier=TWIN_CLASSIFIER) if choose_twin else {}
    oof = out_of_fold_twin(X_loc[sel], t_phys, t_xy, t_h, feats, usable, site_map, settings, **compare)
    for key, value in fit_uncertainty(oof["spread_mm"], oof["misfit"], oof["error_mm"]).items():
        setattr(twin_fit, key, value)
    fe, threshold = refit_class(twin_fit, oof, t_h, t_xy, signal, energy_j[sel], card) or (fe, threshold)  # twin_edge
    if choose_twin:   # the figures twin_role.choose_twin_role decides by
        card["twin_choice"] = twin_choice(oof, t_xy)
    return site_map, twin_fit, fe, threshold


@dataclass
class ImpactModel:
    signal: SignalConfig
    forest_dx: RandomForestRegressor
    forest_dy: RandomForestRegressor
    forest_energy: RandomForestClassifier
    energy_threshold_j: float
    card: dict = field(default_factory=dict)
    # The twin's energy fingerprint (twin.py): when present, the energy classifier reads its height estimate.
    site_map: SiteMap | None = None
    twin_fit: TwinFit | None = None
    # The feature vector's columns the position forests read, in their order (the card's location_features).
    location_features: list[str] = field(default_factory=lambda: list(LOCATION_FEATURES))
    # The feature vector's columns the energy classifier reads without a site map (the card's energy_features).
    energy_class_features: list[str] = field(default_factory=lambda: list(MEASURED_ENERGY_FEATURES))
    # POSITION_MEMBERS name -> (forest dx, forest dy) on that position; empty: the physics position's pair only.
    members: dict = field(default_factory=dict)
    # Without a site map: channel left out -> the linear estimate of log m g h on the other three channels'
    # energies (height_class.three_channel_inputs), the class of a drop with that channel without an onset.
    three_channel_class: dict = field(default_factory=dict)
    # Without a site map, with members (host only): channel out -> the pair correcting the three-sensor position.
    three_channel_position: dict = field(default_factory=dict)
    # (host only) {"forests": pick set -> pick_correction forest, "weights": channel out -> stack weights}: the
    # channels whose three-sensor position is the stack of plain and pick-corrected positions; empty: none.
    three_channel_stack: dict = field(default_factory=dict)
    # The edge correction's coefficients per pick set (edge_travel.py; {"threshold": [...], "band": [...] or
    # None}); empty: off. With it the members include EDGE_MEMBERS.
    edge_travel: dict = field(default_factory=dict)
    # With a site map: the reported position is the twin's match (False: the class only, twin_role.py).
    twin_position: bool = True

    # ----- training -----
    @classmethod
    def fit(cls, features: Features, xy_mm: np.ndarray, height_mm: np.ndarray, ball_mass_g: float,
            signal: SignalConfig, settings: ForestSettings | None = None,
            site_map: SiteMap | None = None, members: bool = True, choose_twin: bool = False,
            choose_class: bool = False, choose_edge: bool = False,
            twin_rows: np.ndarray | None = None, twin_edge: bool = False) -> "ImpactModel":
        """members: with the band picks on, also the POSITION_MEMBERS' forest pairs (False: the board's one
        pair). twin_rows: with a site map, the drops (bool per row) the twin's offsets, weights, uncertainty and
        energy class are fitted on (None: all); the forests learn from all (simulated drops stay out of the twin's
        fit to the rig's recordings). choose_twin: with a site map, the twin's role (position and class, class only,
        none) as the training drops' out-of-fold figures say (twin_role.py; the card's "twin_choice").
        choose_class: without a site map, the energy class from the classifier forest or the linear estimate of log
        m g h (height_class.py), whichever the training drops' out-of-fold accuracy prefers (card:
        "energy_class_choice"). choose_edge: with members and without a site map, the edge correction of the
        arrival times (edge_travel.py) and its EDGE_MEMBERS when the training drops' physics positions say so; the
        level members as correction_scale chooses. twin_edge: the twin estimate's edge term (twin_edge.py; off)."""
        if site_map is not None and choose_twin is True:   # the twin's role in the model (twin_role.py)
            return choose_twin_role(cls.fit, (features, xy_mm, height_mm, ball_mass_g, signal, settings), site_map,
                                    members=members, choose_class=choose_class, choose_edge=choose_edge,
                                    twin_rows=twin_rows, twin_edge=twin_edge)
        settings = settings or ForestSettings()
        use = features.usable
        if use.sum() < 10:
            raise DataError("training data", None, f"only {int(use.sum())} usable drops (need >= 10)")
        X = features.vector[use]
        xy = np.asarray(xy_mm, float)[use]
        resid = xy - features.phys_xy_mm[use]
        card = {"forest": settings.__dict__, "n_train_drops": int(use.sum())}
        edge, train = {}, features.take(np.flatnonzero(use))
        if choose_edge and members and site_map is None:
            edge = choose_edge_travel(train, xy, signal) or {}
            card["edge_travel_chosen"] = bool(edge)
        positions = member_positions(train) if members else None
        loc_names = (chosen_location_names(train, xy, signal, positions, edge, settings, card)   # host_columns.py
                     if choose_edge and members and site_map is None else location_names(signal.channel_left_out, False))
        X_loc = location_matrix(train, loc_names)
        fx = settings.regressor().fit(X_loc, resid[:, 0])
        fy = settings.regressor().fit(X_loc, resid[:, 1])
        member_forests = {}
        if positions is not None and float(signal.band_velocity_mm_per_us) > 0:
            member_forests = fit_member_pairs({name: positions[name] for name in POSITION_MEMBERS}, X_loc,
                                              xy, settings.regressor, loc_names, all_or_none=True)
        energy_j = impact_energy_j(np.asarray(height_mm)[use], ball_mass_g)
        twin_fit = None
        if site_map is not None:
            site_map, twin_fit, fe, threshold = _fit_site_twin(features, use, twin_rows, X_loc, xy, height_mm,
                                                               energy_j, site_map, settings, choose_twin, card,
                                                               signal if twin_edge else None)
        class_features = list(MEASURED_ENERGY_FEATURES)
        if site_map is None:
            fe, threshold = fit_energy_classifier(X[:, columns(MEASURED_ENERGY_FEATURES)], energy_j, settings)
            if choose_class:
                X_lin = X[:, columns(LINEAR_CLASS_FEATURES)]
                card["energy_class_choice"] = energy_class_choice(out_of_fold_classes(
                    X[:, columns(MEASURED_ENERGY_FEATURES)], X_lin, energy_j, xy, settings))
                if card["energy_class_choice"]["use_linear"]:
                    fe, class_features = fit_linear_height_class(X_lin, energy_j, threshold), list(LINEAR_CLASS_FEATURES)
        three = fit_three_channel_classes(train.raw, train.phys_xy_mm, energy_j, threshold) if site_map is None else {}
        if edge:   # chosen only with members and without a site map
            member_forests.update(fit_member_pairs(edge_positions(train, signal, edge), X_loc, xy,
                                                   settings.regressor, loc_names, all_or_none=False))
        three_xy, stack = {}, {}
        if members and site_map is None and not any(signal.channel_left_out):   # host only, as the members
            three_xy, factors, card["three_channel_position_levels"], card["three_channel_position_edge"], stack = \
                fit_three_channel_positions(train, xy, signal, settings.seed, edge or None)
            card["three_channel_position_scale"] = {str(c): f for c, f in factors.items()}
        if site_map is None:   # one channel against the other three, the twin's misfit's stand-in (channel_check.py)
            check = fit_channel_check(train.raw, signal, train.phys_xy_mm, xy)
            if check is not None:
                card["channel_check"] = check
        if site_map is None:   # the forests' position is the one reported: its correction scaled as the drops say
            levels = level_positions(train) if choose_edge and members else None   # level_members.py
            scale_model_correction(card, X_loc, xy, train, signal, edge, fx, fy, member_forests, settings,
                                   levels, training_fields(train.raw, xy, signal) if choose_edge and members else None,
                                   loc_names)
        return cls(signal=signal, forest_dx=fx, forest_dy=fy, forest_energy=fe,
                   energy_threshold_j=threshold, site_map=site_map, twin_fit=twin_fit,
                   card=card, members=member_forests, energy_class_features=class_features,
                   three_channel_class=three, edge_travel=edge, location_features=loc_names,
                   three_channel_position=three_xy, three_channel_stack=stack)

    @property
    def energy_features(self) -> list[str]:
        return TWIN_ENERGY_FEATURES if self.site_map is not None else self.energy_class_features

    @property
    def position_source(self) -> str:
        """Where the reported x, y come from: "twin" (the site map's match; not a class-only twin), else "forest"."""
        return "twin" if self.site_map is not None and self.twin_position else "forest"

    # ----- inference -----
    def predict(self, features: Features) -> dict:
        """Position (mm), per-coordinate spread of the forests' trees, energy class; NaN / -1 where unusable.
        Without a site map x, y are the forests' (physics + correction); with one the twin's matched position
        around the forests' (twin.h TwinEstimate; the board's impactapp TableModels), the forests' in
        forest_xy_mm, unless the twin gives the class only (twin_position False: twin_role.py). An event the twin
        cannot match gets no position and no class. uncertainty_mm: the twin's calibrated 1-sigma radial error
        (twin.calibrated_uncertainty of the match's spread and misfit, as on the board), else NaN."""
        n = len(features)
        xy = np.full((n, 2), np.nan)
        spread = np.full((n, 2), np.nan)
        energy_class = np.full(n, -1, int)
        # no forests on a drop with a channel left out unless trained so (then they read none of its arrival times)
        L = location_matrix(features, self.location_features)
        use = features.usable & np.isfinite(L).all(1)
        if use.any():
            X = features.vector[use]
            Xl = L[use]
            for k, forest in enumerate((self.forest_dx, self.forest_dy)):
                per_tree = np.stack([t.predict(Xl) for t in forest.estimators_])
                xy[use, k] = features.phys_xy_mm[use, k] + per_tree.mean(0)
                spread[use, k] = per_tree.std(0)
            self._join_members(features, use, xy)
            if self.site_map is None:
                energy_class[use] = self.forest_energy.predict(X[:, columns(self.energy_class_features)])
                left_out_class(self, features, use, energy_class)
        out = {"xy_mm": xy, "forest_xy_mm": xy, "spread_mm": spread, "energy_class": energy_class,
               "uncertainty_mm": np.full(n, np.nan), "position_source": self.position_source}
        # One channel without an onset: the physics localiser's three-sensor position (a twin starts there)
        three = three_channel_rows(features) & ~use
        xy[three] = features.phys_xy_mm[three]
        out["three_channel"] = three
        if self.position_source == "forest":   # a channel the check flags, the host's correction, the class
            three_sensor_path(self, features, use, out)
        if self.site_map is not None:
            reported = out["xy_mm"]   # the class-only twin's start: the model's own position
            out["xy_mm"] = np.full((n, 2), np.nan) if self.twin_position else reported
            out["height_mm"] = np.full(n, np.nan)
            out["twin_spread_mm"] = np.full(n, np.nan)
            out["twin_misfit"] = np.full(n, np.nan)
            out["bad_channel"] = out.get("bad_channel", np.full(n, -1))   # the class-only twin's: the check's
            rows = np.flatnonzero(features.status == _core.STATUS_OK)
            if rows.size:
                start = (np.where(use[rows, None], xy[rows], np.nan) if self.twin_position   # NaN: not run
                         else reported[rows])
                twin = twin_match(self.site_map, self.twin_fit, features.take(rows), start, self.signal)
                est = twin["log10_height_mm"]
                ok = (np.asarray(twin["status"]) == 0) & np.isfinite(est)
                energy_class[rows[ok]] = self.forest_energy.predict(est[ok, None])
                out["height_mm"][rows[ok]] = 10.0 ** est[ok]
                if not self.twin_position:
                    return out
                out["xy_mm"][rows[ok]] = np.asarray(twin["xy_mm"], float)[ok]
                spread = np.asarray(twin["spread_mm"], float)[ok]
                misfit = np.asarray(twin["misfit"], float)[ok]
                out["twin_spread_mm"][rows[ok]] = spread
                out["twin_misfit"][rows[ok]] = misfit
                out["uncertainty_mm"][rows[ok]] = calibrated_uncertainty(self.twin_fit, spread, misfit)
                inconsistent = ok & np.isin(np.asarray(twin["reason"]), (_core.TWIN_INCONSISTENT, _core.TWIN_WEAK_CHANNEL))
                out["bad_channel"][rows[inconsistent]] = np.asarray(twin["left_out"])[inconsistent]
        return out

    def featurize(self, adc: np.ndarray) -> Features:
        """The recordings' features as predict reads them, with the level members' positions if it has them and
        the picks at the onset levels if its three-sensor path reads them (three_level_positions.py)."""
        feats = add_level_positions(featurize(adc, self.signal), adc, self.signal, self.members)
        levels = self.card.get("three_channel_position_levels") or self.three_channel_stack
        return add_level_picks(feats, adc, self.signal) if levels else feats

    def _join_members(self, features: Features, use: np.ndarray, xy: np.ndarray) -> None:
        """xy (the main pair's position, in place) becomes the mean over every member that placed the drop:
        the band and threshold picks' pairs and the edge members (position_members.joined_position)."""
        if not self.members:
            return
        rows = np.flatnonzero(use)
        sub = features.take(rows)
        positions = member_positions(sub) if any(n in self.members for n in POSITION_MEMBERS) else None
        edges = (edge_positions(sub, self.signal, self.edge_travel)
                 if self.edge_travel and any(n in self.members for n in EDGE_MEMBERS) else {})
        if any(n in self.members for n in LEVEL_MEMBERS):   # absent from features: those members do not join
            edges.update(level_positions(sub) or {})
        edges.update(member_field_positions(sub.raw, self.signal, self.card, self.members))   # travel_field.py
        X_loc = location_matrix(sub, self.location_features)
        xy[rows] = joined_position(xy[rows], sub.phys_xy_mm, self.members, X_loc, positions, edges,
                                   self.location_features, self.card.get("member_stack"))[0]

    # ----- persistence -----
    def save(self, out_dir: str | Path, extra_card: dict | None = None, force: bool = False) -> Path:
        """The model folder (modelfolder.py), written whole through outputs.output_folder."""
        from .outputs import output_folder

        out = Path(out_dir)
        with output_folder(out, force, tool="impactsense model") as stage:
            self.write_into(stage, extra_card)
        return out

    def write_into(self, stage: Path, extra_card: dict | None = None) -> None:
        """The model's files and card into `stage` (a staging folder of outputs.output_folder)."""
        linear = isinstance(self.forest_energy, LinearHeightClass)
        for role, forest in (("x", self.forest_dx), ("y", self.forest_dy), ("energy", self.forest_energy)):
            if role == "energy" and linear:
                forest.save(stage / LINEAR_ENERGY_FILE)
            else:
                save_forest(stage / MODEL_FILES[role], forest)
        for name, pair in self.members.items():
            for axis, forest in zip("xy", pair):
                save_forest(stage / MEMBER_FILES[f"{axis}_{name}"], forest)
        for c, estimate in self.three_channel_class.items():
            estimate.save(stage / THREE_CHANNEL_FILE.format(c))
        three_xy, three_stack = save_three_channel_positions(stage, self.three_channel_position,
                                                            self.three_channel_stack)
        twin = {}
        if self.site_map is not None:
            self.site_map.save(stage / SITE_MAP_FILE)
            twin = {"twin": {"site_map": SITE_MAP_FILE, "site_map_sha": self.site_map.fingerprint(),
                             "ref_height_mm": self.site_map.ref_height_mm, **self.twin_fit.to_dict()}}
        # every file of the model folder gets its checksum in the card (modelfolder.read_verified)
        names = [p.name for p in stage.iterdir()
                 if p.is_file() and not p.name.startswith(".") and p.name != CARD_FILE]
        card = {
            "package": "impactsense",
            "package_version": __version__,
            "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "target": "x = phys_x_mm + forest_dx(features[location_features]); same for y",
            # The reported x, y: "twin" = the site map's matched position around the forests' (twin.h), the
            # forests' otherwise (models.ImpactModel.predict; the board does the same).
            "position_source": self.position_source,
            "feature_names": FEATURE_NAMES,
            "location_features": self.location_features,
            "energy_features": self.energy_features,
            "energy_threshold_j": self.energy_threshold_j,
            "energy_classes": {"0": "low", "1": "high"},
            "files": {**MODEL_FILES, **({"energy": LINEAR_ENERGY_FILE} if linear else {}),
                      **{f"{a}_{n}": MEMBER_FILES[f"{a}_{n}"] for n in self.members for a in "xy"}},
            "signal": self.signal.to_dict(),
        }
        if linear:   # the energy class from height_class.LinearHeightClass (absent: a classifier forest)
            card["energy_model"] = "linear"
        if self.three_channel_class:   # a drop with one channel without an onset: its class from the other three
            card["three_channel_class"] = {str(c): THREE_CHANNEL_FILE.format(c) for c in self.three_channel_class}
        if three_xy:   # a drop with one channel without an onset: its three-sensor position's correction
            card["three_channel_position"] = three_xy
        if three_stack:   # and the channels whose three-sensor position is a stack (three_channel_position.py)
            card["three_channel_position_stack"] = three_stack
        if self.edge_travel:   # the edge correction's coefficients (edge_travel.py) its members read
            card["edge_travel"] = self.edge_travel
        if self.members:
            card["position_members"] = list(self.members)
            card["target"] = ("x = mean of phys_x_mm + forest_dx(features[location_features]) and, where the band "
                              "picks placed the drop, each position_members' x + its forest_dx (its x, y in "
                              "place of phys_x/y_mm); same for y")
        # what the card carried from before (training settings, provenance); what the model holds now wins
        card = {
            **card,
            **{k: v for k, v in self.card.items()
               if k not in card and k not in ("twin", "sha256", "energy_model", "three_channel_class", "edge_travel",
                                                         "three_channel_position", "three_channel_position_stack")},
            **twin,
            **(extra_card or {}),
            "sha256": file_hashes(stage, names),
        }
        (stage / CARD_FILE).write_text(json.dumps(card, indent=1))
        self.card = card

    @classmethod
    def load(cls, model_dir: str | Path) -> "ImpactModel":
        """Reads a model folder; only the files its card names, each checked against the card's sha256, none
        of them a pickle (modelfolder.py: the trust boundary)."""
        d = Path(model_dir)
        card, card_path = read_card(d)
        for key in ("signal", "energy_threshold_j", "feature_names"):
            if key not in card:
                raise DataError(card_path, key, "missing key")
        if card["feature_names"] != FEATURE_NAMES:
            raise DataError(card_path, "feature_names", "model was trained on another feature set; retrain")
        if not isinstance(card["signal"], dict) or isinstance(card["energy_threshold_j"], bool) \
                or not isinstance(card["energy_threshold_j"], (int, float)):
            raise DataError(card_path, "signal/energy_threshold_j", "wrong type")
        f = load_forests(d, card, card_path, ("x", "y", "energy"))
        forests = [f["x"], f["y"], f["energy"]]
        if card.get("energy_model", "forest") not in ("forest", "linear"):
            raise DataError(card_path, "energy_model", "must be \"forest\" or \"linear\"")
        site_map = twin_fit = None
        if "twin" in card:
            if not isinstance(card["twin"], dict):
                raise DataError(card_path, "twin", "must be an object")
            site_map = SiteMap.load(verified_path(d, card, card_path, card["twin"].get("site_map", SITE_MAP_FILE),
                                                  "twin.site_map"))
            if site_map.fingerprint() != card["twin"].get("site_map_sha"):
                raise DataError(d / SITE_MAP_FILE, None, "site map differs from the one the model was trained with")
            twin_fit = TwinFit.from_dict({k: v for k, v in card["twin"].items()
                                          if k not in ("site_map", "site_map_sha", "ref_height_mm")})
        try:
            signal = SignalConfig.from_dict(card["signal"])
        except (TypeError, ValueError, KeyError, OverflowError) as exc:
            raise DataError(card_path, "signal", str(exc)) from None
        loc = card.get("location_features", LEGACY_LOCATION_FEATURES)
        if not isinstance(loc, list) or not loc or any(n not in FEATURE_NAMES + HOST_LOCATION_FEATURES for n in loc):
            raise DataError(card_path, "location_features", "must list names from feature_names or host_columns")
        if len(loc) != getattr(forests[0], "n_features_in_", len(loc)):
            raise DataError(card_path, "location_features", f"lists {len(loc)}, the x forest reads {forests[0].n_features_in_}")
        energy = ENERGY_FEATURES if site_map is not None else card.get("energy_features", ENERGY_FEATURES)
        if not isinstance(energy, list) or not energy or any(n not in FEATURE_NAMES for n in energy):
            raise DataError(card_path, "energy_features", "must list names from feature_names")
        if site_map is None and len(energy) != getattr(forests[2], "n_features_in_", len(energy)):
            raise DataError(card_path, "energy_features", f"lists {len(energy)} features, the energy forest "
                                                          f"reads {forests[2].n_features_in_}")
        names, known = card.get("position_members", []), POSITION_MEMBERS + EDGE_MEMBERS + LEVEL_MEMBERS + FIELD_MEMBERS
        if not isinstance(names, list) or any(n not in known for n in names):
            raise DataError(card_path, "position_members", f"must list names from {list(known)}")
        edge = check_card_members(card, card_path, names)   # the edge members' coefficients, the field members' fields
        if names and [n for n in loc if n in FEATURE_NAMES] != location_names(signal.channel_left_out, False):
            raise DataError(card_path, "position_members", "needs the current location_features (without a "
                                                           "left-out channel's arrival times)")
        extra = load_forests(d, card, card_path, [f"{a}_{n}" for n in names for a in "xy"]) if names else {}
        members = {n: (extra[f"x_{n}"], extra[f"y_{n}"]) for n in names}
        three_channel, three_xy, three_stack = load_three_sensor_path(d, card, card_path)
        return cls(signal=signal, forest_dx=forests[0], forest_dy=forests[1],
                   forest_energy=forests[2], energy_threshold_j=float(card["energy_threshold_j"]), card=card,
                   site_map=site_map, twin_fit=twin_fit, location_features=list(loc),
                   energy_class_features=list(energy), members=members, three_channel_class=three_channel,
                   three_channel_position=three_xy, three_channel_stack=three_stack,
                   edge_travel=edge if any(n in EDGE_MEMBERS for n in names) else {},
                   twin_position=card.get("position_source") != "forest")
