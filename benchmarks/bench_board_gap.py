"""Where the board's held-out error comes from: one piece of the board's path changed at a time (issue 15).

    python3 benchmarks/bench_board_gap.py --model M --export E [--skip ARM,...] [--json OUT.json]

M = `impactsense train DATA` (the host model; its split), E = `impactsense export M` (E/board-model: the board's
model, trained again on the emulated board's captures; E/export.json). Every
row is the MAE per axis (mm) on M's held-out drops that every row placed (Eq. 36, x and y averaged):

- host: M at the rig's rate (the lab's recordings; ImpactModel.predict);
- board, firmware: the exported tables in the firmware app on the emulated board (what `export` prints);
- board, Python: E/board-model's own predict on the board's captures (the same trees in float64: the difference
  to the firmware's row is the tables' float32 and the export's tree count);
- board, physics only: its localiser's position (no correction trees);
- host model on the board's captures: M itself, its signal taken to 4 x 50 kHz (board.capture.signal_for_board);
- host forests on the board's features: M's forest settings (random forests, no event budget) fitted on the
  board model's own features of the training drops (the correction the budget does not allow);
- boosted, unbudgeted: the board's boosted depth-3 pair with 200 stages on the same features;
- two starts: the board's signal with localiser_starts 2 (its physics position, and with the board's own number
  of boosted stages refitted on those features); two_starts_cap8: the same with each start's normal-equation
  evaluations capped at 8 (edge_travel's call of the core's localiser; the vector's other columns as two_starts'),
  what two starts cost on the board at one start's bound (board.cost: 2 x 8 = 16 evaluations);
- 50 kHz, unbudgeted signal: the localiser fitted on the board's captures with every option the host may use
  (band picks, starts, posterior; board.cost's budget not applied), then M's model type (members on);
- scan delays off: the board model trained and scored (Python) on captures where the four channels are read at
  the same instant (capture delays 0) instead of the SAADC scan's c x 5 us.

The rig's declared front end (rig.json board_front_end) applies to every board row, as `export` applies it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ARMS = ("host", "firmware", "python", "physics", "host_model", "host_forests", "boosted_unbudgeted",
        "two_starts_physics", "two_starts", "two_starts_cap8", "unbudgeted_signal", "no_scan_delay")


def _simultaneous(board_samples, scan_step_us: float):
    """board_samples reading the four channels at one instant: channel c advanced by c x scan step first (a
    band-limited shift of the recording), so the scan's read of channel c at c x step takes channel 0's instant."""
    def wrapped(adc, fs_in_hz, fs_hz, *a, **k):
        x = np.asarray(adc, np.float64)
        n = x.shape[-1]
        pad = 256
        xp = np.pad(x, [(0, 0), (0, 0), (pad, pad)], mode="edge")
        f = np.fft.rfftfreq(xp.shape[-1], 1.0 / float(fs_in_hz))
        out = np.empty_like(x)
        for c in range(x.shape[1]):
            ph = np.exp(2j * np.pi * f * (c * scan_step_us * 1e-6))
            lvl = xp[:, c, :1]
            shifted = np.fft.irfft(np.fft.rfft(xp[:, c] - lvl, axis=-1) * ph, n=xp.shape[-1], axis=-1)
            out[:, c] = shifted[:, pad:pad + n] + lvl
        return board_samples(out.astype(np.float32), fs_in_hz, fs_hz, *a, **k)
    return wrapped


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True, help="the host model (impactsense train)")
    ap.add_argument("--export", type=Path, required=True, help="its export (impactsense export), with board-model/")
    ap.add_argument("--skip", default="", help="comma-separated rows to leave out (" + ",".join(ARMS) + ")")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    skip = {s for s in args.skip.split(",") if s}

    from dataclasses import replace

    from impactsense import _link
    from impactsense.board import capture as bcap
    from impactsense.board import models as bmod
    from impactsense.board.boosted import boosted_regressor
    from impactsense.data import load_session
    from impactsense.models import LOCATION_FEATURES, ForestSettings, ImpactModel, columns
    from impactsense.modelfolder import read_card
    from impactsense.pipeline import featurize, fit_localiser

    card, _ = read_card(args.model)
    split = card["split"]
    s = load_session(split["data_path"])
    index = {int(r): k for k, r in enumerate(s.recording_id)}
    train = np.asarray([index[int(r)] for r in split["train_recordings"]], int)
    test = np.asarray([index[int(r)] for r in split["test_recordings"]], int)
    host = ImpactModel.load(args.model)
    board = ImpactModel.load(args.export / "board-model")
    settings = ForestSettings(**{k: v for k, v in (card.get("forest") or {}).items()
                                 if k in ForestSettings.__dataclass_fields__})
    fs = int(board.card.get("board_fs_hz", 50000))
    pos = {a: np.full((len(s), 2), np.nan) for a in ARMS}

    def timed(name):
        print(f"  {name} ...", file=sys.stderr, flush=True)

    timed("host")
    pos["host"][test] = host.predict(host.featurize(s.adc[test]))["xy_mm"]
    if "firmware" not in skip:
        timed("firmware (emulated board)")
        from impactsense.board.scores import board_reports, report_positions
        from impactsense.export import firmware_models

        models, signal = firmware_models(args.export)
        pos["firmware"][test] = report_positions(board_reports(s.subset(test), models, signal, fs), len(test))
    timed("board captures")
    trigger = {k: v for k, v in bcap.board_signal(board.card).items() if k == bcap.TRIGGER_KEY}   # export's choice
    caps, rows, sig0 = bcap.board_captures(s, fs, trigger or None)
    at = {int(r): k for k, r in enumerate(rows)}
    tr = np.asarray([at[r] for r in train if r in at], int)
    te = np.asarray([at[r] for r in test if r in at], int)
    te_rows = rows[te]
    fb = board.featurize(caps)
    pb = board.predict(fb.take(te))
    pos["python"][te_rows] = pb["xy_mm"]
    pos["physics"][te_rows] = np.asarray(fb.phys_xy_mm, float)[te]
    xy = s.xy_mm[rows]
    if "host_model" not in skip:
        timed("host model on the board's captures")
        hb = ImpactModel.load(args.model)
        hb.signal = bcap.signal_for_board(s.rig, host.signal.to_dict(), fs)
        try:
            pos["host_model"][te_rows] = hb.predict(hb.featurize(caps[te]))["xy_mm"]
        except Exception as e:   # noqa: BLE001 (a row that cannot run is reported, not fatal)
            print(f"  host_model: {e}", file=sys.stderr)
    use = np.asarray(fb.usable, bool)
    X = fb.vector[:, columns(LOCATION_FEATURES)]
    phys = np.asarray(fb.phys_xy_mm, float)
    fit_rows = tr[use[tr]]
    resid = xy[fit_rows] - phys[fit_rows]
    ok_te = te[use[te]]
    if "host_forests" not in skip:
        timed("host forests on the board's features")
        corr = np.stack([settings.regressor().fit(X[fit_rows], resid[:, c]).predict(X[ok_te]) for c in (0, 1)], 1)
        pos["host_forests"][rows[ok_te]] = phys[ok_te] + corr
    if "boosted_unbudgeted" not in skip:
        timed("boosted, 200 stages")
        corr = np.stack([boosted_regressor(X[fit_rows], resid[:, c], 200, settings.seed).predict(X[ok_te])
                         for c in (0, 1)], 1)
        pos["boosted_unbudgeted"][rows[ok_te]] = phys[ok_te] + corr
    if "two_starts" not in skip:
        timed("two localiser starts")
        f2 = featurize(caps, replace(board.signal, localiser_starts=2))
        u2 = np.asarray(f2.usable, bool)
        X2, ph2 = f2.vector[:, columns(LOCATION_FEATURES)], np.asarray(f2.phys_xy_mm, float)
        pos["two_starts_physics"][te_rows] = ph2[te]
        fr2, ok2 = tr[u2[tr]], te[u2[te]]
        stages = int((board.card.get("board_forests") or {}).get("stages") or 20)
        corr = np.stack([boosted_regressor(X2[fr2], xy[fr2, c] - ph2[fr2, c], stages, settings.seed).predict(X2[ok2])
                         for c in (0, 1)], 1)
        pos["two_starts"][rows[ok2]] = ph2[ok2] + corr
        from impactsense.edge_travel import _localise

        ph8 = _localise(f2.raw, replace(board.signal, localiser_starts=2), "threshold", 0.0, max_evaluations=8)
        ok8 = np.isfinite(ph8).all(1) & u2
        fr8, te8 = tr[ok8[tr]], te[ok8[te]]
        corr = np.stack([boosted_regressor(X2[fr8], xy[fr8, c] - ph8[fr8, c], stages, settings.seed).predict(X2[te8])
                         for c in (0, 1)], 1)
        pos["two_starts_cap8"][rows[te8]] = ph8[te8] + corr
    if "unbudgeted_signal" not in skip:
        timed("50 kHz, unbudgeted signal")
        ns = SimpleNamespace(adc=caps, xy_mm=xy, rig=s.rig, height_mm=s.height_mm[rows])
        sig = replace(sig0, onset_threshold_counts=float(board.signal.onset_threshold_counts))
        try:
            sig = fit_localiser(ns, tr, sig, choose_threshold=False, fits=None)
            print(f"  unbudgeted signal: starts {sig.localiser_starts}, posterior grid {sig.posterior_grid}, "
                  f"dispersion exponent {sig.dispersion_exponent:.3f}, band picks {sig.band_pick_hz:.0f} Hz",
                  file=sys.stderr)
            f2 = featurize(caps, sig)
            m2 = ImpactModel.fit(f2.take(tr), xy[tr], s.height_mm[rows][tr], s.rig.ball_mass_g, sig, settings,
                                 members=True)
            pos["unbudgeted_signal"][te_rows] = m2.predict(m2.featurize(caps[te]))["xy_mm"]
        except Exception as e:   # noqa: BLE001
            print(f"  unbudgeted_signal: {e}", file=sys.stderr)
    if "no_scan_delay" not in skip:
        timed("scan delays off")
        orig_samples, orig_caps = bcap.board_samples, bmod.board_captures
        bcap.board_samples = _simultaneous(orig_samples, _link.SCAN_STEP_US)

        def no_delay_captures(session, fs_hz=50000, signal=None):
            c, r, sg = orig_caps(session, fs_hz, signal)
            return c, r, replace(sg, capture_delay_us=[0.0] * 4)
        bmod.board_captures = no_delay_captures
        try:
            import tempfile

            with tempfile.TemporaryDirectory() as tmp:
                bmod.train_board_models(s, Path(tmp) / "m", settings=settings, train_rows=train,
                                        onset_threshold_counts=host.signal.onset_threshold_counts,
                                        choose_class="energy_class_choice" in card)
                m3 = ImpactModel.load(Path(tmp) / "m")
                t3 = {k: v for k, v in bcap.board_signal(m3.card).items() if k == bcap.TRIGGER_KEY}
                c3, r3, _ = no_delay_captures(s.subset(test), fs, t3 or None)
                pos["no_scan_delay"][test[r3]] = m3.predict(m3.featurize(c3))["xy_mm"]
        finally:
            bcap.board_samples, bmod.board_captures = orig_samples, orig_caps

    truth = s.xy_mm[test]
    run = [a for a in ARMS if a not in skip and np.isfinite(pos[a][test]).any()]
    common = np.all([np.isfinite(pos[a][test]).all(1) for a in run], axis=0)
    rows_out = {}
    print(f"{s.path}: {len(test)} held-out drops (seed {split.get('seed')}), {int(common.sum())} placed by every row")
    for a in run:
        p = pos[a][test]
        ok = np.isfinite(p).all(1)
        rows_out[a] = {"mae_common_mm": float(np.abs(p[common] - truth[common]).mean()),
                       "mae_own_mm": float(np.abs(p[ok] - truth[ok]).mean()), "placed": int(ok.sum())}
        r = rows_out[a]
        print(f"  {a:20s} MAE per axis {r['mae_common_mm']:6.2f} mm (own drops {r['mae_own_mm']:.2f}, "
              f"{r['placed']} placed)")
    if args.json:
        args.json.write_text(json.dumps({"data": str(s.path), "seed": split.get("seed"), "rows": rows_out}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
