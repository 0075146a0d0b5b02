"""Is a laminate's near-edge timing bias the edges' reflections or the A0 wave's dispersion? The twin, with and
without edges near the impacts, picked at several onset thresholds.

    python3 benchmarks/bench_edge_cause.py DATA [--margin 150] [--e1 57.1 --e2 16.0 --g12 11.4]
                                           [--picks 10/0,30/0,50/0.2] [--save NPZ | --load NPZ]

DATA's cases (one drop each, at the case's declared position and height) are simulated by the FEM twin (fast path)
twice: on DATA's plate ("edges"), and on the same laminate with every edge moved `--margin` mm outwards, the
sensors and the impacts moved with the plate's interior ("far edges": every reflection then trails the direct
arrival by at least 2 x margin of path, long after the onset the core picks). Both go through the same logger
(the circuit gain set so the median channel peak is DATA's, DATA's quiet-start noise, one seed). For each
threshold/blend pair (the core's onset threshold in counts and AIC blend, the trainer's choices) the core picks
all three sets (the twin with edges, without, DATA's drops); each set's travel law (`travel.fit_travel`: velocity,
delays, the travel metric, the dispersion exponent when kept) is fitted on its own drops at their positions, and
the rms of the centred residuals at the declared positions is printed by distance to DATA's nearest edge, with
the pick shift the edges alone cause (edges minus far edges, the same drop, centred) and DATA's case means (the
per-case timing bias of docs/findings.md "Session 27: rigcmt"). If the near-edge excess is the edges'
reflections it is gone on the far-edge plate; dispersion (a pick that depends on the travel distance and
direction) is in both. The default laminate is Session 21's calibration of the CFRP rig (E1 57.1, E2 16.0, G12
11.4 GPa); nothing is tuned. ~5 min simulating at load 20 (--load skips it). docs/findings.md "Session 28:
rigcmt2" reads it.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

BANDS = ((0, 35), (35, 60), (60, 80), (80, np.inf))
PICKS = "10/0,20/0,30/0,50/0.2,50/0.35,80/0.2"


def edge_distance(xy, w, h):
    return np.minimum.reduce([xy[:, 0], w - xy[:, 0], xy[:, 1], h - xy[:, 1]])


def case_table(session):
    cases = np.unique(session.case_id)
    first = np.array([np.flatnonzero(session.case_id == c)[0] for c in cases])
    return cases, session.xy_mm[first], session.height_mm[first]


def shifted_rig(rig, margin, samples, pretrigger):
    """DATA's rig with every edge `margin` mm further out (sensors kept where they are on the laminate)."""
    from impactsense.data import rig_from_dict

    raw = dict(rig.raw)
    raw["plate_x_mm"] = rig.plate_x_mm + 2 * margin
    raw["plate_y_mm"] = rig.plate_y_mm + 2 * margin
    raw["sensors"] = [{**s, "x_mm": s["x_mm"] + margin, "y_mm": s["y_mm"] + margin} for s in rig.raw["sensors"]]
    raw["samples"] = samples
    raw["pretrigger_samples"] = pretrigger
    raw.pop("inner_region_mm", None)
    return rig_from_dict(raw)


def simulate(params, rig, xy, h):
    from impactsense.sim.simulate import clear_cache, simulate_voltages

    t = time.time()
    res = simulate_voltages(params, rig, xy[:, 0], xy[:, 1], h, method="fast", workers=1)
    clear_cache()
    print(f"  simulated {len(h)} drops on {rig.plate_x_mm:.0f} x {rig.plate_y_mm:.0f} mm in {time.time() - t:.0f} s",
          flush=True)
    return np.asarray(res["volts"])


def to_counts(volts, gain, rig, pre, noise, seed):
    n, c, m = volts.shape
    rec = np.zeros((n, c, rig.samples))
    take = min(m, rig.samples - pre)
    rec[:, :, pre:pre + take] = volts[:, :, :take] * gain
    rec += np.random.default_rng(seed).normal(0.0, noise, rec.shape)
    return np.clip(np.rint(rig.bias_counts + rec), 0, rig.adc_max).astype(np.uint16)


def residuals(toa, period, xy, sensors, fs):
    """Centred travel residuals (us) under the picks' own fit_travel (metric, dispersion when kept)."""
    from impactsense.travel import fit_travel, slowness_scales, travel_distances

    fit = fit_travel(toa, xy, sensors, True, period, fs)
    d = travel_distances(xy, sensors, fit.metric) * slowness_scales(period, fs, fit.dispersion_exponent,
                                                                    fit.dispersion_ref_hz)
    r = toa - d / fit.velocity_mm_per_us - np.asarray(fit.delays_us)[None]
    return r - np.nanmean(r, 1, keepdims=True)


