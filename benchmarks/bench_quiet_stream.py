"""A faulty lab with nobody hitting the plate: minutes of mains hum, noise, offsets and glitches streamed
through the firmware app (the emulated board: impactsense._link.App, the code `impactsense emulate` runs)
at 4 x 50 kHz. Prints the reports it sent (target: 0) and the trigger's threshold at the end.

The stream: per channel an offset (sd 25 counts) and a hum of 0.5..1 x --hum counts at --hum-hz with its
own phase and an amplitude changing by +-10 % over a few seconds, white noise (--noise counts), and a
1-2 sample glitch of 200..2000 counts on a random channel every --glitch-ms on average (Poisson).

    python benchmarks/bench_quiet_stream.py [--minutes 10] [--hum 50] [--hum-hz 50] [--noise 2]
                                            [--glitch-ms 500] [--models DIR]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from impactsense import _link
from impactsense.data import load_session
from impactsense.link.emulator import app_config

FS = 50000
CHUNK = FS  # one second a feed


def chunk(rng, k, state, args):
    t = (k * CHUNK + np.arange(CHUNK)) / FS
    slow = 1.0 + 0.1 * np.sin(2 * np.pi * t[:, None] / 7.0 + state["phase2"])
    x = 2048 + state["offset"] + state["amp"] * slow * np.sin(2 * np.pi * args.hum_hz * t[:, None] + state["phase"])
    x += rng.normal(0, args.noise, x.shape)
    n_glitch = rng.poisson(CHUNK / FS * 1000.0 / args.glitch_ms)
    for _ in range(n_glitch):
        i, c, w = int(rng.integers(CHUNK - 2)), int(rng.integers(4)), 1 + int(rng.integers(2))
        x[i:i + w, c] += rng.choice([-1, 1]) * rng.uniform(200, 2000)
    return np.clip(np.rint(x), 0, 4095).astype(np.int16), n_glitch


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--hum", type=float, default=50.0)
    ap.add_argument("--hum-hz", type=float, default=50.0)
    ap.add_argument("--noise", type=float, default=2.0)
    ap.add_argument("--glitch-ms", type=float, default=500.0,
                    help="mean time between glitches (default 500: one in 10 %% of 50 ms records)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    rig = load_session().rig
    app = _link.App(app_config(rig, FS), None)
    state = {"offset": rng.normal(0, 25, 4), "amp": args.hum * rng.uniform(0.5, 1.0, 4),
             "phase": rng.uniform(0, 2 * np.pi, 4), "phase2": rng.uniform(0, 2 * np.pi, 4)}
    t0, glitches = time.time(), 0
    seconds = int(round(args.minutes * 60))
    for k in range(seconds):
        frames, g = chunk(rng, k, state, args)
        glitches += g
        app.feed(frames)
    print(f"{args.minutes:g} min of hum {args.hum:g} counts at {args.hum_hz:g} Hz, noise {args.noise:g}, "
          f"{glitches} glitches of 200..2000 counts: {app.events} reports ({time.time() - t0:.0f} s)")
    return 0 if app.events == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
