"""Does an onset pick at 50 kHz depend on where the samples fall? The phase test of onset pickers (issue 15).

    python benchmarks/bench_onset_phase.py DATA [DATA ...]

Each 100 kHz recording is cut into its even and its odd samples (two 50 kHz recordings of the same drop whose
samples fall half a board sample, 10 us, apart; no anti-alias filter, as on the board) and every channel is
picked on both. A picker whose time does not depend on the sample phase gives the same time on both (the odd
recording's times + 10 us). Printed per picker: the even - odd difference's median, IQR and 10-90 % range (us),
and the even pick against the 100 kHz threshold pick of the same channel (centred on its median: the scatter
about the host's pick). Reference rows: the core's 100 kHz pick against the same recording shifted by half a
sample (windowed-sinc interpolation; on an arrival that rises within one 100 kHz sample the sinc's pre-ringing
moves the pick too, so this is not a clean phase reference), and the share of each channel's first arrival
energy (its first 100 us at 100 kHz) above the board's Nyquist frequency, 25 kHz. --prefilter-hz low-passes the
recordings before they are cut (an analogue anti-alias filter's model); --physics adds each picker's physics MAE
and the core pick's on captures laid out as the SAADC scans (channels 1 and 3 interpolated half a 100 kHz sample,
by the emulator's windowed sinc and linearly).

Pickers: the core's (threshold + AIC blend, its threshold crossing, its AIC onset; featurize at 50 kHz with the
sample counts, the baseline's too, halved), and candidates written here in numpy as a diagnosis (none is in the core):
- box2: the threshold on |x| smoothed over two samples;
- sinc: the threshold crossing of |x| on the windowed-sinc interpolant (x4, 4 samples a side);
- envelope: |x + j H x| (an 11-tap Hilbert FIR, 2-21 kHz), the up-crossing of half its peak within 2 samples
  after the threshold crossing;
- energy: where the cumulative |x| from 10 samples before the crossing reaches 5 % of its value 10 after;
- tangent: the zero of a line fitted to the running maxima of |x| over the crossing and 3 samples after.
Docs: docs/findings.md "Session 20: onset50". Exits 0.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy.signal import lfilter, remez

FS = 50000.0
US = 1e6 / FS


def core_picks(x, cfg):
    from impactsense.pipeline import featurize

    r = featurize(x, cfg).raw
    us = 1e6 / cfg.fs_hz
    return {"core pick (threshold + AIC blend)": np.asarray(r["toa_us"], float),
            "core threshold crossing": np.asarray(r["toa_threshold"], float) * us,
            "core AIC onset": np.asarray(r["toa_aic"], float) * us}, r


def _each(anchor_us, fn):
    out = np.full(anchor_us.shape, np.nan)
    for i, ch in zip(*np.nonzero(np.isfinite(anchor_us))):
        out[i, ch] = fn(i, ch, int(anchor_us[i, ch] / US))
    return out


def _cross(y, lev, first=1):
    m = first + int(np.argmax(y[first:] >= lev))
    if y[m] < lev or m == 0 or y[m] == y[m - 1]:
        return np.nan
    return m - 1 + (lev - y[m - 1]) / (y[m] - y[m - 1])


def box2(x, base, thr, anchor_us):
    def one(i, c, k0):
        lo = max(1, k0 - 20)
        v = np.abs(x[i, c, lo:k0 + 10].astype(float) - base[i, c])
        return (lo + 0.5 + _cross(0.5 * (v[1:] + v[:-1]), thr[i, c])) * US
    return _each(anchor_us, one)


def sinc(x, base, thr, anchor_us, up=4, taps=4):
    kern = []
    for f in np.arange(up) / up:
        h = np.sinc(np.arange(-taps + 1, taps + 1) - f) * np.kaiser(2 * taps, 6.0)
        kern.append(h / h.sum())
    kern = np.asarray(kern)

    def one(i, c, k0):
        v = x[i, c].astype(float) - base[i, c]
        ks = np.arange(max(taps, k0 - 3), min(v.size - taps, k0 + 3))
        y = np.abs(np.stack([kern @ v[k - taps + 1:k + taps + 1] for k in ks]).ravel())
        m = _cross(y, thr[i, c])
        return (ks[0] + m / up) * US
    return _each(anchor_us, one)


def envelope(x, base, thr, anchor_us, ntaps=11, ahead=2, frac=0.5):
    h = remez(ntaps, [0.04, 0.42], [1.0], type="hilbert", fs=1.0)
    d = (ntaps - 1) // 2

    def one(i, c, k0):
        lo = max(1, k0 - 40)
        v = x[i, c, lo:k0 + 60].astype(float) - base[i, c]
        q = lfilter(h, 1.0, v)
        e = np.hypot(v[:-d], q[d:])
        a = k0 - lo
        j = a - 3 + int(np.argmax(e[a - 3:a + ahead + 1]))
        k = j
        while k > 0 and e[k - 1] >= frac * e[j]:
            k -= 1
        if k == 0:
            return np.nan
        return (lo + k - 1 + (frac * e[j] - e[k - 1]) / (e[k] - e[k - 1])) * US
    return _each(anchor_us, one)


def energy(x, base, thr, anchor_us, ahead=10, q=0.05):
    def one(i, c, k0):
        lo = max(1, k0 - 10)
        cs = np.r_[0.0, np.cumsum(np.abs(x[i, c, lo:k0 + ahead + 1].astype(float) - base[i, c]))]
        return (lo - 0.5 + _cross(cs, q * cs[-1])) * US
    return _each(anchor_us, one)


def tangent(x, base, thr, anchor_us, after=3):
    def one(i, c, k0):
        lo = k0
        v = np.abs(x[i, c, lo:k0 + after + 2].astype(float) - base[i, c])
        run = np.maximum.accumulate(v)
        keep = (v == run) & (v >= 0.5 * thr[i, c])
        if keep.sum() < 2:
            return np.nan
        sl, ic = np.polyfit(np.nonzero(keep)[0] + lo, v[keep], 1)
        return -ic / sl * US if sl > 0 else np.nan
    return _each(anchor_us, one)


CANDIDATES = {"box2: threshold on |x| over 2 samples": box2, "sinc: crossing of the x4 interpolant": sinc,
              "envelope: half its peak (Hilbert FIR)": envelope, "energy: 5 % of cumulative |x|": energy,
              "tangent: line through the running max": tangent}


def half_sample(x):
    """x (int16 [R, 4, n]) at t + half a sample (windowed sinc, 32 taps), as int16."""
    k = np.arange(-15, 17) - 0.5
    h = np.sinc(k) * np.kaiser(k.size, 8.0)
    h /= h.sum()
    xf = x.astype(np.float32)
    pad = np.pad(xf, ((0, 0), (0, 0), (15, 16)), mode="edge")
    y = np.zeros_like(xf)
    for j in range(h.size):
        y += h[j] * pad[:, :, j:j + xf.shape[2]]
    return np.rint(y).astype(np.int16)


def stats(d):
    d = d[np.isfinite(d)]
    if d.size == 0:
        return "   no picks"
    q = np.percentile(d, [10, 25, 50, 75, 90])
    return f"{q[2]:+7.2f} {q[3] - q[1]:6.2f} {q[4] - q[0]:7.2f}"


def prefiltered(x, fc_hz: float, fs_hz: float) -> np.ndarray:
    """x (int16 [R, 4, n]) through a causal 4-pole Butterworth low-pass at fc_hz: a model of an analogue
    anti-alias filter in front of the ADC (the recording's rate stands in for continuous time)."""
    from scipy.signal import butter

    b, a = butter(4, fc_hz, fs=fs_hz)
    xf = x.astype(float)
    m = xf[:, :, :32].mean(axis=2, keepdims=True)
    return np.rint(lfilter(b, a, xf - m, axis=2) + m).astype(np.int16)


def physics_mae(s, toa_us, starts: int) -> float:
    """A proxy of the board's physics position: travel.fit_travel (velocity, delays, metric) on a random 70 % of
    the drops (seed 0), the core's localiser (localise_batch, `starts` starts, no grid) on the rest; MAE per axis."""
    from impactsense import _core
    from impactsense.signal import SignalConfig
    from impactsense.travel import fit_travel, wants_metric

    cfg = SignalConfig.for_rig(s.rig)
    xy, sens = np.asarray(s.xy_mm, float), cfg.sensor_xy_mm
    train = np.random.default_rng(0).random(len(xy)) < 0.7
    fit = fit_travel(toa_us[train], xy[train], sens, wants_metric(s.rig))
    t = toa_us[~train] - np.asarray(fit.delays_us)[None]
    use = np.isfinite(t).astype(np.uint8)
    out = _core.localise_batch(np.where(use, t, 0).astype(np.float32), use, list(sens[:, 0]), list(sens[:, 1]),
                               float(fit.velocity_mm_per_us), float(cfg.sigma_us), float(cfg.plate_x_mm),
                               float(cfg.plate_y_mm), float(cfg.huber_us), list(fit.metric),
                               list(np.ones(use.size, np.float32)), starts, 0, 0)
    p = np.c_[out["x_mm"], out["y_mm"]]
    ok = np.isfinite(p).all(1)
    return float(np.abs(p[ok] - xy[~train][ok]).mean())


def scan_frames(x, half):
    """50 kHz captures as the board's SAADC scan reads them (channel c c x 5 us after channel 0, as
    board.capture.board_samples lays them on its 200 kHz grid): channels 0 and 2 the recording's even and odd
    samples, channels 1 and 3 `half` (the recording half a 100 kHz sample later) at the same indices."""
    n = x.shape[2] // 2 - 1
    y = np.empty((x.shape[0], 4, n), np.int16)
    y[:, 0], y[:, 2] = x[:, 0, 0:2 * n:2], x[:, 2, 1:2 * n + 1:2]
    y[:, 1], y[:, 3] = half[:, 1, 0:2 * n:2], half[:, 3, 1:2 * n + 1:2]
    return y


def scan_rows(s, x100, c50) -> None:
    """The physics proxy of the core pick on the SAADC scan's captures, its half-sample channels made as the
    emulator makes them (windowed sinc) and linearly: how much the emulated board's figure rests on that choice."""
    linear = x100.copy()
    linear[:, :, :-1] = ((x100[:, :, :-1].astype(np.int32) + x100[:, :, 1:]) // 2).astype(np.int16)
    name = "core pick (threshold + AIC blend)"
    for label, half in (("windowed sinc (the emulator's)", half_sample(x100)), ("linear", linear)):
        t = core_picks(scan_frames(x100, half), c50)[0][name]
        print(f"  SAADC scan, channels 1 and 3 interpolated {label:<31} physics MAE "
              f"{physics_mae(s, t, 1):6.2f} {physics_mae(s, t, 2):6.2f}")


def run(data: str, threshold: float | None = None, prefilter_hz: float = 0.0, physics: bool = False) -> None:
    from impactsense import api
    from impactsense.pipeline import as_int16
    from impactsense.signal import SignalConfig

    s = api.load_session(data)
    host_cfg = SignalConfig.for_rig(s.rig)
    if threshold is not None:
        host_cfg.onset_threshold_counts = float(threshold)
    if host_cfg.fs_hz != 2 * FS:
        print(f"{data}: recorded at {host_cfg.fs_hz:g} Hz, not 100 kHz: skipped")
        return
    x100 = as_int16(s.adc, host_cfg)
    host, hraw = core_picks(x100, host_cfg)   # the reference: the host's pick of the recording as it is
    own, own_raw = host, hraw                 # the 100 kHz pick of what is sampled (the reference rows)
    if prefilter_hz > 0:
        x100 = prefiltered(x100, prefilter_hz, host_cfg.fs_hz)
        own, own_raw = core_picks(x100, host_cfg)
    h_thr = host["core threshold crossing"]
    d = host_cfg.to_dict()
    # The same spans at half the rate (the baseline too: the board's captures have their own pre-trigger, these
    # recordings the logger's, which at 64 samples x 20 us would reach into some arrivals).
    d.update(fs_hz=FS, aic_before=d["aic_before"] // 2, aic_after=d["aic_after"] // 2,
             baseline_samples=d["baseline_samples"] // 2)
    c50 = SignalConfig.from_dict(d)
    picks = []
    for p in (0, 1):
        x = np.ascontiguousarray(x100[:, :, p::2])
        got, raw = core_picks(x, c50)
        base = np.asarray(raw["baseline"], float)
        thr = np.maximum(c50.onset_threshold_counts, c50.onset_noise_factor * np.asarray(raw["noise_rms"], float))
        anchor = got["core threshold crossing"]
        for name, fn in CANDIDATES.items():
            got[name] = fn(x, base, thr, anchor)
        picks.append({k: v + 10.0 * p for k, v in got.items()})

    # The first arrival's energy above 25 kHz (100 kHz recording, 100 us from the host's threshold crossing).
    share = []
    o_thr = own["core threshold crossing"]
    for i, c in zip(*np.nonzero(np.isfinite(o_thr))):
        k0 = int(o_thr[i, c] / 10.0)
        seg = x100[i, c, k0 - 2:k0 + 8].astype(float) - float(own_raw["baseline"][i, c])
        if seg.size == 10:
            spec = np.abs(np.fft.rfft(seg, 64)) ** 2
            f = np.fft.rfftfreq(64, 1e-5)
            share.append(spec[f > 25000].sum() / spec.sum())
    shifted, _ = core_picks(half_sample(x100), host_cfg)

    pre = f", low-passed at {prefilter_hz / 1000:g} kHz before sampling" if prefilter_hz > 0 else ""
    print(f"{data}: {x100.shape[0]} drops x 4 channels, onset threshold {host_cfg.onset_threshold_counts:g} counts "
          f"(or {host_cfg.onset_noise_factor:g} x noise rms){pre}; times in us")
    print(f"  first 100 us of each arrival: energy above 25 kHz, median {np.median(share):.0%} "
          f"(IQR {np.percentile(share, 25):.0%}-{np.percentile(share, 75):.0%})")
    head = f"  {'picker (50 kHz)':<42}{'even - odd: median IQR 10-90':>30}   {'vs 100 kHz threshold: IQR 10-90':>32}"
    print(head + ("   physics MAE mm, 1 / 2 starts" if physics else ""))
    for name in picks[0]:
        dp = picks[0][name] - picks[1][name]
        dh = picks[0][name] - h_thr
        dh = dh - np.nanmedian(dh)
        n = int(np.isfinite(dp).sum())
        mae = f"   {physics_mae(s, picks[0][name], 1):6.2f} {physics_mae(s, picks[0][name], 2):6.2f}" if physics else ""
        print(f"  {name:<42}{stats(dp):>30}   {stats(dh)[8:]:>32}   n {n}{mae}")
    if physics:
        name = "core pick (threshold + AIC blend)"
        print(f"  {'100 kHz core pick (the recording as it is)':<42}{'':>30}   {'':>32}   {'':>6}"
              f"   {physics_mae(s, host[name], 1):6.2f} {physics_mae(s, host[name], 2):6.2f}")
        scan_rows(s, x100, c50)
        if prefilter_hz > 0:
            print(f"  {'100 kHz core pick of the low-passed one':<42}{'':>30}   {'':>32}   {'':>6}"
                  f"   {physics_mae(s, own[name], 1):6.2f} {physics_mae(s, own[name], 2):6.2f}")
    dp = own["core pick (threshold + AIC blend)"] - (shifted["core pick (threshold + AIC blend)"] + 5.0)
    print(f"  {'100 kHz core pick, half-sample sinc shift':<42}{stats(dp):>30}   (sinc pre-rings on a sharp rise)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="+", help="session folders recorded at 100 kHz (or 'bundled')")
    ap.add_argument("--prefilter-hz", type=float, default=0.0, help="low-pass the recordings (4-pole Butterworth) "
                    "before they are sampled at 50 kHz: an anti-alias filter in front of the board's ADC")
    ap.add_argument("--physics", action="store_true", help="also the physics position's MAE from each picker's "
                    "even-phase picks (physics_mae: a proxy, not the export's path)")
    ap.add_argument("--threshold", type=float, help="onset threshold, counts (default: the rig's default; the "
                    "trainer chooses among multiples of it, travel.THRESHOLD_FACTORS)")
    args = ap.parse_args()
    for data in args.data:
        run(data, args.threshold, args.prefilter_hz, args.physics)
    return 0


if __name__ == "__main__":
    sys.exit(main())