def by_band(r, edge) -> str:
    return " ".join(f"{np.sqrt(np.nanmean(r[(edge >= lo) & (edge < hi)] ** 2)):5.2f}" for lo, hi in BANDS)


def twin_drops(args, session, xy, h):
    """{"edges": adc, "far": adc} and the two rigs: DATA's cases simulated with and without near edges."""
    from impactsense.sim.params import SimParams

    rig, pre = session.rig, 200
    n_sim = int(round(args.duration_ms * 1e-3 * rig.fs_hz))
    rigs = {"edges": shifted_rig(rig, 0.0, pre + n_sim + 50, pre),
            "far": shifted_rig(rig, args.margin, pre + n_sim + 50, pre)}
    if args.load:
        z = np.load(args.load)
        return {k: z[k] for k in rigs}, rigs
    quiet = session.adc[:, :, :session.rig.pretrigger_samples - 10].astype(float)
    noise = float(np.median(np.std(quiet, axis=2)))
    peak = float(np.median(np.abs(session.adc.astype(float) - np.median(quiet, axis=2, keepdims=True)).max(2)))
    out, gain = {}, None
    for name, r in rigs.items():
        margin = args.margin if name == "far" else 0.0
        params = SimParams.from_rig(r, e_pa=args.e1 * 1e9, e2_pa=args.e2 * 1e9, g12_pa=args.g12 * 1e9,
                                    duration_ms=args.duration_ms, taper_ms=0.1, pretrigger_samples=pre)
        volts = simulate(params, r, xy + margin, h)
        gain = peak / float(np.median(np.abs(volts).max(2))) if gain is None else gain
        out[name] = to_counts(volts, gain, r, pre, noise, 0)
    print(f"  the logger: noise {noise:.2f} counts rms, the median channel peak {peak:.0f} counts (DATA's)")
    if args.save:
        np.savez(args.save, **out)
    return out, rigs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data")
    ap.add_argument("--margin", type=float, default=150.0)
    ap.add_argument("--e1", type=float, default=57.1)
    ap.add_argument("--e2", type=float, default=16.0)
    ap.add_argument("--g12", type=float, default=11.4)
    ap.add_argument("--duration-ms", type=float, default=1.2)
    ap.add_argument("--picks", default=PICKS, help="threshold/blend pairs, comma separated")
    ap.add_argument("--save", default=None, help="save the simulated counts (npz)")
    ap.add_argument("--load", default=None, help="read them from a --save file instead of simulating")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", category=UserWarning)
    from impactsense.data import load_session
    from impactsense.signal import SignalConfig
    from impactsense.travel import picks

    session = load_session(args.data)
    rig = session.rig
    cases, xy, h = case_table(session)
    edge = edge_distance(xy, rig.plate_x_mm, rig.plate_y_mm)
    drops, rigs = twin_drops(args, session, xy, h)
    counts = [int(((edge >= lo) & (edge < hi)).sum()) for lo, hi in BANDS]
    print(f"{session.name}: {len(cases)} cases; by distance to the nearest edge {', '.join(f'{lo:.0f}-{hi:.0f}' for lo, hi in BANDS)}"
          f" mm: {counts} cases. Per band, rms of the centred travel residual (us) under each pick set's own travel fit:")
    print("  threshold/blend | twin, edges | twin, far edges | pick shift by the edges (edges - far) | DATA's case means")
    cfg = SignalConfig.for_rig(rig)
    for pair in args.picks.split(","):
        thr, blend = (float(v) for v in pair.split("/"))
        over = dict(onset_threshold_counts=thr, aic_blend=blend)
        tp = {k: picks(drops[k], SignalConfig.for_rig(rigs[k]), with_period=True, **over) for k in drops}
        shift = {k: args.margin if k == "far" else 0.0 for k in drops}
        res = {k: residuals(*tp[k], xy + shift[k], rigs[k].sensor_xy_mm.astype(float), rig.fs_hz) for k in drops}
        moved = tp["edges"][0] - tp["far"][0]
        moved = moved - np.nanmean(moved, 1, keepdims=True)
        toa, period = picks(session.adc, cfg, with_period=True, **over)
        r = residuals(toa, period, session.xy_mm, rig.sensor_xy_mm.astype(float), rig.fs_hz)
        means = np.array([np.nanmean(r[session.case_id == c], 0) for c in cases])
        print(f"  {thr:4.0f}/{blend:<4g} | {by_band(res['edges'], edge)} | {by_band(res['far'], edge)} | "
              f"{by_band(moved, edge)} | {by_band(means, edge)}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
