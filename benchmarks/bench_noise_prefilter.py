"""How much of a diagnosed white noise a filter matched to the onset's band can take out before the picks (a study for
issue 16's white-noise row, no target), and what such a filter does to the noise row's model.

    python3 benchmarks/bench_noise_prefilter.py REF --white 9.76 [--window 32]
    python3 benchmarks/bench_noise_prefilter.py REF --white 9.76 --train TRAINING SESSION [CONTROL ...]
        [--cutoff-hz F] [--order 6] [--trees 30] [--seed 12]

1. The onset's spectrum: REF's clean drops (the session without the change), each channel's window of --window
samples from 8 samples before its first 10-count crossing (Hann), the mean power S(f), against the white noise's
N = white^2 in the same window. Prints S / N by frequency, the Wiener gain S / (S + N), the share of the white
noise's power the Wiener filter passes (its rms after = white x sqrt of it) and the first frequency where the gain
is below one half (the matched low-pass's cut-off); and the Cramer-Rao bound on the onset window's time under the
noise if each channel's waveform were known (white / sqrt(sum of its squared slope)): what the samples hold.
2. With --train: bench_noise_training's model ("choose", the reference's band floor) trained on TRAINING
(bench_loop's OUT/noise-measured) with a zero-phase Butterworth low-pass (scipy sosfiltfilt, --order, at
--cutoff-hz or the half-gain frequency of 1.) put on every recording before the core (training, SESSION, the
CONTROLs after their noise draw, REF for the band floor), against the same without it. A zero-phase filter is the
best case of any pre-filter at that band (no group delay for the picks to inherit).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_noise_training  # noqa: E402

ONSET_COUNTS = 10.0     # the first crossing the window starts from (the core's default onset threshold)
BEFORE = 8              # samples of the window before it


def onset_windows(session, window: int):
    """Each channel's onset window (counts, offset removed): BEFORE samples before its first crossing of ONSET_COUNTS."""
    x = np.asarray(session.adc, float)
    x = x - x[:, :, :64].mean(-1, keepdims=True)
    for d in range(len(x)):
        for c in range(x.shape[1]):
            above = np.abs(x[d, c]) > ONSET_COUNTS
            i = int(np.argmax(above))
            if above[i] and i >= BEFORE and i - BEFORE + window <= x.shape[2]:
                yield x[d, c, i - BEFORE:i - BEFORE + window]


def onset_spectrum(session, window: int) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies Hz, mean Hann-windowed power of the channels' onset windows, counts^2)."""
    taper = np.hanning(window)
    power = [np.abs(np.fft.rfft(w * taper)) ** 2 for w in onset_windows(session, window)]
    if not power:
        raise SystemExit(f"{session.path}: no channel crosses {ONSET_COUNTS:g} counts")
    return np.fft.rfftfreq(window, 1.0 / float(session.rig.fs_hz)), np.mean(power, 0)


def timing_bound(session, white: float, window: int) -> np.ndarray:
    """Each channel's Cramer-Rao bound (us) on the time of its onset window (as onset_spectrum's) under the white
    noise if its waveform were known: white / sqrt(sum of the window's squared slope), counts / s."""
    fs = float(session.rig.fs_hz)
    return np.asarray([white / np.sqrt(np.sum((np.gradient(w) * fs) ** 2)) * 1e6
                       for w in onset_windows(session, window)])


def wiener(session, white: float, window: int) -> dict:
    f, s = onset_spectrum(session, window)
    n = white ** 2 * float((np.hanning(window) ** 2).sum())
    gain = s / (s + n)
    passed = float(np.mean(gain ** 2))          # white noise: the same power in every bin
    half = f[np.argmax(gain < 0.5)] if (gain < 0.5).any() else float(session.rig.fs_hz) / 2
    return {"f_hz": f, "snr": s / n, "gain": gain, "noise_power_passed": passed, "half_gain_hz": float(half)}


def lowpassed(session, cutoff_hz: float, order: int):
    from scipy.signal import butter, sosfiltfilt

    sos = butter(order, cutoff_hz, fs=float(session.rig.fs_hz), output="sos")
    bias = session.rig.bias_counts
    a = sosfiltfilt(sos, np.asarray(session.adc, float) - bias, axis=-1)
    return dataclasses.replace(session, adc=np.clip(np.rint(a + bias), 0, session.rig.adc_max).astype(np.uint16))


def main(argv=None) -> int:
    from impactsense.commands.retrain import score
    from impactsense.data import load_session

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("reference")
    ap.add_argument("--white", type=float, required=True, help="the diagnosed white noise (counts rms)")
    ap.add_argument("--window", type=int, default=32)
    ap.add_argument("--train", nargs="+", metavar="PATH", help="TRAINING SESSION [CONTROL ...]")
    ap.add_argument("--cutoff-hz", type=float)
    ap.add_argument("--order", type=int, default=6)
    ap.add_argument("--trees", type=int, default=30)
    ap.add_argument("--seed", type=int, default=12)
    args = ap.parse_args(argv)
    ref = load_session(args.reference)
    w = wiener(ref, args.white, args.window)
    step = max(1, len(w["f_hz"]) // 16)
    for f, snr, g in zip(w["f_hz"][::step], w["snr"][::step], w["gain"][::step]):
        print(f"  {f / 1e3:6.1f} kHz  S/N {snr:10.2f}  Wiener gain {g:.3f}")
    print(f"Wiener filter: passes {w['noise_power_passed']:.2f} of the white noise's power (rms {args.white:g} -> "
          f"{args.white * np.sqrt(w['noise_power_passed']):.2f} counts); gain 1/2 at {w['half_gain_hz'] / 1e3:.1f} kHz")
    for n in (16, 32):
        b = timing_bound(ref, args.white, n)
        print(f"timing bound, a known waveform over {n} samples from {BEFORE} before the crossing: median "
              f"{np.median(b):.2f} us, p90 {np.percentile(b, 90):.2f} us (a DToA: sqrt(2) x)")
    if not args.train:
        return 0
    if len(args.train) < 2:
        ap.error("--train needs TRAINING SESSION [CONTROL ...]")
    cutoff = args.cutoff_hz or w["half_gain_hz"]
    training, session = load_session(args.train[0]), load_session(args.train[1])
    controls = [bench_noise_training.noisy(load_session(p), args.white, 2000 + i) for i, p in enumerate(args.train[2:])]
    for label, f in (("none", None), (f"zero-phase low-pass {cutoff / 1e3:.1f} kHz, order {args.order}", cutoff)):
        t0 = time.time()
        put = (lambda s: s) if f is None else (lambda s: lowpassed(s, f, args.order))
        model = bench_noise_training.trained(put(training), "choose", 3.0, args.trees, args.seed, put(ref))
        s = score(put(session), model)
        ctl = " / ".join(f"{score(put(c), model)['mae_mm']:.2f}" for c in controls)
        print(f"{label} (threshold {model.signal.onset_threshold_counts:g}, band {model.signal.band_pick_hz:g} Hz): "
              f"session {s['mae_mm']:.2f} mm (physics {s['physics_mae_mm']:.2f}); controls + {args.white:g} counts: "
              f"{ctl or '-'} ({time.time() - t0:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
