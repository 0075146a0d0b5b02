"""Train and evaluate: the steps `impactsense train`, `evaluate` and `demo` share."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import _core
from .band_forests import ForestBandChoice
from .checks import require_labels, rig_summary
from .data import IMPACTS_FILE, Session
from .errors import DataError
from .flagged_position import choose_flagged_positions
from .level_members import add_level_positions
from .three_level_positions import add_level_picks
from .metrics import region_metrics
from .models import ForestSettings, ImpactModel, impact_energy_j
from .outputs import json_text, write_file
from .pipeline import featurize, fit_localiser
from .signal import SignalConfig
from .split import case_split


def train(session: Session, out_dir: str | Path | None, test_fraction: float = 0.2, seed: int = 0,
          exclude_rows: np.ndarray | None = None, settings: ForestSettings | None = None,
          signal: SignalConfig | None = None, extra_card: dict | None = None,
          site_map=None, force: bool = False, choose_twin: bool = False,
          choose_class: bool = False, members: bool = True,
          twin_rows: np.ndarray | None = None,
          rig_drops: tuple[np.ndarray, np.ndarray] | None = None,
          twin_edge: bool = False) -> tuple[ImpactModel, dict]:
    """Fits the localiser constants and the forests on the training cases; saves if out_dir is given.
    choose_twin: keep the site map's twin only when the training drops' out-of-fold figures say so
    (twin_oof.twin_choice; a measured session's calibrated twin). choose_class: without a site map, the energy
    class from the classifier forest or the linear estimate, as those figures say (height_class.py), and the edge
    correction of the arrival times when the training drops' physics positions say so (position_members.choose_edge_travel).
    members False: one forest pair on the physics position (no position members: what the board runs).
    twin_rows: the session's rows (bool) the site map's twin is fitted on (ImpactModel.fit; None: all).
    rig_drops (adc, xy_mm): the session is a calibrated twin's virtual drops (simulate-dataset --calibration) and
    these the rig's calibration drops: the localiser's onset threshold is chosen for the rig (fit_localiser).
    twin_edge: with a site map, the twin height estimate's edge term (twin_edge.py) as the training drops'
    out-of-fold estimates say; off by default (it helps the session's held-out drops and hurts another day's:
    docs/findings.md "Session 19: classfix"); never on virtual drops (that twin is refitted on the rig's drops)."""
    require_labels(session)
    train_rows, test_rows = case_split(session.case_id, test_fraction, seed, exclude_rows)
    if test_fraction > 0 and len(test_rows) == 0:
        raise DataError(session.path / IMPACTS_FILE, "case_id", f"no case can be held out: the drops are in "
                        f"{session.n_cases} case(s) (give more cases, or --test-fraction 0)")
    cfg = signal or SignalConfig.for_rig(session.rig)
    # Without a site map (nor a virtual set), or with a twin that may give the class only (twin_role.py), the forests'
    # position is (or may be) the one reported: the band picks as their out-of-fold positions say (band_forests.py)
    band_choice = (ForestBandChoice(session, train_rows, settings or ForestSettings())
                   if (site_map is None or choose_twin) and rig_drops is None and members else None)
    cfg = fit_localiser(session, train_rows, cfg, rig_drops=rig_drops, band_choice=band_choice)
    feats = featurize(session.adc, cfg)
    if choose_class and members and (site_map is None or choose_twin):   # the level members' positions
        add_level_positions(feats, session.adc, cfg)
        add_level_picks(feats, session.adc, cfg)   # and the picks the three-sensor path may read (three_level_positions.py)
    model = ImpactModel.fit(feats.take(train_rows), session.xy_mm[train_rows], session.height_mm[train_rows],
                            session.rig.ball_mass_g, cfg, settings, site_map=site_map, choose_twin=choose_twin,
                            choose_class=choose_class, choose_edge=choose_class, members=members,
                            twin_rows=None if twin_rows is None else np.asarray(twin_rows, bool)[train_rows],
                            twin_edge=twin_edge and rig_drops is None)
    if band_choice is not None:
        model.card["band_choice"] = band_choice.record
    if choose_class and members:   # a flagged drop's position per channel, as a debond there says (flagged_position.py)
        rig = session.rig
        choose_flagged_positions(model, session.adc[train_rows], session.xy_mm[train_rows], float(rig.fs_hz),
                                 float(rig.bias_counts), int(rig.adc_max), seed)
    split = {
        "data_path": str(session.path),
        "data_hash": session.fingerprint(),
        "recordings_hash": session.recordings_hash(),
        "test_fraction": test_fraction,
        "seed": seed,
        "train_recordings": session.recording_id[train_rows].tolist(),
        "test_recordings": session.recording_id[test_rows].tolist(),
        "excluded_recordings": [] if exclude_rows is None else session.recording_id[np.asarray(exclude_rows)].tolist(),
    }
    if out_dir is not None:
        model.save(out_dir, extra_card={"split": split, "rig": rig_summary(session.rig), **(extra_card or {})},
                   force=force)
    else:
        model.card.update(split=split, rig=rig_summary(session.rig))
    return model, split


def evaluation_rows(session: Session, model: ImpactModel) -> tuple[np.ndarray, str]:
    """On the model's own session only its held-out drops; on the session a sim-trained model's calibration
    came from, its drops but the calibration drops; on any other session every drop."""
    split = model.card.get("split", {})
    split = split if isinstance(split, dict) else {}
    own = (split["recordings_hash"] == session.recordings_hash() if split.get("recordings_hash")
           else bool(split.get("data_hash")) and split["data_hash"] == session.fingerprint())
    if own:
        rows = np.asarray(split.get("test_recordings", []), int)
        return rows, "held-out drops of the training session"
    zero = model.card.get("zero_shot", {})
    if zero.get("data_hash") and zero["data_hash"] == session.fingerprint():
        rows = np.asarray(zero.get("test_recordings", []), int)
        return rows, "the calibrated session's drops but the calibration drops (a sim-trained model)"
    return np.arange(len(session)), "all drops (another session)"


def evaluate(session: Session, model: ImpactModel, rows: np.ndarray | None = None) -> dict:
    """The JSON report of `impactsense evaluate`."""
    scope = "given rows"
    if rows is None:
        rows, scope = evaluation_rows(session, model)
    if len(rows) == 0:
        raise DataError(session.path, None, "no drops to evaluate (the model was trained with --test-fraction 0 "
                                            "on this session)")

    require_labels(session, rows)
    feats = model.featurize(session.adc[rows])
    pred = model.predict(feats)
    true_xy = session.xy_mm[rows]
    ok = np.isfinite(pred["xy_mm"]).all(1)
    classed = ok & (pred["energy_class"] >= 0)
    energy = impact_energy_j(session.height_mm[rows], session.rig.ball_mass_g)
    region = session.rig.inner_region_mm
    label = (energy >= model.energy_threshold_j).astype(int)
    report = {
        "scope": scope,
        "n": int(len(rows)),
        "predicted": int(ok.sum()),
        "accepted": int(feats.accepted.sum()),
        "rejected": int((~feats.accepted).sum()),
        **region_metrics(true_xy[ok], pred["xy_mm"][ok], region),
        # over the drops given a class (a drop placed without one: a channel without an onset and no site map)
        "classified": int(classed.sum()),
        "energy_class_accuracy": float(np.mean(pred["energy_class"][classed] == label[classed])) if classed.any()
        else float("nan"),
        "physics": region_metrics(true_xy[ok], feats.phys_xy_mm[ok], region),
        # Where all/inner's positions come from ("twin": the site map's match, "forest"), and the forests'
        # own position on the same drops (the twin's starting point; equal to all/inner without a site map).
        "position_source": pred["position_source"],
        "forest": region_metrics(true_xy[ok], pred["forest_xy_mm"][ok], region),
        "accepted_only": region_metrics(true_xy[ok & feats.accepted], pred["xy_mm"][ok & feats.accepted], region),
        "energy_threshold_j": model.energy_threshold_j,
        "high_energy_fraction": float(label.mean()),
        "clipped_drops": int(feats.clipped.any(1).sum()),
        # drops with no position, and of them those clipped on every channel with an onset (a twin model's match
        # reads no energy there: the core's "clipped" reason, impactcore.h kErrClipped)
        "not_placed": int((~ok).sum()),
        "not_placed_every_channel_clipped": int((~ok & feats.clipped.any(1)
                                                 & (feats.clipped | feats.no_onset | feats.dead).all(1)).sum()),
        "inner_region_mm": list(region),
    }
    # per channel, the drops whose report calls it inconsistent and leaves it out (the twin's misfit or, without a
    # site map, the channel check): a debonded disc
    flags = channel_flags(feats.flags, pred)
    report["channels_left_out_inconsistent"] = [int(v) for v in ((flags & _core.FLAG_INCONSISTENT) != 0).sum(0)]
    report["_arrays"] = {"rows": rows, "true_xy": true_xy, "pred_xy": pred["xy_mm"], "forest_xy": pred["forest_xy_mm"],
                         "phys_xy": feats.phys_xy_mm,
                         "spread": pred["spread_mm"], "energy_class": pred["energy_class"], "label": label,
                         "accepted": feats.accepted, "flags": flags}
    return report


def channel_flags(flags: np.ndarray, pred: dict) -> np.ndarray:
    """The core's channel flags with FLAG_INCONSISTENT where the models left a channel out (bad_channel)."""
    out = np.array(flags, copy=True)
    bad = np.asarray(pred.get("bad_channel", np.full(len(out), -1)))
    rows = np.flatnonzero(bad >= 0)
    out[rows, bad[rows]] |= _core.FLAG_INCONSISTENT
    return out


def public(report: dict) -> dict:
    """The report without its arrays, for JSON."""
    return {k: v for k, v in report.items() if not k.startswith("_")}


def write_json(report: dict, path: str | Path) -> None:
    write_file(path, json_text(public(report)))
