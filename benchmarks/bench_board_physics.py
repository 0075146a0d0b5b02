"""Where the board's physics position loses to the host's: the physics localiser's MAE per axis (Eq. 36, x
and y averaged) on every drop of a session, the board's 4 x 50 kHz captures against the lab's recordings.

    python benchmarks/bench_board_physics.py DATA --model M --export OUT [--json OUT.json]

M: `impactsense train DATA --out M` (the host model, its signal at the rig's rate); OUT: `impactsense export M
--out OUT` (the board's refit: its signal at 50 kHz, OUT/board-model/model_card.json). Rows printed:
- the host's signal on the recordings, and with its options taken away one at a time (band picks, localiser
  starts, dispersion) and all together;
- the board refit's signal on the recordings (its speed/delays at the rig's rate) and on the board captures;
- on the board captures: the refit's signal with 2 / 4 localiser starts, the host's dispersion, the host's
  speed + dispersion + delays, the AIC blend 0 / 1, and onset thresholds x0.4 / x0.6 / x1.6 of the refit's.
Every row is the core's process_batch (physics position only: no forests, no twin). The physics position is
fitted on the drops it is scored on (speed and delays from the training drops): a diagnosis, not a held-out
figure (bench_board_rigs.py gives those). Prints; exits 0.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("--model", type=Path, required=True, help="the host model (impactsense train)")
    ap.add_argument("--export", type=Path, required=True, help="its board export (impactsense export)")
    ap.add_argument("--fs", type=int, default=50000, help="the board's rate")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()

    from impactsense import _core
    from impactsense.board.capture import board_captures
    from impactsense.data import load_session
    from impactsense.pipeline import as_int16
    from impactsense.signal import SignalConfig

    session = load_session(args.data)
    host = json.loads((args.model / "model_card.json").read_text())["signal"]
    board = json.loads((args.export / "board-model" / "model_card.json").read_text())["signal"]
    caps, rows, _ = board_captures(session, args.fs, board)
    everything = np.arange(len(session))
    out: dict[str, float] = {}

    def score(name: str, signal: dict, adc: np.ndarray, which: np.ndarray) -> None:
        cfg = SignalConfig.from_dict(signal)
        ev = _core.process_batch(as_int16(adc, cfg), cfg.core(), cfg.localiser())
        xy = np.asarray(ev["phys_xy_mm"], float)
        ok = np.isfinite(xy).all(1)
        mae = float(np.abs(xy[ok] - session.xy_mm[which][ok]).mean())
        out[name] = mae
        print(f"{name:<58} {mae:7.2f} mm  ({ok.sum()} of {len(ok)} located, "
              f"<= {int(np.max(ev['localiser_evaluations']))} evaluations a run)", flush=True)

    def changed(base: dict, **kw) -> dict:
        return {**base, **kw}

    rate = f"{session.rig.fs_hz / 1000:g} kHz"
    print(f"{session.path}: physics position MAE per axis, every drop")
    score(f"host signal, recordings ({rate})", host, session.adc, everything)
    score("  band picks off", changed(host, band_pick_hz=0.0), session.adc, everything)
    score("  1 localiser start", changed(host, localiser_starts=1), session.adc, everything)
    score("  no dispersion", changed(host, dispersion_exponent=0.0), session.adc, everything)
    score("  all three", changed(host, band_pick_hz=0.0, localiser_starts=1, dispersion_exponent=0.0),
          session.adc, everything)
    at_rate = changed(board, fs_hz=float(session.rig.fs_hz), aic_before=host["aic_before"],
                      aic_after=host["aic_after"], capture_delay_us=[0.0] * len(board["capture_delay_us"]))
    score(f"board refit's signal, recordings ({rate})", at_rate, session.adc, everything)
    score(f"board refit's signal, board captures ({args.fs / 1000:g} kHz)", board, caps, rows)
    for starts in (2, 4):
        score(f"  {starts} localiser starts", changed(board, localiser_starts=starts), caps, rows)
    score("  the host's dispersion", changed(board, dispersion_exponent=host["dispersion_exponent"],
                                             dispersion_ref_hz=host["dispersion_ref_hz"]), caps, rows)
    score("  the host's speed, dispersion, delays", changed(
        board, velocity_mm_per_us=host["velocity_mm_per_us"], dispersion_exponent=host["dispersion_exponent"],
        dispersion_ref_hz=host["dispersion_ref_hz"], rig_delay_us=host["rig_delay_us"]), caps, rows)
    for blend in (0.0, 1.0):
        score(f"  AIC blend {blend:g}", changed(board, aic_blend=blend), caps, rows)
    thr = float(board["onset_threshold_counts"])
    for k in (0.4, 0.6, 1.6):
        score(f"  onset threshold {k * thr:g} counts", changed(board, onset_threshold_counts=k * thr), caps, rows)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
