"""How the core's picks follow a pure time shift of one channel (a study, no target): each delay is put into the
channel's recordings by an exact band-limited (FFT) shift and the rig's onset picked again; the pick change
should equal the delay. Whole-sample delays are exact by construction; a fractional one tells how steady the
onset is under a sub-sample change of the waveform (what a `channel_delay` of the loop's sessions reads).

    python3 benchmarks/bench_delay_picks.py SESSION [--drops 60] [--channel 0] [--delays-us -7.83,-3,1,3,5,7.83,10]

Prints per delay the median pick change and its quartiles over the drops (us).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def fft_delay(a: np.ndarray, delay_samples: float) -> np.ndarray:
    """Each row of a delayed by delay_samples (any real number) as a band-limited signal (FFT). The record is
    padded with its own edge values (no step at either end to ring into the pre-trigger baseline)."""
    n = a.shape[-1]
    pad = n // 2
    x = np.pad(a, [(0, 0)] * (a.ndim - 1) + [(pad, pad)], mode="edge")
    spec = np.fft.rfft(x, axis=-1)
    f = np.fft.rfftfreq(x.shape[-1])
    return np.fft.irfft(spec * np.exp(-2j * np.pi * f * delay_samples), x.shape[-1], axis=-1)[..., pad:pad + n]


def pick_changes(session, channel: int, delays_us, drops: int) -> list[dict]:
    from impactsense.signal import SignalConfig
    from impactsense.travel import picks

    sess = session.subset(np.arange(min(drops, len(session))))
    cfg = SignalConfig.for_rig(sess.rig)
    a = np.asarray(sess.adc, float) - sess.rig.bias_counts

    def counts(x):
        return np.clip(np.rint(x + sess.rig.bias_counts), 0, sess.rig.adc_max).astype(np.uint16)

    before = picks(counts(a), cfg)
    rows = []
    for d in delays_us:
        b = a.copy()
        b[:, channel] = fft_delay(a[:, channel], d * 1e-6 * sess.rig.fs_hz)
        x = (picks(counts(b), cfg) - before)[:, channel]
        q1, med, q3 = np.nanpercentile(x, [25, 50, 75])
        rows.append({"delay_us": d, "median_us": float(med), "q1_us": float(q1), "q3_us": float(q3)})
    return rows


def main(argv=None) -> int:
    from impactsense.data import load_session

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("session")
    ap.add_argument("--drops", type=int, default=60)
    ap.add_argument("--channel", type=int, default=0)
    ap.add_argument("--delays-us", default="-7.83,-3,1,3,5,7.83,10")
    args = ap.parse_args(argv)
    rows = pick_changes(load_session(Path(args.session)), args.channel,
                        [float(v) for v in args.delays_us.split(",")], args.drops)
    print("| delay us | pick change: median | quartiles |")
    print("|---|---|---|")
    for r in rows:
        print(f"| {r['delay_us']:+.2f} | {r['median_us']:+.2f} | {r['q1_us']:+.2f} .. {r['q3_us']:+.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
