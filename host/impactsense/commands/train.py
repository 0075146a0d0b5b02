"""impactsense train DATA --out MODEL_DIR"""

from __future__ import annotations

from ..record_window import warn_if_short

ORDER = 20


def register(sub) -> None:
    p = sub.add_parser("train", help="train the localisation forests and the energy classifier on a session",
                       description="Fits the physics localiser (group velocity, channel delays) and the "
                                   "random forests on a session's training cases; writes the models and a "
                                   "JSON model card.")
    p.add_argument("data", help="session folder (or 'bundled')")
    p.add_argument("--out", required=True, help="model folder to write")
    p.add_argument("--force", action="store_true", help="write into a folder that holds other files (kept)")
    p.add_argument("--test-fraction", type=float, default=0.2,
                   help="fraction of cases held out for evaluate (0 trains on everything; default 0.2)")
    p.add_argument("--seed", type=int, default=0, help="split and forest seed (default 0)")
    p.add_argument("--trees", type=int, default=100, help="trees per forest (default 100)")
    p.add_argument("--site-map", default="auto", metavar="auto|none|site-map.npz",
                   help="the twin's site map (`impactsense sitemap`); auto = for a virtual session made by "
                        "`simulate-dataset --calibration` its calibrated twin's (built once, cached in the "
                        "folder), else with --calibration that twin's (built once, cached beside CAL.json), "
                        "else the bundled twin's when the rig is the bundled rig, else none")
    p.add_argument("--calibration", default=None, metavar="CAL.json",
                   help="this rig's calibrated twin (`impactsense calibrate DATA --out CAL.json`): with "
                        "--site-map auto the measured-trained model reads its site map (position and energy "
                        "class from the twin's match) when the training drops' out-of-fold figures say it "
                        "beats the forests and the measured classifier, its class alone on the model's own "
                        "position when only the class gains; the model card's twin_choice records them")
    p.add_argument("--exclude", default=None,
                   help="comma-separated recording ids to leave out (e.g. calibration drops), or a CAL.json")
    p.set_defaults(func=run)


def parse_exclude(text):
    import numpy as np

    from ..data import read_json

    from ..errors import ConfigError

    if not text:
        return None
    if text.endswith(".json"):
        from ..errors import DataError

        cal = read_json(text)
        # a CAL.json of `impactsense calibrate` names its drops' recordings in exclude_recording_ids (its
        # "drops" entry is the drops' table); a plain {"drops": [ids]} file is read as before
        key = next((k for k in ("exclude_recording_ids", "drops", "calibration_drops") if k in cal), "drops")
        ids = cal.get(key) or []
        if not isinstance(ids, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in ids):
            raise DataError(text, key, "must be a list of recording ids (integers)")
        if not all(abs(v) < 2 ** 62 for v in ids):
            raise DataError(text, key, "recording id out of range")
        return np.asarray(ids, np.int64)
    try:
        return np.asarray([int(v) for v in text.split(",") if v.strip()], np.int64)
    except (ValueError, OverflowError):
        raise ConfigError(f"--exclude: {text!r} is not a list of recording ids") from None


def print_travel_refit(fits: dict) -> dict:
    """Prints, per pick set, the travel model read from the calibration drops against its prior, the twin's
    (calibration_drops.map_travel_refit: what the drops determine moves, the rest stays); returns `fits`."""
    refit = fits.get("travel_refit_on_calibration_drops") or {}
    for name, r in refit.items():
        p, sd = r["prior"], r["posterior_sd"]
        a = (r["travel_metric"][0] - r["travel_metric"][2]) / 2
        print(f"{name} picks' travel model from the calibration drops (the twin's as prior): "
              f"v {r['velocity_mm_per_us']:.3f} mm/us (twin {p['velocity_mm_per_us']:.3f}), metric a {a:+.3f} +- "
              f"{sd['metric_a']:.3f} (twin {p['metric_a']:+.3f} +- {p['sd_metric']:.3f}), delays "
              f"{', '.join(f'{d:+.1f}' for d in r['delays_us'][1:])} us +- {sd['delay_1_us']:.1f} (prior sd "
              f"{p['sd_delay_us']:.1f}); picks scatter {r['pick_sd_us']:.1f} us between repetitions")
    return fits


def print_choices(card: dict) -> None:
    """What the training drops chose for the model (its card): the forests' correction scale, the edge correction,
    the energy class's kind."""
    if "correction_scale" in card:
        c = card["correction_scale"]
        print(f"forests' correction of the physics position x {c['scale']:g} (training drops' out-of-fold MAE "
              f"{c['out_of_fold_mae_mm'][c['scales'].index(c['scale'])]:.2f} mm; whole {c['out_of_fold_mae_mm'][-1]:.2f})")
    if "edge_travel_chosen" in card:
        print("edge correction of the arrival times (training drops' physics positions): "
              f"{'kept, three more position members' if card['edge_travel_chosen'] else 'not kept'}")
    choice = (card.get("channel_check") or {}).get("three_sensor_choice") or []
    if any("four_channel_mae_mm" in r for r in choice):
        keep = card["channel_check"]["three_sensor_position"]
        print("a flagged channel's drop placed by (its training drops debonded, out of fold, MAE three-sensor / four "
              "channels): " + ", ".join(f"ch{c} {r['three_sensor_mae_mm']:.1f}/{r['four_channel_mae_mm']:.1f} mm "
                                        f"{'three' if keep[c] else 'FOUR'}" for c, r in enumerate(choice)
                                        if "four_channel_mae_mm" in r))
    energy = card.get("energy_class_choice")
    if energy:
        print(f"energy class: {'linear estimate of log m g h' if energy['use_linear'] else 'classifier forest'} "
              f"(training drops, out of fold: linear {energy['linear_class_accuracy']:.3f} / forest "
              f"{energy['forest_class_accuracy']:.3f})")


