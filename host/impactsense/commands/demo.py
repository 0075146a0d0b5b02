"""impactsense demo [--data DATA]: the main job on the bundled data or on any session folder."""

from __future__ import annotations

from ..seed import SEED_ROWS

ORDER = 5

def register(sub) -> None:
    p = sub.add_parser("demo", help="train on 80 %% of a session's cases (default the bundled session-1), evaluate "
                                    "on 20 %%, compare with the seed",
                       description="Trains on 80 % of the cases of a session (default the bundled session-1; any "
                                   "rig's session folder with --data), evaluates on the held-out 20 %, with the "
                                   "bundled data also scores session-2 with that model, prints our table beside "
                                   "the seed's Tables 7-9 and writes plots and JSON.")
    p.add_argument("--data", default="bundled", help="session folder of any rig (default: bundled session-1)")
    p.add_argument("--out", default="impactsense-demo", help="output folder (default ./impactsense-demo)")
    p.add_argument("--force", action="store_true", help="write into a folder that holds other files (kept)")
    p.add_argument("--seed", type=int, default=0, help="seed of the case split and the forests (default 0)")
    p.add_argument("--zero-shot", action="store_true",
                   help="also the seed's central experiment: calibrate the twin on four drops, train on N "
                        "virtual drops only, test on the measured split (Tables 7-9: sim- vs measured-trained)")
    p.add_argument("--calibration", default=None,
                   help="with --zero-shot: an existing CAL.json (default: OUT/CAL.json, calibrated if missing)")
    p.add_argument("--virtual", type=int, default=490, help="with --zero-shot: virtual drops (default 490)")
    from .simulate import add_scheduler_option

    add_scheduler_option(p)
    p.set_defaults(func=run)


def is_bundled(session) -> bool:
    """Whether `session` is the bundled session-1, the session the seed paper's Tables 7-9 are of."""
    from ..data import bundled_session_path

    return session.path.resolve() == bundled_session_path().resolve()


def comparison_table(ours: dict, seed_rows: bool = True) -> str:
    """Our rows, after the seed paper's (its Tables 7-9 are the bundled rig's: seed_rows False elsewhere)."""
    lines = [f"{'':54s} {'R2':>6s} {'RMSE mm':>8s} {'MAE mm':>7s} {'class acc':>9s}"]
    for name, (r2, rmse, mae, acc) in SEED_ROWS.items():
        if seed_rows and name.startswith("measured"):
            lines.append(f"{'seed paper, ' + name:54s} {r2:6.2f} {rmse:8.1f} {mae:7.1f} {acc:9.2f}")
    for name, (m, acc) in ours.items():
        lines.append(f"{'impactsense, ' + name:54s} {m['r2']:6.3f} {m['rmse_mm']:8.2f} {m['mae_mm']:7.2f} "
                     f"{acc if isinstance(acc, str) else format(acc, '9.2f'):>9s}")
    return "\n".join(lines)


def run(args) -> int:
    import time

    from ..data import load_session
    from ..plots import evaluation_plots
    from ..workflow import evaluate, train, write_json

    t0 = time.time()
    if args.zero_shot and args.calibration:   # a bad CAL.json fails before anything is trained or written
        from ..zeroshot import read_calibration

        read_calibration(args.calibration)
    from ..outputs import adopt, check_output_folder

    out = check_output_folder(args.out, args.force)
    out.mkdir(parents=True, exist_ok=True)
    session = load_session(args.data)
    print(f"training on 80 % of the cases of {session.name} ({len(session)} drops, {session.n_cases} cases) ...")
    from ..sitemap import resolve_site_map

    site = resolve_site_map("auto", session.rig)
    if site is not None:
        print(f"position and energy class from the twin's site map ({site.nx} x {site.ny} points, "
              f"{site.step_mm:g} mm, drop height {site.ref_height_mm:g} mm)")
    # as `impactsense train DATA` does: without a site map the energy class the training drops choose
    model, split = train(session, out / "model", 0.2, args.seed, site_map=site, choose_class=site is None)
    report = evaluate(session, model)
    write_json(report, out / f"evaluate-{session.name}.json")
    evaluation_plots(report, session.rig, out / "plots")
    acc = report["energy_class_accuracy"]
    # The reported position: the twin's match with a site map, else the forests' (models.ImpactModel.predict).
    reported = "twin's matched position" if report.get("position_source") == "twin" else "forests' position"
    ours = {
        f"{reported}, whole plate": (report["all"], acc),
        f"{reported}, inner region": (report["inner"], acc),
    }
    if report.get("position_source") == "twin":   # the forests' position the twin's match started from
        ours.update({"forests' position (the twin's start), whole plate": (report["forest"]["all"], "-"),
                     "forests' position, inner region": (report["forest"]["inner"], "-")})
    ours |= {
        "physics localiser only, whole plate": (report["physics"]["all"], "-"),
        "physics localiser only, inner region": (report["physics"]["inner"], "-"),
    }
    print(f"\n{session.name}, held-out 20 % of cases: n = {report['n']} "
          f"(Eq. 35 accepted {report['accepted']}, rejected {report['rejected']})")
    print(comparison_table(ours, seed_rows=is_bundled(session)))
    try:
        other = load_session("bundled:session-2") if args.data == "bundled" else None
    except Exception:  # the second bundled session is optional
        other = None
    if other is not None:
        rep2 = evaluate(other, model)
        write_json(rep2, out / "evaluate-session-2.json")
        print(f"\nsession-2 (a later day) with the session-1 model, all {rep2['n']} drops:")
        rows2 = {"whole plate": (rep2["all"], rep2["energy_class_accuracy"]),
                 "inner region": (rep2["inner"], rep2["energy_class_accuracy"])}
        if rep2.get("position_source") == "twin":
            rows2["forests' position, whole plate"] = (rep2["forest"]["all"], "-")
        print(comparison_table(rows2))
        print("  (run `impactsense diagnose` to find what changed)")
    if args.zero_shot:
        run_zero_shot_part(args, session, out)
    adopt(out, ["model", "plots", "evaluate-session-1.json", "evaluate-session-2.json",
                *(["zero-shot"] if args.zero_shot else []),
                *(["CAL.json"] if args.zero_shot and not args.calibration else [])])
    print(f"\nwrote {out}/ (model/, plots/, evaluate-*.json) in {time.time() - t0:.1f} s")
    return 0


def run_zero_shot_part(args, session, out) -> None:
    from pathlib import Path

    from ..cli import main as cli_main
    from ..errors import ImpactSenseError
    from ..zeroshot import run_zero_shot, zero_shot_table

    cal = Path(args.calibration) if args.calibration else out / "CAL.json"
    if not cal.is_file():
        if args.calibration:
            raise ImpactSenseError(f"{cal}: calibration file not found")
        print(f"\ncalibrating the twin on four drops of {session.name} -> {cal} ...")
        if cli_main(["calibrate", str(session.path), "--out", str(cal), "--seed", str(args.seed)]) != 0:
            raise ImpactSenseError("calibration failed")
    print(f"\nzero-shot: {args.virtual} virtual drops from {cal}, trained on them only ...")
    res = run_zero_shot(session, cal, out / "zero-shot", n_virtual=args.virtual, seed=args.seed)
    print(f"measured test split: {len(res['test_recordings'])} drops (the calibration drops "
          f"{len(res['calibration_recordings'])} recordings excluded); channel delays from the calibration "
          f"drops (us): {', '.join(f'{d:+.2f}' for d in res['channel_delay_us_from_calibration_drops'])}")
    print(zero_shot_table(res, seed_rows=is_bundled(session)))
