"""The shipped board models on the emulated board with mains hum on every channel: the board's MAE and class on a
session as `impactsense inject` puts the hum in, and with the same amount of hum continuous through the board's
capture.

    python benchmarks/bench_board_hum.py [--data bundled:session-2] [--hum 50] [--hum-hz 50] [--noise 2] [--lead 400]

Rows: the session as recorded; `inject --hum H --hum-hz F --noise N` (per record 0.5..1 x H at F Hz, random phase); a
flat lead of --lead samples before each record (the board's capture then starts inside the record, not in the stream's
lead-in), without hum and with a hum of 0.5..1 x H continuous over the record and its lead. The emulator joins the
recorded drops into one stream (board.capture.joined_without_steps: where a join steps by the trigger's threshold,
each record is led in by its quiet start continued back in time, the hum going on with its own phase, over as far as
a capture reaches; a crossfade from the previous record before that). Compare the inject row with the continuous one.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="bundled:session-2")
    ap.add_argument("--hum", type=float, default=50.0, help="hum amplitude, counts (per channel 0.5..1 x)")
    ap.add_argument("--hum-hz", type=float, default=50.0, help="mains frequency, Hz")
    ap.add_argument("--noise", type=float, default=2.0, help="white noise the inject row adds, counts rms")
    ap.add_argument("--lead", type=int, default=400, help="flat samples put before each record")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    from impactsense.board.scores import board_accuracy
    from impactsense.data import load_session
    from impactsense.export import firmware_models
    from impactsense.faults import FaultSpec, inject_session

    models, signal = firmware_models(ROOT / "models")
    threshold = float(json.loads((ROOT / "models" / "export.json").read_text())["energy_threshold_j"])
    s = load_session(args.data)
    rng = np.random.default_rng(args.seed)
    base = np.median(s.adc[..., :max(2, s.rig.pretrigger_samples // 2)], axis=-1, keepdims=True)
    led = np.concatenate([np.broadcast_to(base, s.adc.shape[:-1] + (args.lead,)), s.adc.astype(float)], axis=-1)
    rig = dataclasses.replace(s.rig, pretrigger_samples=s.rig.pretrigger_samples + args.lead)
    t = np.arange(led.shape[-1]) / s.rig.fs_hz

    def continuous(amp: float):
        phase = rng.uniform(0, 2 * np.pi, size=led.shape[:2] + (1,))
        a = amp * rng.uniform(0.5, 1.0, size=led.shape[:2] + (1,))
        adc = np.rint(led + a * np.sin(2 * np.pi * args.hum_hz * t + phase)).astype(s.adc.dtype)
        return dataclasses.replace(s, adc=adc, rig=rig)

    rows = {"as recorded": s,
            f"inject --hum {args.hum:g} --hum-hz {args.hum_hz:g} --noise {args.noise:g}":
                inject_session(s, FaultSpec(hum=args.hum, hum_hz=args.hum_hz, noise=args.noise, seed=args.seed)),
            f"flat lead {args.lead}, no hum": continuous(0.0),
            f"flat lead {args.lead}, hum {args.hum:g} continuous": continuous(args.hum)}
    print(f"{'session':<46}{'reported':>10}{'MAE mm':>9}{'class':>8}")
    for name, session in rows.items():
        acc = board_accuracy(session, models, signal, threshold, 50000)
        print(f"{name:<46}{acc['reported']:>6}/{acc['n']:<3}{acc['all']['mae_mm']:>9.2f}"
              f"{acc['energy_class_accuracy']:>8.3f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
