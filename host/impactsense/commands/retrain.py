"""impactsense retrain --baseline DATA_REF --data DATA_NEW --out MODEL_DIR"""

from __future__ import annotations

import math
from pathlib import Path

from ..bond_choice import fit_with_bond_choice

ORDER = 51
TRAINING_DATA = "training-data"   # OUT's copy of DATA_REF with the effects put in
TWIN_TRAINING_DATA = "twin-training-data"           # a move with a twin: the corrected twin's drops
MEASURED_TRAINING_DATA = "measured-training-data"   # ... and when those are trained on, the recordings' copy


def register(sub) -> None:
    p = sub.add_parser(
        "retrain", help="retrain for a changed rig: add the diagnosed effects to the training data",
        description="Diagnoses DATA_NEW against DATA_REF, puts the significant effects into DATA_REF's "
                    "recordings (each effect's own signal model: gain, low-pass, speed, ...; a channel delay the "
                    "model's picks take out instead), "
                    "trains the standard model on that (as `impactsense train`: with the twin's site map "
                    "for the bundled rig) and evaluates it on DATA_NEW beside a model trained on DATA_REF as "
                    "it is. The recordings with the effects are kept in OUT/training-data, so "
                    "`impactsense export OUT` can train the board's model on them.")
    p.add_argument("--baseline", required=True, help="reference session folder (or 'bundled')")
    p.add_argument("--data", required=True, help="the changed session")
    p.add_argument("--out", required=True, help="model folder to write")
    p.add_argument("--force", action="store_true", help="write into a folder that holds other files (kept)")
    p.add_argument("--test-fraction", type=float, default=0.2, help="cases of DATA_REF held out (default 0.2)")
    p.add_argument("--seed", type=int, default=0, help="seed of the case split and the forests (default 0)")
    p.add_argument("--trees", type=int, default=100, help="trees per forest (default 100)")
    p.add_argument("--site-map", default="auto", metavar="auto|none|site-map.npz",
                   help="the twin's site map, as in `impactsense train` (auto = the bundled twin's when the rig "
                        "is the bundled rig): the twin's position, energy class and calibrated uncertainty, "
                        "its offsets, weights and uncertainty fitted on the recordings with the effects put in")
    p.add_argument("--twin", default=None, metavar="CAL.json",
                   help="also train a model on DATA_REF's declared drops simulated by this calibrated twin with the "
                        "diagnosed plate and sensor effects in the FEM (moved disc, E, damping) and the rest at the "
                        "signal level: zero-shot from the corrected twin (OUT/twin-model)")
    p.add_argument("--moved-rig", action="store_true",
                   help="a diagnosed sensor move also in the retrained model's rig (its localiser and features "
                        "take the disc where the diagnosis places it; off: the move is in the training recordings "
                        "only); measured both ways (docs/findings.md, Session 21 loopmove)")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="the diagnosis's report (report.html, summary.md, figures) with the models' MAE before/after")
    p.add_argument("--exclude", default=None,
                   help="recording ids of DATA_REF to leave out of training (comma-separated, or a CAL.json)")
    p.set_defaults(func=run)


def augment(base, accepted, ref, seed: int = 0):
    """DATA_REF's recordings with the diagnosed effects put in (uint16, same shape)."""
    from ..effects import context
    from ..effects.apply import apply_effects

    effects = [{"effect": c.effect, "sensor": c.sensor, "params": c.params} for c in accepted]
    return apply_effects(base.adc, effects, context(base, ref.slowness_us_per_mm), seed)


