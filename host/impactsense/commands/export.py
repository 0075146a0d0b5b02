"""`impactsense export MODEL_DIR --out models/`: the forests as C for the firmware (and tables for the
emulator)."""

ORDER = 60


def register(sub):
    p = sub.add_parser("export", help="export trained forests to C for the firmware (float32, per-tree)",
                       description=__doc__)
    p.add_argument("model_dir", help="folder written by `impactsense train` (model_card.json + joblib)")
    p.add_argument("--out", default="models", help="output folder (default: models/)")
    p.add_argument("--trees", default="all",
                   help="trees per coordinate forest: all, N, or auto (smallest within 0.2 mm MAE of the "
                        "full forest on the model's held-out drops)")
    p.add_argument("--no-m2cgen", action="store_true", help="write only the node tables")
    p.set_defaults(func=run)


def run(args) -> int:
    import json

    from ..export import export_models

    X = xy = phys = None
    if args.trees == "auto":
        X, phys, xy = _held_out(args.model_dir)
    s = export_models(args.model_dir, args.out, trees=args.trees, X_eval=X, xy_eval=xy, phys_eval=phys,
                      write_m2cgen=not args.no_m2cgen)
    for row in s["tree_sweep"]:
        print(f"  {row['trees']:>4} trees: MAE {row['mae_mm']:.2f} mm, {row['table_bytes'] / 1024:.1f} KB of tables")
    print(f"exported {s['trees']} trees, {s['nodes']} nodes, {s['table_bytes_total'] / 1024:.1f} KB of tables "
          f"(budget 256 KB: {'ok' if s['within_budget'] else 'OVER'}) -> {args.out}")
    print(json.dumps({k: s[k] for k in ('trees', 'table_bytes_total', 'within_budget')}))
    return 0 if s["within_budget"] else 1


def _held_out(model_dir):
    """Feature vectors, physics positions and true positions of the model card's held-out drops."""
    import json
    from pathlib import Path

    import numpy as np

    from ..data import load_session
    from ..pipeline import SignalConfig, featurize

    card = json.loads((Path(model_dir) / "model_card.json").read_text())
    split = card.get("split") or {}
    rows = split.get("test_recordings")
    for key in ("test_recording_ids", "held_out", "held_out_recording_ids", "test_ids", "test_rows"):
        if rows is None and card.get(key):
            rows = card[key]
    data = split.get("data_path") or card.get("data") or card.get("session")
    s = load_session(data if data and Path(str(data)).is_dir() else None)
    rows = np.asarray(rows if rows is not None else np.arange(len(s)), dtype=int)
    signal = card.get("signal") or {}
    board_fs = card.get("board_fs_hz")
    if board_fs and abs(float(board_fs) - s.rig.fs_hz) > 1:
        # A model trained on board captures: evaluate on what the (emulated) board captures.
        from ..link.boardmodel import board_captures

        caps, got, sig = board_captures(s.subset(rows), int(board_fs), signal)
        rows = rows[got]
        f = featurize(caps, sig)
    else:
        f = featurize(s.adc[rows], SignalConfig.from_dict(signal))
    use = f.usable
    return f.vector[use], f.phys_xy_mm[use], s.xy_mm[rows][use]