def run(args) -> int:
    from ..data import load_session
    from ..errors import ConfigError
    from ..models import ForestSettings
    from ..workflow import train

    if not 0.0 <= args.test_fraction < 1.0:
        raise ConfigError(f"--test-fraction must be in [0, 1), got {args.test_fraction}")
    from ..checks import exclude_rows
    from ..outputs import check_output_folder

    check_output_folder(args.out, args.force)
    session = warn_if_short(load_session(args.data))
    from ..sitemap import resolve_site_map

    from ..chain import adapt, rig_calibration_drops, session_calibration, start_calibration_twins
    from ..chain import site_map as calibrated_site_map

    cal = session_calibration(session)   # a virtual session made by simulate-dataset --calibration
    cal_twins = start_calibration_twins(cal, args.seed) if cal is not None else None
    measured_twin = False
    if cal is not None and args.site_map in (None, "auto"):
        site = calibrated_site_map(session, cal)
    elif cal is None and args.calibration and args.site_map in (None, "auto"):
        from ..chain import measured_site_map

        print(f"the calibrated twin of {args.calibration}: its site map (cached beside it)")
        site = measured_site_map(session, args.calibration)
        measured_twin = True
    else:
        site = resolve_site_map(args.site_map, session.rig)
    settings = ForestSettings(n_estimators=args.trees, seed=args.seed)
    exclude = exclude_rows(parse_exclude(args.exclude), session, "--exclude")
    rig_drops = rig_calibration_drops(cal) if cal is not None else None   # they choose the onset threshold
    model, split = train(session, None if cal else args.out, args.test_fraction, args.seed,
                         exclude, settings, site_map=site, force=args.force, choose_twin=measured_twin,
                         choose_class=cal is None, rig_drops=rig_drops)
    choice = model.card.get("twin_choice")
    if choice:
        kept = "kept" if choice["use_twin"] else "kept for the class" if choice.get("use_twin_class") else "not kept"
        print(f"twin's site map {kept} (training drops, out of fold): MAE {choice['twin_mae_mm']:.2f} mm with it / "
              f"{choice.get('reported_mae_mm', choice['forest_mae_mm']):.2f} without, class "
              f"{choice['twin_class_accuracy']:.3f} / {choice['measured_class_accuracy']:.3f}")
        site = model.site_map
    print_choices(model.card)
    if cal is not None:
        print(f"virtual drops of the twin {cal}: fitting the rig's channel delays, gains, group velocity"
              + (" and the twin's fingerprint" if site is not None else "") + " on its calibration drops")
        fits = print_travel_refit(adapt(model, session, cal, args.seed, cal_sim=cal_twins()))
        model.save(args.out, extra_card={"split": split, **fits}, force=args.force)
    sig = model.signal
    print(f"trained on {len(split['train_recordings'])} drops of {session.name}; "
          f"held out {len(split['test_recordings'])} drops")
    print(f"physics localiser: v = {sig.velocity_mm_per_us * 1000:.0f} m/s, channel delays (us) = "
          f"{', '.join(f'{d:+.2f}' for d in sig.rig_delay_us)}")
    q = (sig.travel_metric_xx, sig.travel_metric_xy, sig.travel_metric_yy)
    print(f"onset threshold {sig.onset_threshold_counts:g} counts; travel metric Q = "
          + ("identity (isotropic)" if q == (1.0, 0.0, 1.0) else f"[{q[0]:.3f} {q[1]:+.3f}; {q[1]:+.3f} {q[2]:.3f}]"))
    alpha = float(getattr(sig, "dispersion_exponent", 0.0))
    print("dispersion: " + (f"slowness x (f / {sig.dispersion_ref_hz / 1000:.1f} kHz)^-{alpha:.3f} per channel, f the "
                            "picked cycle's frequency" if alpha else "none (one velocity)")
          + f"; localiser starts {int(getattr(sig, 'localiser_starts', 1))}")
    band = float(getattr(sig, "band_velocity_mm_per_us", 0.0)) > 0 and float(getattr(sig, "band_pick_hz", 0.0)) > 0
    slope = float(getattr(sig, "band_slowness_per_decade", 0.0))
    loud = (f" (slowness {slope:+.4f} us/mm per decade of summed energy from 10^{sig.band_log_energy_ref:.2f} counts^2 s)"
            if slope else "")
    floor = float(getattr(sig, "band_noise_counts", 0.0))
    loud += f", noise floor 3 x {floor:.2f} counts (the training drops')" if floor > 0 else ""
    print("band picks: " + (f"at {sig.band_pick_hz / 1000:.1f} kHz, {sig.band_velocity_mm_per_us:.3f} mm/us{loud}; the "
                            "physics position is the mean of both localisers'" if band else "off (threshold picks only)"))
    linear = (model.card.get("energy_class_choice") or {}).get("use_linear")
    print(f"energy class threshold: {model.energy_threshold_j * 1000:.3f} mJ (75th percentile), from "
          + ("the twin's height estimate (site map)" if site is not None else
             "a linear estimate of log m g h (summed energies, a cubic in position)" if linear else
             "the channels' energies and first peaks"))
    boundary = model.card.get("energy_class_boundary_j")
    if boundary:
        print(f"energy class boundary: {boundary * 1000:.3f} mJ, in the calibrated session's gap between drop heights")
    print(f"wrote {args.out}")
    return 0
