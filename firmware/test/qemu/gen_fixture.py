"""Generates the qemu test image's inputs: the exported models (C) and fixture.h with recorded drops at the
board rate and the host's expected values (the natively compiled app's reports, the C++ core's features,
scikit-learn's predictions).

    python gen_fixture.py BUILD_DIR [--data SESSION] [--model-dir MODEL_DIR] [--drops 6] [--trees 12]
                          [--site-map auto|none|FILE] [--site-map-step MM] [--site-map-cache FILE]

--data: the session folder whose drops the image replays (default: the bundled session); its rig.json sets the
board's capture (rate conversion, channels' layout) and the model should be one trained on that rig.
With --rows or --data, drops the board does not report once or the host's models give no answer for
(ImpactModel.predict: no position or class, whichever path the drop takes) are left out (listed in fixture.json's
skipped_rows); on the default session every fixture drop must be reported and answered.

--trees: the localisation forests' trees exported; --energy-trees the energy forest's (default: whole).

Without --model-dir it trains small forests on the firmware's own captures (impactsense.board.models),
with the energy class on the twin's site map as the board sees it (made from --site-map, by default the
bundled twin's map, at --site-map-step, default the map's own 5 mm: a few minutes, cached in
--site-map-cache, default BUILD_DIR/board-site-map.npz).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from impactsense import _link
from impactsense.data import load_session
from impactsense.export import export_models, firmware_models
from impactsense.board.capture import app_config, board_frames, replay_reports, signal_for_board
from impactsense.models import ImpactModel
from impactsense.pipeline import featurize
from impactsense.twin import _slowness_scales   # the localiser's travel-time factors, as the host's twin_match


def c_array(ctype, name, a, fmt):
    a = np.asarray(a)
    dims = "".join(f"[{d}]" for d in a.shape)
    flat = [fmt(v) for v in a.reshape(-1).tolist()]
    rows = [", ".join(flat[i:i + 16]) for i in range(0, len(flat), 16)]
    return f"static const {ctype} {name}{dims} = {{\n  " + ",\n  ".join(rows) + "\n};\n"


def app_defines(cfg: dict) -> str:
    """The native app's acquisition settings that the image's app must share (test_main.cpp fixture_config):
    the rig's ADC rails as the core takes them and, when app_config scaled them to the rig's ADC, the
    trigger's counts."""
    out = f"#define FIX_ADC_MIN {int(cfg['core'].adc_min)}\n#define FIX_ADC_MAX {int(cfg['core'].adc_max)}\n"
    if "threshold_counts" in cfg:
        out += (f"#define FIX_THRESHOLD_COUNTS {float(cfg['threshold_counts'])!r}f\n"
                f"#define FIX_REARM_COUNTS {float(cfg['rearm_counts'])!r}f\n")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("build")
    ap.add_argument("--data", default=None, help="session folder (default: the bundled session)")
    ap.add_argument("--model-dir")
    ap.add_argument("--drops", type=int, default=6)
    ap.add_argument("--rows", default=None, help="the session's rows A:B instead of --drops evenly spaced ones")
    ap.add_argument("--trees", type=int, default=12)
    ap.add_argument("--energy-trees", type=int, default=None, help="the energy forest's trees (default: all)")
    ap.add_argument("--fs", type=int, default=50000)
    ap.add_argument("--site-map", default="auto", help="auto (the bundled twin's), none, or a site map file")
    ap.add_argument("--site-map-step", type=float, default=None, help="board map grid step, mm")
    ap.add_argument("--site-map-cache", default=None, help="board map file (reused when it fits)")
    args = ap.parse_args(argv)
    build = Path(args.build)
    build.mkdir(parents=True, exist_ok=True)
    s = load_session(args.data) if args.data else load_session()
    lenient = bool(args.rows or args.data)   # leave out drops the board or the models cannot take
    model_dir = Path(args.model_dir) if args.model_dir else None
    if model_dir is None:
        from impactsense.board.models import board_site_map, train_board_models
        from impactsense.sitemap import resolve_site_map

        source = resolve_site_map(args.site_map, s.rig)
        board_map = None
        if source is not None:
            board_map = board_site_map(source, s.rig, args.fs, step_mm=args.site_map_step,
                                       cache=Path(args.site_map_cache or build / "board-site-map.npz"))
        model_dir = train_board_models(s, build / "model", n_trees=args.trees, fs_hz=args.fs, site_map=board_map)
    export_models(model_dir, build / "models", trees=args.trees, energy_trees=args.energy_trees)
    model = ImpactModel.load(model_dir)
    boosted = bool((model.card.get("board_forests") or {}).get("use_boosted"))
    for forest in (model.forest_dx, model.forest_dy):  # the exported prefix (a random forest itself); the board's
        if not boosted:                                # boosted trees are exported whole (no prefix is the model)
            forest.estimators_ = forest.estimators_[:args.trees]
    if args.energy_trees and hasattr(model.forest_energy, "estimators_"):   # a linear energy estimate: whole
        model.forest_energy.estimators_ = model.forest_energy.estimators_[:args.energy_trees]
    # The image checks the models' own answer per drop (TableModels::predict: the forests, the twin); the channel
    # check's flags, a run's state, are in the report bodies the native app sent (fix_report_body).
    model.card = {k: v for k, v in model.card.items() if k != "channel_check"}
    fm, signal = firmware_models(build / "models")

    if args.rows:
        a, b = (int(v) for v in args.rows.split(":"))
        rows = np.arange(max(a, 0), min(b, len(s)))
        if rows.size == 0:
            raise SystemExit(f"--rows {args.rows}: no rows of the session in that range (0..{len(s) - 1})")
    else:
        rows = np.linspace(0, len(s) - 1, args.drops).round().astype(int)
    cfg = app_config(s.rig, args.fs, signal, dump_raw=True)
    board_signal = signal_for_board(s.rig, signal, args.fs)

    def replay(rows):
        """The native app on the rows' drops as the board's stream (board_frames: each record continued for the
        app's capture and hold-off, led in when its quiet start is short): report bodies, captures, one report
        per drop?"""
        app = _link.App(cfg, fm)
        frames = board_frames(s.adc[rows], s.rig, app, args.fs, threshold_counts=cfg.get("threshold_counts"))
        reports, captures = replay_reports(app, frames)
        one = np.array([len(r) == 1 for r in reports])
        bodies = [np.frombuffer(_link.report_body(r[0]), dtype=np.uint8) for r in reports if len(r) == 1]
        caps = [c[0] for c in captures if len(c) == 1]
        return frames, bodies, caps, one

    frames, bodies, caps, one = replay(rows)
    skipped = []
    if lenient and not one.all():   # a range of rows: keep the drops the board reports and the models read
        skipped = rows[~one].tolist()
        rows = rows[one]
        frames, bodies, caps, one = replay(rows)
    if not one.all():
        raise SystemExit(f"drop {rows[~one][0]}: not one report from the native app")
    caps = np.stack(caps)
    feats = featurize(caps, board_signal)
    pred = model.predict(feats)

    def served(pred):   # the drops the host answers (a position and a class), whichever path it took
        return np.isfinite(pred["xy_mm"]).all(1) & (pred["energy_class"] >= 0)

    good = served(pred)
    if lenient and not good.all():
        skipped += rows[~good].tolist()
        rows = rows[good]
        if rows.size == 0:
            raise SystemExit("no drop of the fixture gets a position and class from the host's models")
        frames, bodies, caps, one = replay(rows)
        caps = np.stack(caps)
        feats = featurize(caps, board_signal)
        pred = model.predict(feats)
    if not served(pred).all():
        raise SystemExit("the host's models give no position or class on a fixture drop; pick others")
    # The reference is what the host serves for each drop (ImpactModel.predict: the forests, or twin_match leaving
    # a channel out, or the three-sensor path); the image runs TableModels::predict_event on the same inputs (the
    # picks, the localiser's per-channel travel-time factors and geometry the three-sensor localisations read).
    sk = np.concatenate([pred["xy_mm"], pred["energy_class"][:, None]], axis=1)
    left_out = np.asarray(pred.get("bad_channel", np.full(len(rows), -1)), int)  # -1: none or not named
    scales = np.asarray(_slowness_scales(feats, model.signal), np.float32).reshape(-1, 4)
    if scales.size == 0:   # no dispersion: every factor 1
        scales = np.ones((len(rows), 4), np.float32)

    from impactsense.export import _c_float

    def fmt_f(v):
        return _c_float(v) if np.isfinite(v) else "NAN"
    out = ["// Generated by firmware/test/qemu/gen_fixture.py; do not edit.\n#pragma once\n#include <stdint.h>\n",
           f"#define FIX_N_DROPS {len(rows)}\n#define FIX_FRAMES {frames.shape[1]}\n",
           app_defines(cfg),
           c_array("int16_t", "fix_frames", frames.reshape(len(rows), -1), str),
           c_array("uint8_t", "fix_report_body", np.stack(bodies), str),
           c_array("float", "fix_vector", feats.vector, fmt_f),
           c_array("float", "fix_phys_xy", feats.phys_xy_mm, fmt_f),
           c_array("float", "fix_toa_us", feats.toa_us, fmt_f),
           c_array("float", "fix_window_energy", feats.raw["window_energy"], fmt_f),
           c_array("float", "fix_diff_energy", feats.raw["diff_energy"], fmt_f),
           c_array("float", "fix_energy", feats.raw["energy"], fmt_f),
           c_array("uint8_t", "fix_flags", feats.flags, str),
           c_array("float", "fix_sklearn", sk.astype(np.float32), fmt_f),
           c_array("float", "fix_slowness_scale", scales, fmt_f),
           c_array("int8_t", "fix_left_out", left_out, str)]
    (build / "fixture.h").write_text("".join(out))
    (build / "fixture.json").write_text(json.dumps({"rows": rows.tolist(), "skipped_rows": sorted(skipped),
                                                    "model_dir": str(model_dir)}))


if __name__ == "__main__":
    main()