def run(args) -> int:
    from ..data import load_session, resolve_session_path
    from ..diagnose import diagnose
    from ..errors import ConfigError
    from ..loop import channel_delays, fit_bond, pick_settings
    from ..models import ForestSettings
    from ..sitemap import resolve_site_map
    from .train import parse_exclude
    try:
        from ..workflow import train
    except ImportError as exc:  # the training API is the lead's
        raise ConfigError(f"retrain needs impactsense.workflow (train/evaluate): {exc}") from None

    if not 0.0 <= args.test_fraction < 1.0:
        raise ConfigError(f"--test-fraction must be in [0, 1), got {args.test_fraction}")
    from ..checks import exclude_rows
    from ..outputs import check_output_folder, json_text, output_folder

    check_output_folder(args.out, args.force)
    base = load_session(args.baseline)
    same = resolve_session_path(args.baseline).resolve() == resolve_session_path(args.data).resolve()
    data = base if same else load_session(args.data)
    # The augmented recordings keep DATA_REF's rig, so the site map resolves the same for both models. The
    # map itself is the twin's (the plate's) and is not changed: the effects act on the recordings, and the
    # twin's offsets, weights and uncertainty are fitted on them (a gain moves that channel's offsets by
    # 2 log10 g; a delay leaves the energies, which start at the arrival, as they were).
    site = resolve_site_map(args.site_map, base.rig)
    exclude = exclude_rows(parse_exclude(args.exclude), base, "--exclude")
    result, details = diagnose(base, data, same=same)
    # a gain loss or low-pass on a channel (a partly debonded disc): its low-pass and gain sized on the recordings
    accepted = [] if same else fit_bond(base, data, details["accepted"], args.seed)
    # a channel whose change the effects cannot describe (a move beyond a re-glued disc's): no effect is put
    # on it, the model leaves it out (the core's channel_left_out: three-sensor position and class), flagged
    left_out = bond_decides(result, accepted)
    accepted = [c for c in accepted if c.sensor not in left_out]
    settings = ForestSettings(n_estimators=args.trees, seed=args.seed)
    card = retrain_card(result, base, data, accepted, left_out, args.moved_rig)
    out = Path(args.out)
    rows = {}
    plain, plain_split = train(base, None, args.test_fraction, args.seed, exclude, settings=settings, site_map=site)
    rows["baseline model"] = score(data, plain)
    train_on = base
    with output_folder(out, args.force, tool="impactsense retrain") as stage:
        if accepted:
            # The drops the model is trained on are kept in OUT (the card's split points there): `export OUT` trains
            # the board's model on them (an absolute path). The twin: the calibration's, else the site map's
            train_on, accepted = training_session(base, data, details, accepted, twin_params(args, site),
                                                  stage / TRAINING_DATA, args.seed, card, args.moved_rig,
                                                  candidate_fit(args, base, exclude, settings, site))
        exclude, measured = training_rows(train_on, base, accepted, exclude)
        (model, split), choice = fit_with_bond_choice(   # a delay: not in the recordings, the model's picks'
            lambda signal: carry_delays(train(train_on, None, args.test_fraction, args.seed, exclude,
                                              settings=settings, signal=signal, extra_card=card, site_map=site,
                                              twin_rows=measured), channel_delays(accepted)),
            pick_settings(train_on, accepted, base), data, accepted, site_map=site, left_out=left_out, seed=args.seed,
            reference=(plain, plain_split))
        left_out = note_bond_choice(card, choice, left_out)   # a bond not absorbed: its channel left out, flagged
        if choice is None and accepted:   # no bond choice: the retrained model against the reference on DATA_NEW
            model, split = keep_better(card, model, split, plain, plain_split, data, args.seed)
        if model is not plain:   # the reference model kept (bond choice): written as it served DATA_NEW
            fit_into_training_data(model, split, train_on, measured, accepted, left_out, out)
        note_sensors_moved(card, model, base, model is not plain)
        model.write_into(stage, extra_card=card)
        rows["retrained model"] = score(data, model)
        if args.twin and "training_choice" not in card["retrain"]:   # (a move: the choice's candidate)
            rows["twin-corrected model"] = twin_model(args, base, data, details, accepted, settings, exclude,
                                                        site, stage)
        (stage / "retrain.json").write_text(json_text({**card, "on_data": rows}))
    if args.report:
        from ..diagnose import write_report
        write_report(result, details, args.report,
                     {"rows": rows, "note": f"every drop of {data.name} (its own labels)"})
    print_summary(result, accepted, rows, data.name, site is not None, out, card["retrain"].get("bond_choice"))
    if card["retrain"].get("model_choice", {}).get("chosen") == "reference":
        print(f"the REFERENCE MODEL IS KEPT: {card['retrain']['model_kept_why']}")
    warning = worse_than_baseline(rows, accepted, data.name)
    if warning:
        print(warning)
    return 0


def carry_delays(fitted, delays):
    """(model, split) of `train` with the diagnosed channel delays taken out of its picks (loop.with_channel_delays:
    a delay is the model's, not its training recordings')."""
    from ..loop import with_channel_delays

    model, split = fitted
    model.signal = with_channel_delays(model.signal, delays)
    return model, split


