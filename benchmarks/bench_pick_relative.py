"""Onset picks relative to each channel's own arrival, against the trained fixed thresholds: do they take the
edges' reflections out of a laminate's near-edge timing, and does a physics position follow?

    python3 benchmarks/bench_pick_relative.py DATA [--seeds 0,1,2,3] [--only NAME,NAME]

Every pick is the core's (its baseline, noise floor, transient rejection, crossing and pick period through the
binding); the candidates read back from or scale the core's own crossing:

- `T/b`: the core's pick at a fixed onset threshold T (counts) and AIC blend b (the trainer's choices);
- `zc30`: the baseline crossing that starts the half cycle the 30-count threshold caught (amplitude-free);
- `pk30`: the first extremum after the 30-count crossing less a quarter of the picked period (the onset read back
  from the first peak);
- `peak F`: the core's threshold pick at F x the channel's peak over the capture (at least 10 counts; the core's
  channel gain carries the per-drop threshold, only the ToA is read);
- `first F`: at F x the largest |x| within three picked periods after the 10-count crossing (the first arrival's
  own peak, before most reflections);
- `gate`: (needs the drop's position: an oracle bound, not a product candidate) the 50 / 0.2 pick, replaced by the
  30 / 0 pick (plus their median offset) on a channel whose 50 / 0.2 pick lies later behind its 10-count pick than
  the earliest edge image (the four first-order images at the declared position, the travel law's metric and
  velocity of the 10-count picks) trails the direct arrival: a window that ends before the earliest reflection.

For each: the rms of the case means of the centred travel residual (us) under the picks' own `travel.fit_travel`
(metric, dispersion when kept) by distance to the nearest edge (0-35 / 35-60 / 60-80 / >= 80 mm, as
bench_edge_cause.py), over all cases, and within a case; then the held-out physics MAE per axis (mm) at split seeds
`--seeds` (travel.fit_travel on the training 80 % of cases, then a Huber TDOA grid search, 2 mm, over the plate:
one simple localiser for every candidate, not the product's). ~5 min per rig at load 15.
docs/findings.md "Session 29: peakthr" reads it.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_edge_cause import BANDS, edge_distance, residuals  # noqa: E402


def core_raw(adc, cfg, **over):
    """The core's per-channel features at the overrides (the rig's delays off)."""
    from impactsense import _core
    from impactsense.pipeline import as_int16
    from impactsense.signal import SignalConfig

    trial = SignalConfig.from_dict({**cfg.to_dict(), "rig_delay_us": [0.0] * 4, **over})
    return _core.extract_batch(as_int16(adc, trial), trial.core())


def half_cycle_start(x: np.ndarray, cross: float) -> float:
    """The baseline crossing (sub-sample) that starts the half cycle holding the threshold crossing `cross`."""
    i = int(cross)
    sign = np.sign(x[i + 1])
    j = i
    while j > 0 and np.sign(x[j]) == sign:
        j -= 1
    a, b = x[j], x[j + 1]
    return j + a / (a - b)


def first_extremum(x: np.ndarray, cross: float) -> int:
    """The index of the first extremum after the crossing (|x| stops growing within the half cycle)."""
    i = int(cross) + 1
    sign = np.sign(x[i])
    while i + 1 < len(x) and np.sign(x[i + 1]) == sign and abs(x[i + 1]) >= abs(x[i]):
        i += 1
    return i


def read_back(adc, cfg, fs, threshold):
    """zc and pk picks (us, capture delay not removed) from the core's crossing at `threshold`, with its periods."""
    raw = core_raw(adc, cfg, onset_threshold_counts=threshold, aic_blend=0.0)
    us = 1e6 / fs
    zc = np.full(raw["toa_us"].shape, np.nan)
    pk = np.full(raw["toa_us"].shape, np.nan)
    for r, c in zip(*np.nonzero(raw["toa_threshold"] >= 0)):
        x = adc[r, c].astype(float) - raw["baseline"][r, c]
        cross = float(raw["toa_threshold"][r, c])
        zc[r, c] = half_cycle_start(x, cross) * us
        pk[r, c] = (first_extremum(x, cross) - raw["pick_period"][r, c] / 4.0) * us
    return zc, pk, raw["pick_period"].astype(float)


