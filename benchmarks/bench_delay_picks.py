"""How the core's picks follow a pure time shift of one channel (a study, no target): the rig's onset picked
again after each delay; the pick change should equal the delay.

    python3 benchmarks/bench_delay_picks.py SESSION [--drops 60] [--channel 0] [--delays-us -7.83,-3,1,3,5,7.83,10]
        [--fem [--calibration CAL.json|rig] [--element-mm 3]]

Without --fem the delay is put into the session's own recordings by a band-limited (FFT) shift of the samples:
exact for a record without content above half the sampling rate, not a physical delay where the onset is
aliased (a thin metal plate's first cycles lie near or above it; what was recorded cannot say which). With --fem
the delay acts on the twin's analogue signal before the recorder samples it (`sim.simulate.delayed_fields`, as a
channel skew does), at the session's first declared positions (one drop each), with the twin's noise (one draw, the same before
and after); the FFT shift of the same simulated records is printed beside it.

Prints per delay the pick change's median, mean and quartiles over the drops (us).
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


def _row(delay_us, method, x) -> dict:
    q1, med, q3 = np.nanpercentile(x, [25, 50, 75])
    return {"delay_us": delay_us, "method": method, "median_us": float(med), "mean_us": float(np.nanmean(x)),
            "q1_us": float(q1), "q3_us": float(q3)}


def pick_changes(session, channel: int, delays_us, drops: int) -> list[dict]:
    """The FFT shift of the session's own recordings."""
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
        rows.append(_row(d, "FFT shift of the recorded samples", (picks(counts(b), cfg) - before)[:, channel]))
    return rows


def fem_pick_changes(session, channel: int, delays_us, drops: int, params) -> list[dict]:
    """The twin's analogue signal delayed (physical), and the FFT shift of the same simulated records."""
    from impactsense.signal import SignalConfig
    from impactsense.sim.simulate import simulate_voltages
    from impactsense.travel import picks

    rig = session.rig
    first = np.unique(session.case_id, return_index=True)[1]     # one drop per declared position
    sub = session.subset(np.sort(first)[:drops])
    noise = np.random.default_rng(0).normal(0.0, params.noise_counts_rms, (len(sub), 4, rig.samples))

    def clean(delays_s=None):
        volts = simulate_voltages(params, rig, sub.x_mm, sub.y_mm, sub.height_mm, workers=1,
                                  disc_delays_s=delays_s)["volts"]
        return _counts_float(volts, params, rig)

    def adc(c):
        return np.clip(np.rint(c + noise + rig.bias_counts), 0, rig.adc_max).astype(np.uint16)

    cfg = SignalConfig.for_rig(rig)
    c0 = clean()
    before = picks(adc(c0), cfg)
    rows = []
    for d in delays_us:
        delays = [0.0] * 4
        delays[channel] = d * 1e-6
        rows.append(_row(d, "twin: the analogue signal delayed", (picks(adc(clean(delays)), cfg) - before)[:, channel]))
        b = c0.copy()
        b[:, channel] = fft_delay(c0[:, channel], d * 1e-6 * rig.fs_hz)
        rows.append(_row(d, "twin: FFT shift of its samples", (picks(adc(b), cfg) - before)[:, channel]))
    return rows


def _counts_float(volts, params, rig) -> np.ndarray:
    """Clean counts (bias removed, not rounded) of volts as `to_adc` places them in the record."""
    rec = np.zeros((volts.shape[0], volts.shape[1], rig.samples))
    start = params.pretrigger_samples
    take = min(volts.shape[-1], rig.samples - start)
    rec[:, :, start:start + take] = volts[:, :, :take]
    return params.circuit_gain * rec * (2 ** rig.adc_bits) / rig.vref


def twin_params(session, calibration: str, element_mm: float):
    import dataclasses
    import json

    from impactsense.sim import SimParams

    if calibration == "rig":
        p = SimParams.from_rig(session.rig)
    else:
        p = SimParams.from_dict(json.loads(Path(calibration).read_text())["sim_params"], calibration)
    return dataclasses.replace(p, element_mm=element_mm, method="fast", solver="direct", duration_ms=3.0, taper_ms=0.5)


def main(argv=None) -> int:
    from impactsense.data import load_session

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("session")
    ap.add_argument("--drops", type=int, default=60)
    ap.add_argument("--channel", type=int, default=0)
    ap.add_argument("--delays-us", default="-7.83,-3,1,3,5,7.83,10")
    ap.add_argument("--fem", action="store_true", help="the twin's analogue signal delayed (physical)")
    ap.add_argument("--calibration", default="rig", help="with --fem: CAL.json, or 'rig' (the rig's material)")
    ap.add_argument("--element-mm", type=float, default=3.0)
    args = ap.parse_args(argv)
    session = load_session(Path(args.session) if Path(args.session).exists() else args.session)
    delays = [float(v) for v in args.delays_us.split(",")]
    if args.fem:
        rows = fem_pick_changes(session, args.channel, delays, args.drops,
                                twin_params(session, args.calibration, args.element_mm))
    else:
        rows = pick_changes(session, args.channel, delays, args.drops)
    print("| delay us | how | pick change: median | mean | quartiles |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['delay_us']:+.2f} | {r['method']} | {r['median_us']:+.2f} | {r['mean_us']:+.2f} | "
              f"{r['q1_us']:+.2f} .. {r['q3_us']:+.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
