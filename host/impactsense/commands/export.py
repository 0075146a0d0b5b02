"""`impactsense export MODEL_DIR --out models/`: the forests as C for the firmware (and tables for the
emulator).

The board samples 4 x 50 kHz (the SAADC's ceiling), not the lab logger's 100 kHz. A model trained at 100 kHz
(`impactsense train`) is therefore first trained again, with the same split and forest settings, on the drops
as the board captures them (resampled, SAADC scan delays, cut by the firmware app); that model is written to
OUT/board-model and exported; a model whose energy class reads the twin's site map gets the site map as the
board sees it (the twin's drops taken the same way; a few minutes, cached as OUT/board-site-map.npz).
A sim-trained model (`impactsense demo --zero-shot`'s model-sim) is made again from its virtual drops and
then fitted on its calibration drops, both as the board captures them, and scored on its measured test split.
`--rate native` exports MODEL_DIR's forests as they are. The held-out drops
are then run through the emulated board (the firmware app with the exported tables) and scored.
All of it is written into a folder next to OUT and moved in only when every step has succeeded: a failure
midway leaves OUT (an earlier board-model, C sources, tables) as it was (impactsense's one output writer:
a folder holding files impactsense did not write is refused unless --force, and never loses them)."""

ORDER = 60


def register(sub):
    p = sub.add_parser("export", help="export trained forests to C for the firmware (float32, per-tree)",
                       description=__doc__)
    p.add_argument("model_dir", help="folder written by `impactsense train` (model_card.json + forest .npz files)")
    p.add_argument("--out", default="models", help="output folder (default: models/)")
    from ..export import MODELS_FLASH_BUDGET, TWIN_MAX_TREES

    p.add_argument("--trees", default="auto",
                   help="trees per coordinate forest: auto (default: the smallest within 0.2 mm mean distance "
                        "of the best on the held-out drops, within the flash the firmware's code leaves of 256 KB "
                        f"({MODELS_FLASH_BUDGET // 1024} KB) and, for a twin "
                        f"model, the per-event cycle budget's {TWIN_MAX_TREES} trees), all, or N; a board model "
                        "whose position correction is boosted trees (its card's board_forests) exports all of them")
    p.add_argument("--rate", default="50000",
                   help="board sample rate per channel (Hz) to train the shipped models at (default 50000); "
                        "'native' exports MODEL_DIR's forests unchanged")
    p.add_argument("--no-m2cgen", action="store_true", help="write only the node tables")
    p.add_argument("--force", action="store_true", help="write into a folder that holds other files (kept)")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    from pathlib import Path

    from ..export_check import within_event_budget
    from ..errors import ConfigError
    from ..export import staged_output

    from ..outputs import check_output_folder

    out = Path(args.out)
    card = _card(Path(args.model_dir))
    check_output_folder(out, args.force)
    rate = None
    if args.rate != "native":
        try:
            rate = int(args.rate)
        except ValueError:
            raise ConfigError(f"--rate: {args.rate!r} is neither a rate in Hz nor 'native'") from None
        if rate <= 0:
            raise ConfigError(f"--rate: {args.rate!r} is not a positive rate in Hz")
    if args.trees not in ("auto", "all") and not (args.trees.isdigit() and int(args.trees) > 0):
        raise ConfigError(f"--trees: {args.trees!r} is neither auto, all nor a positive number of trees")
    # Everything (OUT/board-model, the C sources, the tables, export.json) is written into a folder next to
    # OUT and moved into OUT only when all of it is done: a failure midway leaves OUT as it was. The board's
    # site map is a cache (written whole, keyed by its source map and rate) and stays in OUT.
    left_out = [c for c, v in enumerate((card.get("signal") or {}).get("channel_left_out") or []) if v]
    with staged_output(out, args.force) as stage:
        s, card, model_dir = _export(args, card, rate, stage, out)
    print(f"exported {s['trees']} trees, {s['nodes']} nodes, {s['table_bytes_total'] / 1024:.1f} KB of tables "
          f"(budget {s['flash_budget_bytes'] / 1024:.0f} KB, what the firmware's code leaves of 256 KB: "
          f"{'ok' if s['within_budget'] else 'OVER'}) -> {out}")
    front = s.get("board_front_end")
    if front:
        print(f"the board's models assume its front end (rig.json board_front_end): a {front['anti_alias_poles']}-pole "
              f"Butterworth low-pass at {front['anti_alias_hz'] / 1000:g} kHz before each ADC input: build it "
              "(README \"Hardware\")")
    acc = s.get("board_held_out")
    if acc is not None:
        which = "the measured test split" if "zero_shot" in card else "held-out drops"
        print(f"{which} on the emulated board (4 x {acc['fs_hz'] / 1000:g} kHz, firmware app, exported "
              f"tables): {acc['reported']}/{acc['n']} reported, MAE {acc['all']['mae_mm']:.2f} mm "
              f"(inner {acc['inner']['mae_mm']:.2f} mm), mean distance {acc['all']['euclid_mm']:.2f} mm, "
              f"energy class accuracy {acc['energy_class_accuracy']:.3f}")
        _print_versus_host(acc)
    if "twin" not in card and "three_channel_class" not in card:
        print("a drop with one channel without an onset (dead, disconnected): the board reports it as not valid "
              "(this model has no three-channel classes: train it again)")
    if left_out:
        board_left = [c for c, v in enumerate((card.get("signal") or {}).get("channel_left_out") or []) if v]
        how = ("the twin's match on the other three channels" if "twin" in card else
               "the physics three-sensor position and the three-channel class" if "three_channel_class" in card
               else "no report (no three-channel classes)")
        print(f"channel(s) {left_out} left out by retrain (a change the models cannot absorb): "
              + (f"the board leaves {board_left} out too ({how}; the report names the channel)" if board_left
                 else "the board's models keep all four channels"))
    est = s.get("event_instructions_estimate")
    # the flash decides the exit status (the image would not link); the event estimate is a bound, said beside it
    print(json.dumps({"trees": s["trees"], "table_bytes_total": s["table_bytes_total"],
                      "within_flash_budget": s["within_budget"],
                      "within_event_budget": within_event_budget(est)}))
    return 0 if s["within_budget"] else 1