def per_channel_threshold(adc, cfg, threshold):
    """The core's threshold picks (us) and periods with a threshold per drop and channel [R, 4] (counts): the
    channel gain carries it (threshold x gain, base 10 counts); only the ToA and the period are read."""
    from impactsense.signal import SignalConfig

    toa = np.full(threshold.shape, np.nan)
    per = np.full(threshold.shape, np.nan)
    base = {**cfg.to_dict(), "aic_blend": 0.0, "onset_threshold_counts": 10.0}
    for r in range(adc.shape[0]):
        trial = SignalConfig.from_dict({**base, "channel_gain": [float(v) / 10.0 for v in threshold[r]]})
        raw = core_raw(adc[r:r + 1], trial)
        toa[r], per[r] = raw["toa_us"][0], raw["pick_period"][0]
    return toa, per


def earliest_reflection_us(xy, sensors, w, h, metric, velocity):
    """How long the earliest first-order edge image trails the direct arrival at each channel (us) [R, 4]."""
    from impactsense.travel import travel_distances

    direct = travel_distances(xy, sensors, metric)
    images = (np.c_[-xy[:, 0], xy[:, 1]], np.c_[2 * w - xy[:, 0], xy[:, 1]],
              np.c_[xy[:, 0], -xy[:, 1]], np.c_[xy[:, 0], 2 * h - xy[:, 1]])
    return np.min([travel_distances(i, sensors, metric) - direct for i in images], 0) / velocity


def candidates(session, cfg, only):
    from impactsense.travel import fit_travel

    rig, adc = session.rig, session.adc
    out = {}
    for thr, blend in ((10, 0.0), (30, 0.0), (50, 0.2)):
        raw = core_raw(adc, cfg, onset_threshold_counts=thr, aic_blend=blend)
        out[f"{thr}/{blend:g}"] = (raw["toa_us"].astype(float), raw["pick_period"].astype(float))
    zc, pk, per = read_back(adc, cfg, rig.fs_hz, 30.0)
    out["zc30"], out["pk30"] = (zc, per), (pk, per)
    low = core_raw(adc, cfg, onset_threshold_counts=10.0, aic_blend=0.0)
    for f in (0.02, 0.03, 0.05):
        out[f"peak {f:g}"] = per_channel_threshold(adc, cfg, np.maximum(f * low["peak"].astype(float), 10.0))
    first = np.zeros(low["peak"].shape)
    for r, c in zip(*np.nonzero(low["toa_threshold"] >= 0)):
        p = low["pick_period"][r, c] if low["pick_period"][r, c] > 0 else 10.0
        cross = float(low["toa_threshold"][r, c])
        first[r, c] = np.abs(adc[r, c, int(cross):int(cross + 3 * p) + 2].astype(float) - low["baseline"][r, c]).max()
    for f in (0.1, 0.2):
        out[f"first {f:g}"] = per_channel_threshold(adc, cfg, np.maximum(f * first, 10.0))
    sensors = rig.sensor_xy_mm.astype(float)
    law = fit_travel(out["10/0"][0], session.xy_mm, sensors, True, None, None)
    gap = earliest_reflection_us(session.xy_mm, sensors, rig.plate_x_mm, rig.plate_y_mm, law.metric,
                                 law.velocity_mm_per_us)
    hi, lo = out["50/0.2"], out["30/0"]
    late = (hi[0] - out["10/0"][0]) > gap
    out["gate (oracle)"] = (np.where(late, lo[0] + np.nanmedian(hi[0] - lo[0]), hi[0]), np.where(late, lo[1], hi[1]))
    print(f"  the earliest edge image trails the direct arrival by {np.median(gap):.1f} us (median; < 20 us on "
          f"{np.mean(gap < 20):.0%} of the channels); picks later than it behind the 10-count pick: 30/0 "
          f"{np.nanmean((lo[0] - out['10/0'][0]) > gap):.0%}, 50/0.2 {np.mean(late):.0%}")
    return {k: v for k, v in out.items() if not only or k in only}


