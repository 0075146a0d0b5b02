"""Near-edge energy bias of the twin, from physics (no matcher): which edge model makes it go away?

The zero-shot energy class reads impacts < 30 mm from an edge ~0.017 low in log10 h (bench_zeroshot_class.py).
Here every session-1 case is simulated at its declared position and height (fast path, no noise) with the
calibrated twin, and its 16 twin features (twin.h: 4 channels x log10 arrival energy and Delta^1..3
difference energies) are compared with the measured ones (mean over the case's usable drops, the rig's
signal config for both; the simulated counts unclipped as in the site map):

    r = measured - simulated (log10), per case and feature
    offset = mean r over the control cases (> 80 mm from every edge): the rig's gains and spectral tilt
    bias(bin) = mean over a bin's cases of (r - offset)

and in log10 h: each feature's bias over the twin's slope d feature / d log10 h (from the same cases
simulated 0.1 lower in log10 h), and all 16 combined as the matcher's least-squares height shift
sum w s b / sum w s^2 (w per kind: 1 / the control cases' residual variance of the baseline twin, the
default weights of twin.fit_twin). Negative = the twin's energies there are too high, the event reads low.

Each suspect edge model is the same calibration with other SimParams fields:

    ss        simply supported, hard (w and the tangential rotation held): the twin's
    ss_soft   simply supported, soft (w held, both rotations free)
    rim1e9, rim3e9, rim1e10        elastic_rim, spring on w per metre of edge [N/m per m], free edges
    rim3e9c, rim1e10c              the same with a dashpot (--rim-damping, N s/m per m)
    rim1e10i2                      the stiff rim 2 mm inside the edges

    other suspects as SUPPORT[@FIELD=VALUE...] with any SimParams fields (clamped, free,
    simply_supported@element_mm=1.05, elastic_rim@rim_stiffness_n_m2=1e9@rim_damping_n_s_m2=3000);
    @inner_line=K (diagnostic, energies only): springs K [N/m per m] on w one element inside the held edges,
    a rim of one element's width that resists the edge's rotation (ss@inner_line=1e8)

    python3 benchmarks/bench_edge_energy.py [--calibration CAL.json] [--suspects ss,ss_soft,rim3e9,...]
        [--cache DIR] [--per-feature] [--spectrum] [--workers 2]

    the diagnostics (which way the bias moves; none of them a candidate twin):
    python3 benchmarks/bench_edge_energy.py --suspects ss,clamped,ss@inner_line=1e9,ss@inner_line=1e10,\
        elastic_rim@rim_stiffness_n_m2=1e10@rim_inset_mm=4,simply_supported@damping_per_s=1000,\
        simply_supported@element_mm=1.05 --spectrum

    the discs' mechanical coupling (SimParams.disc_*; the energies' near-edge bias follows the stiffness the
    ceramic adds, docs/findings.md "The disc's bond"):
    python3 benchmarks/bench_edge_energy.py --calibration CAL.json --suspects ss,\
        simply_supported@disc_stiffness_scale=0.51,simply_supported@disc_patch_diameter_mm=14

--spectrum: for the first suspect, the same bias in band energies (0-45 kHz) over [ToA, ToA + 5 ms] and in
broadband energies of time windows after the ToA: where in frequency and in time the deficit sits.

Each suspect costs one reciprocal solve per disc and two contact windows per case (~1-3 min on 2 cores);
the simulated features are cached under --cache by the SimParams they were made with.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import warnings
from itertools import pairwise
from pathlib import Path

import numpy as np
from impactsense.data import load_session
from impactsense.pipeline import SignalConfig, featurize
from impactsense.sim import SimParams, clear_cache, simulate_voltages, to_adc
from impactsense.sitemap import BUNDLED, twin_features

EDGE_BINS_MM = (0, 30, 50, 80, 1000)
KINDS = ("arrival", "diff1", "diff2", "diff3")
DLOG_H = 0.1    # the slope's step in log10 h (the lower height: h / 1.26)

SUSPECTS = {
    "ss": {"support": "simply_supported"},
    "ss_soft": {"support": "simply_supported_soft"},
    "rim1e9": {"support": "elastic_rim", "rim_stiffness_n_m2": 1e9},
    "rim3e9": {"support": "elastic_rim", "rim_stiffness_n_m2": 3e9},
    "rim1e10": {"support": "elastic_rim", "rim_stiffness_n_m2": 1e10},
    "rim3e9c": {"support": "elastic_rim", "rim_stiffness_n_m2": 3e9, "rim_damping_n_s_m2": None},
    "rim1e10c": {"support": "elastic_rim", "rim_stiffness_n_m2": 1e10, "rim_damping_n_s_m2": None},
    "rim1e10i2": {"support": "elastic_rim", "rim_stiffness_n_m2": 1e10, "rim_inset_mm": 2.0},
}


def edge_distance_mm(xy: np.ndarray, rig) -> np.ndarray:
    x, y = xy[:, 0], xy[:, 1]
    return np.minimum.reduce([x, rig.plate_x_mm - x, y, rig.plate_y_mm - y])


def measured_cases(session, signal: SignalConfig) -> dict:
    """Per case: position, height, and the mean of each twin feature over the drops where it is usable."""
    feats, usable = twin_features(featurize(session.adc, signal))
    bits = (usable[:, None].astype(int) >> np.arange(feats.shape[1])[None]) & 1
    f = np.where(bits.astype(bool) & np.isfinite(feats), feats, np.nan)
    cases = np.unique(session.case_id)
    first = np.array([np.flatnonzero(session.case_id == c)[0] for c in cases])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # a feature no drop of the case has usable
        mean = np.array([np.nanmean(f[session.case_id == c], 0) if np.isfinite(f[session.case_id == c]).any()
                         else np.full(f.shape[1], np.nan) for c in cases])
    return {"case": cases, "xy": session.xy_mm[first], "h": session.height_mm[first], "feats": mean}


def simulated_features(params: SimParams, rig, xy: np.ndarray, h: np.ndarray, signal: SignalConfig,
                       workers: int) -> np.ndarray:
    """The twin features [n, 16] of noiseless simulated drops (unclipped counts, as in the site map)."""
    res = simulate_voltages(params, rig, xy[:, 0], xy[:, 1], h, method="fast", workers=workers)
    counts = to_adc(res["volts"], params, rig, clip=False)
    sig = SignalConfig.from_dict(signal.to_dict())
    sig.adc_min, sig.adc_max = -32768, 32767
    feats, usable = twin_features(featurize(counts, sig))
    bits = (usable[:, None].astype(int) >> np.arange(feats.shape[1])[None]) & 1
    return np.where(bits.astype(bool), feats, np.nan)


def add_inner_line(params: SimParams, rig, stiffness_n_m2: float) -> None:
    """Diagnostic only (energies; bench_support cannot score it): springs on w along the node lines one
    element inside the edges of the cached model of `params` (held edges), i.e. a rim of one element's width
    that also resists the edge's rotation (~ stiffness x h^2 per metre). The springs are far below the
    stability limit for stiffness <= 1e10 N/m per m (node omega ~1e6 rad/s against dt ~0.5 us)."""
    from impactsense.sim.model import rim_springs
    from impactsense.sim.simulate import get_model

    model = get_model(params, rig)
    line = SimParams(support="elastic_rim", rim_stiffness_n_m2=stiffness_n_m2, rim_inset_mm=model.hx_m * 1e3)
    k, _ = rim_springs(model.nx, model.ny, model.hx_m, model.hy_m, line)
    model.plate.set_node_springs(np.ascontiguousarray(k.ravel()), np.zeros(k.size))


def suspect_features(params: SimParams, rig, cases: dict, signal: SignalConfig, cache: Path,
                     workers: int, inner_line: float = 0.0) -> dict:
    """Features at the declared heights and DLOG_H lower, cached by the SimParams (and inner_line)."""
    key = hashlib.sha256(json.dumps([params.to_dict(), cases["xy"].tolist(), cases["h"].tolist(), DLOG_H]
                                    + ([inner_line] if inner_line else []), sort_keys=True).encode()).hexdigest()[:16]
    path = cache / f"edge-energy-{key}.npz"
    if path.is_file():
        with np.load(path) as z:
            return {"at": z["at"], "low": z["low"]}
    clear_cache()
    if inner_line:
        add_inner_line(params, rig, inner_line)
    xy = np.vstack([cases["xy"], cases["xy"]])
    h = np.concatenate([cases["h"], cases["h"] / 10 ** DLOG_H])
    f = simulated_features(params, rig, xy, h, signal, workers)
    clear_cache()   # the reciprocal fields (~230 MB) of this suspect
    n = cases["h"].size
    out = {"at": f[:n], "low": f[n:]}
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, **out)
    return out


def bias_table(meas: np.ndarray, sim: np.ndarray, slope: np.ndarray, edge: np.ndarray,
               weight: np.ndarray | None = None) -> dict:
    """Per edge bin: the mean of (measured - simulated - control offset) per feature [16] and in log10 h
    (per feature over the slope, and the weighted least-squares shift of all 16). weight None: 1 / the
    control cases' residual variance per kind (returned, to score other suspects with the same weights)."""
    r = meas - sim
    control = edge >= EDGE_BINS_MM[-2]
    offset = np.nanmean(r[control], 0)
    dev = r - offset[None]
    nk = len(KINDS)
    if weight is None:
        var = np.array([np.nanmean(dev[control][:, k::nk] ** 2) for k in range(nk)])
        weight = np.tile(1.0 / var, dev.shape[1] // nk)
    ws = weight * slope
    ok = np.isfinite(dev)
    shift = np.where(ok, dev, 0.0) @ ws / np.maximum(ok @ (ws * slope), 1e-12)   # per case, log10 h
    bins = []
    for a, b in pairwise(EDGE_BINS_MM):
        m = (edge >= a) & (edge < b)
        bins.append({"lo": a, "hi": b, "n": int(m.sum()), "feature": np.nanmean(dev[m], 0),
                     "shift": float(np.mean(shift[m])), "shift_sd": float(np.std(shift[m], ddof=1))})
    return {"offset": offset, "weight": weight, "bins": bins, "case_shift": shift}


def suspect_params(base: SimParams, spec: str, rim_damping: float) -> SimParams:
    """A named suspect (SUSPECTS) or SUPPORT[@FIELD=VALUE...] (any SimParams fields, e.g.
    elastic_rim@rim_stiffness_n_m2=1e9@rim_damping_n_s_m2=3000, simply_supported@element_mm=1.05)."""
    name, *extra = spec.split("@")
    extra = [kv for kv in extra if not kv.startswith("inner_line=")]
    if name in SUSPECTS:
        fields = {k: (rim_damping if v is None else v) for k, v in SUSPECTS[name].items()}
    else:
        fields = {"support": name}
    for kv in extra:
        key, _, val = kv.partition("=")
        if key not in SimParams.field_names() or not val:
            raise SystemExit(f"suspect {spec!r}: {kv!r} is not FIELD=VALUE with a SimParams field")
        fields[key] = bool(int(val)) if isinstance(getattr(base, key), bool) else float(val)
    rim = {k: 0.0 for k in ("rim_stiffness_n_m2", "rim_damping_n_s_m2", "rim_inset_mm")}
    return base.replace(**{**rim, **fields})


def inner_line(spec: str) -> float:
    """@inner_line=K of a suspect spec: add_inner_line's stiffness [N/m per m] (0: none)."""
    vals = [float(kv.split("=", 1)[1]) for kv in spec.split("@")[1:] if kv.startswith("inner_line=")]
    return vals[-1] if vals else 0.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calibration", default=str(BUNDLED.parent / "calibration.json"))
    ap.add_argument("--suspects", default="ss,ss_soft,rim1e9,rim3e9,rim1e10,rim3e9c,rim1e10c,rim1e10i2")
    ap.add_argument("--rim-damping", type=float, default=1000.0, help="the dashpot of the *c suspects [N s/m per m]")
    ap.add_argument("--cache", default="/tmp/impactsense-bench-edge-energy")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--per-feature", action="store_true", help="also the per-channel, per-kind bias of each suspect")
    ap.add_argument("--spectrum", action="store_true",
                    help="also the first suspect's near-edge bias per frequency band and per time window after the ToA")
    args = ap.parse_args()

    session = load_session("bundled:session-1")
    rig = session.rig
    signal = SignalConfig.for_rig(rig)
    base = SimParams.from_json(args.calibration)
    cases = measured_cases(session, signal)
    edge = edge_distance_mm(cases["xy"], rig)
    names = args.suspects.split(",")
    print(f"calibration {args.calibration}; {edge.size} cases: "
          + ", ".join(f"{a}-{b} mm {np.sum((edge >= a) & (edge < b))}" for a, b in pairwise(EDGE_BINS_MM))
          + f"; control > {EDGE_BINS_MM[-2]} mm", flush=True)

    results, weight = {}, None
    for name in names:
        p = suspect_params(base, name, args.rim_damping)
        f = suspect_features(p, rig, cases, signal, Path(args.cache), args.workers, inner_line(name))
        slope = np.nanmedian((f["at"] - f["low"]) / DLOG_H, 0)
        res = bias_table(cases["feats"], f["at"], slope, edge, weight)
        weight = res["weight"] if weight is None else weight     # the first suspect's weights for all
        res["slope"] = slope
        results[name] = res
        print(f"{name} done", flush=True)

    report(results, names, edge)
    if args.spectrum:
        spectrum_report(session, suspect_params(base, names[0], args.rim_damping), cases, edge, signal, args.workers)
    if args.per_feature:
        for name in names:
            per_feature(results[name], name)
    return 0


BANDS_HZ = ((0, 300), (300, 1000), (1000, 2000), (2000, 5000), (5000, 10000), (10000, 20000), (20000, 45000))
WINDOWS_MS = ((0, 0.25), (0.25, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 3.5), (3.5, 5.0))


def band_window_energies(adc: np.ndarray, toa_us: np.ndarray, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """log10 energy of each channel [R, 4, band] in BANDS_HZ over [ToA, ToA + 5 ms] (Butterworth, zero
    phase) and [R, 4, window] in WINDOWS_MS after the ToA (broadband); NaN where the channel has no ToA."""
    from scipy.signal import butter, sosfiltfilt

    x = adc.astype(float) - np.median(adc[..., :150].astype(float), -1, keepdims=True)
    n5 = int(round(5e-3 * fs_hz))
    r, c = x.shape[:2]
    i0 = np.where(np.isfinite(toa_us), np.rint(np.nan_to_num(toa_us) * 1e-6 * fs_hz), -1).astype(int)
    bands = np.full((r, c, len(BANDS_HZ)), np.nan)
    for k, (lo, hi) in enumerate(BANDS_HZ):
        sos = butter(4, hi, "lowpass", fs=fs_hz, output="sos") if lo == 0 else \
            butter(4, [lo, hi], "bandpass", fs=fs_hz, output="sos")
        y = sosfiltfilt(sos, x, axis=-1) ** 2
        for a in range(r):
            for b in range(c):
                if i0[a, b] >= 0:
                    bands[a, b, k] = np.log10(y[a, b, i0[a, b]:i0[a, b] + n5].sum())
    wins = np.full((r, c, len(WINDOWS_MS)), np.nan)
    for k, (t0, t1) in enumerate(WINDOWS_MS):
        j0, j1 = int(round(t0 * 1e-3 * fs_hz)), int(round(t1 * 1e-3 * fs_hz))
        for a in range(r):
            for b in range(c):
                if i0[a, b] >= 0:
                    wins[a, b, k] = np.log10(np.sum(x[a, b, i0[a, b] + j0:i0[a, b] + j1] ** 2))
    return bands, wins


def spectrum_report(session, params: SimParams, cases: dict, edge: np.ndarray, signal: SignalConfig,
                    workers: int) -> None:
    """Where in frequency and in time after the arrival the near-edge deficit sits (one suspect)."""
    rig = session.rig
    meas = featurize(session.adc, signal)
    toa = np.where(meas.clipped, np.nan, meas.toa_us)
    bm, wm = band_window_energies(session.adc, toa, rig.fs_hz)
    per_case = lambda a: np.array([np.nanmean(a[session.case_id == c], 0) for c in cases["case"]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        bm, wm = per_case(bm), per_case(wm)
    res = simulate_voltages(params, rig, cases["xy"][:, 0], cases["xy"][:, 1], cases["h"], method="fast",
                            workers=workers)
    clear_cache()
    counts = to_adc(res["volts"], params, rig, clip=False)
    sig = SignalConfig.from_dict(signal.to_dict())
    sig.adc_min, sig.adc_max = -32768, 32767
    bs, ws = band_window_energies(counts, featurize(counts, sig).toa_us, rig.fs_hz)
    control = edge >= EDGE_BINS_MM[-2]
    for title, m, s_, labels in (("band energy in [ToA, ToA + 5 ms]", bm, bs, [f"{a / 1e3:g}-{b / 1e3:g} kHz" for a, b in BANDS_HZ]),
                                 ("energy in windows after the ToA", wm, ws, [f"{a:g}-{b:g} ms" for a, b in WINDOWS_MS])):
        r = m - s_
        dev = r - np.nanmean(r[control], 0)
        print(f"\n{params.support}: near-edge bias of the {title} (log10, measured - twin, control offset removed, "
              "mean over channels)")
        print("| bin | " + " | ".join(labels) + " |")
        print("|---" * (len(labels) + 1) + "|")
        for a, b in pairwise(EDGE_BINS_MM):
            sel = (edge >= a) & (edge < b)
            label = f"{a}-{b} mm" if b < 1000 else f">{a} mm"
            print(f"| {label} | " + " | ".join(f"{np.nanmean(dev[sel][..., k]):+.3f}" for k in range(len(labels))) + " |")
        print("| control case sd | " + " | ".join(f"{np.nanstd(np.nanmean(dev[control][..., k], 1), ddof=1):.3f}"
                                         for k in range(len(labels))) + " |")


def report(results: dict, names: list[str], edge: np.ndarray) -> None:
    first = results[names[0]]
    bins = [f"{b['lo']}-{b['hi']}" if b["hi"] < 1000 else f">{b['lo']}" for b in first["bins"]]
    print("\nnear-edge bias in log10 h (weighted 16-feature shift; mean over the bin's cases; control offset removed)")
    print("| suspect | " + " | ".join(f"{b} mm" for b in bins) + " | <30 minus >80 | control case sd |"
          " control offset vs first (log10, mean abs) | per kind <30 mm (arr/d1/d2/d3, log10 h) |")
    print("|---" * (len(bins) + 5) + "|")
    for name in names:
        r = results[name]
        b = r["bins"]
        kinds = near_edge_by_kind(r)
        d_off = float(np.nanmean(np.abs(r["offset"] - first["offset"])))
        print(f"| {name} | " + " | ".join(f"{x['shift']:+.4f}" for x in b)
              + f" | {b[0]['shift'] - b[-1]['shift']:+.4f} | {b[-1]['shift_sd']:.4f} | {d_off:.3f} | "
              + " / ".join(f"{v:+.3f}" for v in kinds) + " |")


def near_edge_by_kind(r: dict) -> np.ndarray:
    """Per kind, the < 30 mm bin's bias over the slope, averaged over channels (log10 h)."""
    b = r["bins"][0]["feature"] / r["slope"]
    return np.array([np.nanmean(b[k::len(KINDS)]) for k in range(len(KINDS))])


def per_feature(r: dict, name: str) -> None:
    print(f"\n{name}: bias per feature (log10; in brackets over the slope, log10 h), control offset removed")
    print("| bin | " + " | ".join(f"ch{c} {k}" for c in range(4) for k in KINDS) + " |")
    for b in r["bins"]:
        label = f"{b['lo']}-{b['hi']}" if b["hi"] < 1000 else f">{b['lo']}"
        print(f"| {label} | " + " | ".join(f"{v:+.3f} ({v / s:+.3f})" for v, s in zip(b["feature"], r["slope"])) + " |")
    print("| slope | " + " | ".join(f"{s:.2f}" for s in r["slope"]) + " |")


if __name__ == "__main__":
    raise SystemExit(main())