def training_session(base, data, details, accepted, twin, folder: Path, seed: int, card: dict,
                     moved_rig: bool = False, fit=None):
    """(the session retrain trains on, the accepted effects as put in), written in `folder`: DATA_REF's recordings
    with the effects put in (`loop.measured_training_session`; a random effect: the twin's drops at more positions
    too; `moved_rig`: the rig they are written with carries a diagnosed move); with a twin (SimParams), a diagnosed move (`loop.moves_disc`) and `fit` (session, effects -> model, as
    retrain trains), also DATA_REF's declared drops simulated by the corrected twin (the disc moved in the FEM; a
    plate change sized by the twin's scan as for `--twin`; the rest at the signal level:
    `loop.twin_training_session`), a model fitted on each, and the one whose model places DATA_NEW's labelled drops
    better kept (`model_choice.choose_model`) unless its energy class there is worse by more than one binomial
    standard error (the card's `training_choice`, `training_data`), in `folder` (the other beside it)."""

    from ..data import load_session
    from ..loop import (effect_dicts, measured_training_session, moves_disc, size_plate_change, twin_move_positions,
                        twin_training_session)

    measured = measured_training_session(base, accepted, details["ref"], folder, seed, twin=twin, moved_rig=moved_rig)
    card["retrain"]["training_data"] = "reference recordings with the effects put in"
    if twin is None or fit is None or not moves_disc(accepted):
        return measured, accepted
    sized = size_plate_change(twin, data, accepted, (details["ref"].probe or {}).get("picker"), seed, base=base)
    other = folder.parent / TWIN_TRAINING_DATA
    sim = twin_training_session(base, twin, effect_dicts(sized), other, details["ref"].slowness_us_per_mm, seed,
                                moved_rig=moved_rig, new_positions=twin_move_positions(base, effect_dicts(sized)))
    models = {"measured": fit(measured, accepted), "corrected twin": fit(sim, sized)}
    card["retrain"]["training_choice"] = got = choose_training_data(models, data, seed)
    chosen, acc = got["chosen"], got["class_accuracy"]
    print(f"a moved disc with a twin: DATA_NEW's drops placed by the model trained on DATA_REF's recordings with the "
          f"move put in {got['mae_mm']['measured']:.2f} mm (class {acc['measured']:.3f}), on the corrected twin's "
          f"drops (the disc moved in the FEM) {got['mae_mm']['corrected twin']:.2f} (class "
          f"{acc['corrected twin']:.3f}): trained on the {chosen} drops")
    if chosen == "measured":
        return measured, accepted
    folder.rename(folder.parent / MEASURED_TRAINING_DATA)
    other.rename(folder)
    card["retrain"]["training_data"] = "corrected twin"
    card["retrain"]["effects_added"] = [{"effect": c.effect, "sensor": c.sensor, "params": c.params} for c in sized]
    return load_session(folder), sized


def choose_training_data(models: dict, data, seed: int = 0) -> dict:
    """A moved disc with a twin: which training drops retrain keeps, from the models fitted on each
    (`models`: "measured" and "corrected twin"): the one that places DATA_NEW's labelled drops better
    (`model_choice.choose_model`), the twin's only when its model's energy class there is not worse by more than
    one binomial standard error. The card's `training_choice`: chosen, each one's MAE and class accuracy, the
    rule's cross-fitted MAE."""
    import numpy as np

    from ..model_choice import choose_model

    got = choose_model(models, data, seed)
    acc = {k: class_accuracy(m, data) for k, m in models.items()}
    se = float(np.sqrt(max(acc["measured"] * (1.0 - acc["measured"]), 1e-4) / len(data)))
    chosen = "measured" if acc["corrected twin"] < acc["measured"] - se else got["chosen"]
    return {"chosen": chosen, "mae_mm": got["mae_mm"], "class_accuracy": acc,
            "cross_fitted_mae_mm": got["cross_fitted_mae_mm"]}


def class_accuracy(model, session) -> float:
    """The model's energy class accuracy on every drop of `session` (its labels)."""
    import numpy as np

    from ..workflow import evaluate

    return float(evaluate(session, model, np.arange(len(session)))["energy_class_accuracy"])


def candidate_fit(args, base, exclude, settings, site):
    """fit(session, effects) -> the model retrain trains on that session (its delays carried: `carry_delays`), for
    `training_session`'s choice."""
    from ..loop import channel_delays, pick_settings
    from ..workflow import train

    def fit(session, effects):
        ex, rows = training_rows(session, base, effects, exclude)
        return carry_delays(train(session, None, args.test_fraction, args.seed, ex, settings=settings,
                                  signal=pick_settings(session, effects, base), site_map=site, twin_rows=rows),
                            channel_delays(effects))[0]
    return fit