def locate(fit, toa, period, sensors, fs, w, h, step=2.0, huber=4.0):
    """Each drop's position (mm) on a step-mm grid: least Huber cost of the centred travel residuals."""
    from impactsense.travel import slowness_scales, travel_distances

    gx, gy = np.meshgrid(np.arange(0.0, w + 1e-9, step), np.arange(0.0, h + 1e-9, step))
    grid = np.c_[gx.ravel(), gy.ravel()]
    t_grid = travel_distances(grid, sensors, fit.metric) / fit.velocity_mm_per_us
    out = np.full((len(toa), 2), np.nan)
    for i in range(len(toa)):
        t = toa[i] - np.asarray(fit.delays_us)
        if not np.all(np.isfinite(t)):
            continue
        scale = slowness_scales(period[i:i + 1], fs, fit.dispersion_exponent, fit.dispersion_ref_hz)[0] \
            if fit.dispersion_exponent else np.ones(len(t))
        r = t[None] - t_grid * scale[None]
        r = r - r.mean(1, keepdims=True)
        a = np.abs(r)
        out[i] = grid[np.argmin(np.where(a < huber, 0.5 * r ** 2, huber * (a - 0.5 * huber)).sum(1))]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data")
    ap.add_argument("--seeds", default="0,1,2,3")
    ap.add_argument("--only", default="", help="candidate names, comma separated (default: all)")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", category=UserWarning)
    from impactsense.data import load_session
    from impactsense.signal import SignalConfig
    from impactsense.split import case_split
    from impactsense.travel import fit_travel

    t0 = time.time()
    session = load_session(args.data)
    rig = session.rig
    sensors = rig.sensor_xy_mm.astype(float)
    cases = np.unique(session.case_id)
    first = np.array([np.flatnonzero(session.case_id == c)[0] for c in cases])
    edge = edge_distance(session.xy_mm[first], rig.plate_x_mm, rig.plate_y_mm)
    seeds = [int(s) for s in args.seeds.split(",")]
    print(f"{session.name}: {len(cases)} cases, by distance to the nearest edge "
          f"{[int(((edge >= lo) & (edge < hi)).sum()) for lo, hi in BANDS]} (0-35 / 35-60 / 60-80 / >= 80 mm)")
    cands = candidates(session, SignalConfig.for_rig(rig), [s for s in args.only.split(",") if s])
    print("  pick | case means' rms by band (us) | all cases | within a case | held-out physics MAE (mm) by seed | mean")
    for name, (toa, period) in cands.items():
        r = residuals(toa, period, session.xy_mm, sensors, rig.fs_hz)
        means = np.array([np.nanmean(r[session.case_id == c], 0) for c in cases])
        within = r - means[np.searchsorted(cases, session.case_id)]
        band = " ".join(f"{np.sqrt(np.nanmean(means[(edge >= lo) & (edge < hi)] ** 2)):5.2f}" for lo, hi in BANDS)
        mae = []
        for seed in seeds:
            train, test = case_split(session.case_id, 0.2, seed)
            fit = fit_travel(toa[train], session.xy_mm[train], sensors, True, period[train], rig.fs_hz)
            xy = locate(fit, toa[test], period[test], sensors, rig.fs_hz, rig.plate_x_mm, rig.plate_y_mm)
            mae.append(float(np.nanmean(np.abs(xy - session.xy_mm[test]))))
        print(f"  {name:13s} | {band} | {np.sqrt(np.nanmean(means ** 2)):5.2f} | {np.sqrt(np.nanmean(within ** 2)):5.2f}"
              f" | {' '.join(f'{v:5.2f}' for v in mae)} | {np.mean(mae):5.2f}", flush=True)
    print(f"  ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