def _export(args, card, rate, stage, out):
    """The export written into `stage` (its final place: `out`): (summary, model card, model folder)."""
    from pathlib import Path

    from ..export import export_models, needs_board_refit

    model_dir = Path(args.model_dir)
    if needs_board_refit(card, rate):
        from ..board.models import BOARD_SITE_MAP, retrain_for_board

        if (out / BOARD_SITE_MAP).is_file():    # the cache goes along into the new OUT
            import shutil

            shutil.copy2(out / BOARD_SITE_MAP, stage / BOARD_SITE_MAP)
        model_dir = retrain_for_board(model_dir, stage / "board-model", rate, site_map_cache=stage / BOARD_SITE_MAP)
        card = _card(model_dir)
        how = ("sim-trained: the virtual drops, then the calibration drops' fits" if "zero_shot" in card
               else "same split")
        print(f"trained again on the board's captures at 4 x {rate / 1000:g} kHz ({how}, "
              f"{card['forest']['n_estimators']} trees) -> {out / 'board-model'}")
    X = xy = phys = twin = None
    if args.trees == "auto":
        X, phys, xy, twin = _held_out(model_dir)
    s = export_models(model_dir, stage, trees=args.trees, X_eval=X, xy_eval=xy, phys_eval=phys,
                      write_m2cgen=not args.no_m2cgen, twin_eval=twin, into_stage=True)
    for row in s["tree_sweep"]:
        forest = f" (the forests' {row['forest_mean_distance_mm']:.2f} mm)" if "forest_mean_distance_mm" in row else ""
        cost = f", ~{row['instructions']:,} instructions an event" if "instructions" in row else ""
        print(f"  {row['trees']:>4} trees: mean distance {row['mean_distance_mm']:.2f} mm{forest}, "
              f"{row['table_bytes'] / 1024:.1f} KB of tables{cost}{'' if row['within_budgets'] else ', over a budget'}")
    est = s.get("event_instructions_estimate")
    if est is not None:
        from ..export_check import estimate_total, flagged_total, verdict_text

        drops, total = est.get("drops"), estimate_total(est)
        split = card.get("zero_shot") or card.get("split") or {}
        where = {"export_dir": out, "data": split.get("data_path") or card.get("data")}   # for the qemu command
        print(f"per-event cost on the board, estimated: {total:,} instructions ({verdict_text(est, **where)}); "
              f"each part at its worst (board.cost) {est['total']:,}: "
              f"features and report {est['base']:,}, band picks {est['band']:,}, localiser {est['localiser']:,}, "
              f"forests {est['models']:,}{', channel check ' + format(est['check'], ',') if est.get('check') else ''}"
              f"{', twin match ' + format(est['twin'], ',') if est.get('twin') else ''}")
        if drops:
            print(f"  the model's {drops['drops']} drops, each priced whole (board.drop_cost): the slowest "
                  f"{drops['slowest']:,} (row {drops['row']})"
                  + (f", flagged {drops['flagged']:,}" if "flagged" in drops else "")
                  + ("; a drop models a mains hum (or redoes a channel): the larger of the two is used"
                     if drops.get("hum") or drops.get("beyond_base") else "; it is used"))
        if "flagged" in est:
            which = ("a drop whose match the twin doubts (its cued search)" if est.get("twin") else
                     "an event the channel check flags (the localiser without the channel, the three-channel class)")
            print(f"  {which}: {flagged_total(est):,} instructions ({verdict_text(est, flagged=True, **where)})")
    if isinstance(s.get("channel_check"), str):
        print(s["channel_check"])
    host = Path(args.model_dir)
    refit = model_dir != host
    trees = s.get("trees")
    acc = _board_accuracy(model_dir, card, stage, host if refit else None, _card(host) if refit else None,
                          int(trees["x"]) if isinstance(trees, dict) else int(trees) if trees else None)
    if acc is not None:
        s["board_held_out"] = acc
        from ..outputs import json_text

        (stage / "export.json").write_text(json_text(s))
    return s, card, model_dir