def retrain_card(result, base, data, accepted, left_out, moved_rig: bool = False) -> dict:
    """What the model card keeps of the diagnosis and the retrain; `sensors_moved`: the discs the retrained
    model's rig (the card's `rig`, its localiser and features) has where the diagnosis placed them."""
    from ..loop import channel_delays, effect_dicts, moved_sensors, training_rig

    return {"diagnose": {k: result[k] for k in ("effects", "before", "after", "reference")},
            "retrain": {"baseline": str(base.path), "data": str(data.path),
                        "effects_added": [{"effect": c.effect, "sensor": c.sensor, "params": c.params}
                                          for c in accepted],
                        "picks_delay_us": channel_delays(accepted),
                        "sensors_moved": moved_sensors(base.rig,
                                                       training_rig(base.rig, effect_dicts(accepted), moved_rig)),
                        "channels_left_out": left_out}}


def training_rows(train_on, base, accepted, exclude):
    """(excluded rows of the training session: every copy of an excluded baseline drop; the rows that are
    recordings, DATA_REF's copies, on which the site map's twin is fitted, not the twin's own drops after them)."""
    import numpy as np

    from ..loop import training_draws

    copies = training_draws(accepted) * len(base) if accepted else len(base)
    if exclude is not None and len(train_on) != len(base):
        rows = np.arange(copies)
        exclude = rows[np.isin(rows % len(base), exclude)]
    return exclude, np.arange(len(train_on)) < copies


def bond_decides(result: dict, accepted) -> list:
    """The channels retrain leaves out: those whose timing asks for a move beyond a re-glued disc's
    (`unabsorbed_channels`), but for one with a diagnosed low-pass (a debonded disc's late, filtered picks ask
    for such a move): its low-pass and gain are put in and the bond choice (`bond_choice`) decides on DATA_NEW
    between that four-channel model and the channel left out (with two sensors close together the three others
    may place worse than the four with the bond modelled)."""
    unabsorbed = sorted(u["sensor"] for u in result.get("unabsorbed_channels", []))
    lowpass = {c.sensor for c in accepted if c.effect == "channel_lowpass"}
    return [k for k in unabsorbed if k not in lowpass]


def note_bond_choice(card: dict, choice, left_out: list) -> list:
    """The card's record of the bond choice (bond_choice.fit_with_bond_choice); the channels left out after it."""
    if choice is None:
        return left_out
    card["retrain"]["bond_choice"] = choice
    if choice["chosen"] == "left_out":
        left_out = [choice["channel"]]
    if choice["chosen"] == "reference":   # the reference model as it is: its check flags the channel itself
        card["retrain"]["model_kept"] = "reference"
        card["retrain"]["model_kept_why"] = reference_kept_why(choice)
    card["retrain"]["channels_left_out"] = left_out
    return left_out


def keep_better(card: dict, model, split, plain, plain_split, data, seed: int):
    """(model, split) retrain writes: the retrained model, or the reference model when it places DATA_NEW's
    labelled drops better (`model_choice.keep_retrained_or_reference`: the effects as sized do not describe
    DATA_NEW); the choice recorded in the card (`model_choice`, and `model_kept` with why when the reference)."""
    from ..model_choice import keep_retrained_or_reference

    choice = keep_retrained_or_reference(model, plain, data, seed)
    card["retrain"]["model_choice"] = choice
    if choice["chosen"] != "reference":
        return model, split
    card["retrain"]["model_kept"] = "reference"
    card["retrain"]["model_kept_why"] = (
        f"the reference model (trained on DATA_REF as it is) places DATA_NEW's drops better "
        f"({choice['reference_mae_mm']:.2f} mm) than the model retrained with the effects "
        f"({choice['retrained_mae_mm']:.2f}; the rule cross-fitted {choice['cross_fitted_mae_mm']:.2f}; its lead per "
        f"case {choice['reference_lead_mm']:+.2f} mm, SE {choice['reference_lead_se_mm']:.2f}): it is the "
        f"model written; the training data with the effects is kept beside it")
    return plain, plain_split


def fit_into_training_data(model, split, train_on, measured, accepted, left_out, out: Path) -> None:
    """A model trained on OUT's training data: its card's split points there (export trains on it again), the
    twin's own drops named, a debonded disc the twin's weak channel, the channels left out set in its signal."""
    from ..loop import weak_channel

    if accepted:
        split["data_path"] = str(out.resolve() / TRAINING_DATA)
    if not measured.all():   # the twin's own drops: `export` keeps them out of the board model's twin fit too
        split["simulated_recordings"] = train_on.recording_id[~measured].tolist()
    if model.twin_fit is not None:   # a debonded disc: the twin also matches without it, and flags it
        model.twin_fit.weak_channel = weak_channel(accepted)
    if left_out:
        model.signal = leave_out(model.signal, left_out)


