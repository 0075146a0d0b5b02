"""impactsense evaluate DATA --model MODEL_DIR --json OUT.json [--plots DIR]"""

from __future__ import annotations

ORDER = 25


def register(sub) -> None:
    p = sub.add_parser("evaluate", help="evaluate a trained model on a session",
                       description="On the model's own session only its held-out drops are used; on any "
                                   "other session every drop.")
    p.add_argument("data", help="session folder (or 'bundled')")
    p.add_argument("--model", required=True, help="model folder from `impactsense train`")
    p.add_argument("--json", dest="json_out", required=True, help="report to write")
    p.add_argument("--plots", default=None, help="folder for predicted-vs-true and error-map plots")
    p.set_defaults(func=run)


def format_table(rows: list[tuple[str, dict, float | None]]) -> str:
    lines = [f"{'':34s} {'R2':>6s} {'RMSE mm':>8s} {'MAE mm':>7s} {'class acc':>9s}"]
    for name, m, acc in rows:
        acc_s = f"{acc:9.2f}" if acc is not None and acc == acc else f"{'-' if acc is not None else '':>9s}"
        lines.append(f"{name:34s} {m['r2']:6.3f} {m['rmse_mm']:8.2f} {m['mae_mm']:7.2f} {acc_s}")
    return "\n".join(lines)


def report_table(report: dict) -> str:
    acc = report["energy_class_accuracy"]
    twin = report.get("position_source") == "twin"
    name = "twin's position (site map)" if twin else "random forest"
    rows = [(f"{name}, whole plate", report["all"], acc), (f"{name}, inner region", report["inner"], acc)]
    if twin:   # the forests' position the twin started from, on the same drops
        rows += [("forests' position, whole plate", report["forest"]["all"], None),
                 ("forests' position, inner region", report["forest"]["inner"], None)]
    return format_table(rows + [
        ("physics localiser, whole plate", report["physics"]["all"], None),
        ("physics localiser, inner region", report["physics"]["inner"], None),
    ])


def flagged_placement(card: dict, channel: int) -> str:
    """How the model places and classifies a drop whose channel the check flags, and why (the card's
    channel_check.three_sensor_choice: the training drops, that channel debonded, placed out of fold by the other
    three sensors and by all four)."""
    check = card.get("channel_check") or {}
    keep = check.get("three_sensor_position") or [True] * 4
    if keep[channel]:
        return "placed and classified from the other three channels"
    why = (check.get("three_sensor_choice") or [None] * 4)[channel]
    measured = ("" if not why else f": its training drops, that channel debonded, placed {why['four_channel_mae_mm']:.1f} "
                f"mm off by all four against {why['three_sensor_mae_mm']:.1f} by the other three, out of fold")
    return ("classified from the other three channels and placed by all four (the card's "
            f"channel_check.three_sensor_choice{measured})")


def run(args) -> int:
    from ..data import load_session
    from ..models import ImpactModel
    from ..plots import evaluation_plots
    from ..workflow import evaluate, write_json

    from ..checks import check_rig

    session = load_session(args.data)
    model = ImpactModel.load(args.model)
    check_rig(model.card, session.rig, f"{args.model}/model_card.json", session.path)
    report = evaluate(session, model)
    write_json(report, args.json_out)
    print(f"{session.name}: {report['scope']}: n = {report['n']}, accepted {report['accepted']}, "
          f"rejected {report['rejected']} (Eq. 35)")
    print(report_table(report))
    if report.get("not_placed"):
        clipped = report.get("not_placed_every_channel_clipped", 0)
        why = (f"; {clipped} of them clipped on every channel with an onset: the twin's site map matches energies "
               f"and none of theirs can be read" if clipped else "")
        print(f"not placed: {report['not_placed']} of {report['n']} drops have no position (the figures above are "
              f"over the other {report['predicted']}){why}")
    unclassed = report["predicted"] - report["classified"]
    if unclassed:
        print(f"energy class: {unclassed} of {report['predicted']} placed drops have none (class acc. is over the "
              f"other {report['classified']}): a channel without an onset, and the model has no site map to classify "
              f"from three channels (`impactsense calibrate DATA --out CAL.json`, then `train --calibration CAL.json`)")
    for c, n in enumerate(report.get("channels_left_out_inconsistent", [])):
        if n:
            print(f"channel {c}: inconsistent with the other three on {n} of {report['n']} drops (a debonded or "
                  f"weak disc?): those drops are {flagged_placement(model.card, c)}, flagged")
    if args.plots:
        for p in evaluation_plots(report, session.rig, args.plots):
            print(f"plot: {p}")
    print(f"wrote {args.json_out}")
    return 0