def _card(model_dir):
    from pathlib import Path

    from ..data import MODEL_CARD_MISSING, read_json

    return read_json(Path(model_dir) / "model_card.json", MODEL_CARD_MISSING)


def _board_accuracy(model_dir, card, out, host_dir=None, host_card=None, trees=None):
    """The exported tables on the emulated board over the held-out drops (None without held-out drops). With
    host_dir (the model the board's was trained again from, its card host_card), also the host model's positions
    of the same drops at the rig's rate, both scored on the drops both place ("versus_host": board.gap.compare,
    and "board_lacks": what the host's model uses that the board's does not run)."""
    import numpy as np

    from ..export import firmware_models
    from ..board.scores import board_accuracy, board_reports, held_out_rows, report_positions

    s, rows = held_out_rows(card)
    if rows is None or rows.size == 0 or "energy_threshold_j" not in card:
        return None
    models, signal = firmware_models(out)
    held = s.subset(rows)
    fs = int(card.get("board_fs_hz") or 50000)
    got = board_reports(held, models, signal, fs)
    acc = board_accuracy(held, models, signal, float(card["energy_threshold_j"]), fs, reports=got)
    if host_dir is not None:
        from ..board.gap import board_lacks, compare, host_positions

        from ..errors import DataError

        try:
            host_xy = host_positions(host_dir, held, np.arange(len(held)))
        except DataError as exc:   # a model the host cannot run as it is (it still exports): no comparison
            acc["versus_host"] = {"scored": 0, "note": f"the host model's positions: {exc}"}
        else:
            acc["versus_host"] = compare(held.xy_mm, host_xy, report_positions(got, len(held)))
        acc["board_lacks"] = board_lacks(host_card or {}, card, trees)
    return acc


def _print_versus_host(acc: dict) -> None:
    """The board's expected accuracy against the host's (board.gap), and what the board lacks when it is worse."""
    import sys

    vs = acc.get("versus_host") or {}
    if not vs.get("scored"):
        print(f"the host model's MAE on these drops: not available ({vs.get('note', 'no drop placed by both')})",
              file=sys.stderr)
        return
    b, h, ratio = vs["board"]["mae_mm"], vs["host"]["mae_mm"], vs["ratio_mae"]
    print(f"expected accuracy, the same {vs['scored']} held-out drops (both placed): board MAE {b:.2f} mm, host "
          f"{h:.2f} mm: the board is {ratio:.2f}x the host's (target <= {vs['target_ratio']:g}x: "
          f"{'met' if vs['within_target'] else 'MISSED'})")
    if not vs["within_target"]:
        lacks = acc.get("board_lacks") or ["nothing the card names (the board's 4 x 50 kHz sampling)"]
        print(f"WARNING: the board's model places drops {ratio:.1f}x worse than the host's; it runs only what the "
              "board's rate and event budget allow and lacks:\n" + "\n".join(f"  - {x}" for x in lacks),
              file=sys.stderr)


def _held_out(model_dir):
    """Feature vectors, physics positions, true positions and the twin's features (twin features, usable
    masks) of the model card's held-out drops (usable rows), on which --trees auto chooses. A sim-trained
    model's are its calibration drops, the only measured drops it may learn from (its measured test split
    only scores it)."""
    import numpy as np

    from ..board.scores import held_out_features
    from ..sitemap import twin_features

    card = _card(model_dir)
    if "zero_shot" in card:
        card["zero_shot"] = {**card["zero_shot"], "test_recordings": card["zero_shot"]["calibration_recordings"]}
    if any((card.get("signal") or {}).get("channel_left_out") or []):
        # a channel left out: the forests never run (no drop has all four onsets); their trees are chosen as the
        # four-channel model's, on the drops with every channel (the tables' size and cost stay bounded)
        card["signal"] = {**card["signal"], "channel_left_out": [0] * len(card["signal"]["channel_left_out"])}
    f, xy, _ = held_out_features(card)
    use = f.usable
    return f.vector[use], f.phys_xy_mm[use], xy[use], twin_features(f.take(np.flatnonzero(use)))