def note_sensors_moved(card: dict, model, base, retrained: bool) -> None:
    """The card's rig: the written model's (a retrained one's has the diagnosed positions, `sensors_moved`) with
    DATA_REF's declared sensor positions beside them (`declared_sensor_xy_mm`: its sessions' rig.json, which
    `evaluate` checks; printed); the reference model kept: no disc moved, no diagnosed delay in its picks."""
    from ..checks import rig_summary

    if not retrained:
        card["retrain"]["sensors_moved"] = []
        card["retrain"]["picks_delay_us"] = [0.0] * 4
    if card["retrain"]["sensors_moved"]:
        card["rig"] = {**model.card.get("rig", {}),
                       "declared_sensor_xy_mm": rig_summary(base.rig)["sensor_xy_mm"]}
    for m in card["retrain"]["sensors_moved"]:
        print(f"sensor {m['sensor']}: the retrained model's rig has it at ({m['diagnosed_xy_mm'][0]:.1f}, "
              f"{m['diagnosed_xy_mm'][1]:.1f}) mm (declared ({m['declared_xy_mm'][0]:.1f}, "
              f"{m['declared_xy_mm'][1]:.1f})): the diagnosed move")


def leave_out(signal, channels):
    """`signal` with the core's channel_left_out set on `channels` (the core treats them as without an onset)."""
    from dataclasses import replace

    return replace(signal, channel_left_out=[int(c in channels) for c in range(len(signal.channel_left_out))])


def reference_kept_why(choice: dict) -> str:
    """Why retrain keeps the reference model (bond_choice chose it): the three candidates' MAE on DATA_NEW."""
    return (f"the reference model (trained on DATA_REF as it is; its check flags channel {choice['channel']} and "
            f"places by the three other sensors) places DATA_NEW's drops better ({choice['reference_mae_mm']:.2f} mm) "
            f"than the retrained models with the bond's low-pass and gain ({choice['four_mae_mm']:.2f}) or with the "
            f"channel left out ({choice['left_out_mae_mm']:.2f}): it is the model written; the training data "
            f"with the effects is kept beside it")


def print_summary(result: dict, accepted, rows: dict, name: str, twin: bool, out, choice=None) -> None:
    """retrain's printout: the effects put in, the channels left out, both models' scores on DATA_NEW."""
    print("effects added: " + (", ".join(f"{c.effect}[{c.sensor}]" for c in accepted) or "none"))
    if choice is not None:
        print(f"channel {choice['channel']}'s bond: {name}'s drops placed by the model with its low-pass and gain "
              f"{choice['four_mae_mm']:.2f} mm, with the channel left out {choice['left_out_mae_mm']:.2f} mm "
              f"(cross-fitted {choice['cross_fitted_mae_mm']:.2f}): " +
              {"left_out": "the channel is left out (three-sensor position and class), flagged",
               "four": "the four-channel model is kept",
               "reference": "the REFERENCE MODEL IS KEPT"}[choice["chosen"]])
        if choice["chosen"] == "reference":
            print(f"kept the reference model: {reference_kept_why(choice)}")
    for u in result.get("unabsorbed_channels", []):
        if choice is not None and choice["channel"] == u["sensor"]:
            continue   # its bond was put in and the choice above decided
        print(f"channel {u['sensor']}: a change the models cannot absorb (its timing asks for a move of "
              f"{u['params']['offset_mm']:.0f} mm, more than a re-glued disc's {u['max_move_mm']:.0f} mm): the model "
              f"leaves it out (three-sensor position and class), flagged")
    print(f"energy class and position from {'the twin (site map)' if twin else 'the forests'}")
    print(f"{'on ' + name:<18} {'MAE mm':>7} {'inner':>6} {'phys MAE':>8} {'class acc':>9} "
          f"{'within 1u':>9} {'2u':>5}")
    for k, v in rows.items():
        print(f"{k:<18} {v['mae_mm']:7.2f} {v['inner_mae_mm']:6.2f} {v['physics_mae_mm']:8.2f} "
              f"{v['energy_class_accuracy']:9.3f} {_share(v['within_1u']):>9} {_share(v['within_2u']):>5}")
    if any(not math.isfinite(v["within_1u"]) for v in rows.values()):
        print("  (within 1u / 2u '-': the model reports no uncertainty for these drops: no site map, or every drop "
              "placed by three sensors)")
    print(f"model written to {out}")


def _share(x: float) -> str:
    return f"{x:.2f}" if math.isfinite(x) else "-"


# The retrained model is called worse when its MAE on DATA_NEW exceeds the baseline model's by this factor.
WORSE_FACTOR = 1.1


def worse_than_baseline(rows: dict, accepted, name: str) -> str | None:
    """A warning when the retrained model places DATA_NEW's drops clearly worse than the baseline model (both
    scored on its own labels): the diagnosed effects, as sized, do not describe the session."""
    base, new = rows.get("baseline model"), rows.get("retrained model")
    if not base or not new or not new["mae_mm"] > WORSE_FACTOR * base["mae_mm"]:
        return None
    effects = ", ".join(f"{c.effect}[{c.sensor}]" for c in accepted) or "none"
    return (f"WARNING: the retrained model places {name}'s drops worse than the baseline model ({new['mae_mm']:.2f} "
            f"mm against {base['mae_mm']:.2f}): the effects added ({effects}) do not describe this session as "
            f"sized (retrain.json holds their sizes); keep the baseline model")


def twin_params(args, site):
    """The twin's SimParams for the training data: --twin's CAL.json, else the site map's own (its source), else
    None."""
    from ..data import read_json
    from ..errors import ConfigError
    from ..sim import SimParams

    if args.twin:
        cal = read_json(args.twin)
        if "sim_params" not in cal:
            raise ConfigError(f"{args.twin} [sim_params]: missing key (a CAL.json from `impactsense calibrate`)")
        return SimParams.from_dict(cal["sim_params"], args.twin)
    raw = (site.source or {}).get("sim_params") if site is not None else None
    return SimParams.from_dict(raw) if raw else None


def twin_model(args, base, data, details, accepted, settings, exclude, site, out: Path) -> dict:
    """A model trained on DATA_REF's declared drops simulated by the corrected twin (the accepted effects, a
    debonded channel's as fit_bond sized them); its score on DATA_NEW."""
    from ..loop import (channel_delays, effect_dicts, size_plate_change, twin_move_positions, twin_training_session,
                        weak_channel)
    from ..workflow import train

    params = twin_params(args, None)
    # a plate speed change: its E by the twin's own scan at DATA_NEW's drops, picked as diagnose picked them
    accepted = size_plate_change(params, data, accepted, (details["ref"].probe or {}).get("picker"), args.seed,
                                 base=base)
    sess = twin_training_session(base, params, effect_dicts(accepted), out.resolve() / "twin-training-data",
                                 details["ref"].slowness_us_per_mm, args.seed, moved_rig=args.moved_rig,
                                 new_positions=twin_move_positions(base, effect_dicts(accepted)))
    model, _ = carry_delays(train(sess, None, args.test_fraction, args.seed, exclude, settings=settings,
                                  site_map=site), channel_delays(accepted))
    if model.twin_fit is not None:   # as the retrained model: the debonded channel is the twin's weak one
        model.twin_fit.weak_channel = weak_channel(accepted)
    model.save(out / "twin-model")
    return score(data, model)


def score(session, model) -> dict:
    """A model on every drop of `session`: position MAE (whole plate, inner region), physics MAE, class
    accuracy, and the share of the reported positions' errors within 1x and 2x the reported uncertainty
    (NaN without a site map: the model reports none)."""
    import numpy as np

    from ..workflow import evaluate

    rows = np.arange(len(session))
    rep = evaluate(session, model, rows)
    pred = model.predict(model.featurize(session.adc))
    err = np.linalg.norm(pred["xy_mm"] - session.xy_mm, axis=1)
    u = pred["uncertainty_mm"]
    ok = np.isfinite(err) & np.isfinite(u)
    within = {f"within_{k}u": float(np.mean(err[ok] <= k * u[ok])) if ok.any() else float("nan") for k in (1, 2)}
    return {"n": rep["n"], "mae_mm": rep["all"]["mae_mm"], "inner_mae_mm": rep["inner"]["mae_mm"],
            "rmse_mm": rep["all"]["rmse_mm"], "physics_mae_mm": rep["physics"]["all"]["mae_mm"],
            "energy_class_accuracy": rep["energy_class_accuracy"], "position_source": rep["position_source"],
            "median_uncertainty_mm": float(np.median(u[ok])) if ok.any() else float("nan"), **within}
