"""A parametric onset fit of each channel's first cycles against the core's picks (a study for issues 15 and 16, no
target; nothing of it is in the core).

    python3 benchmarks/bench_pulse_pick.py noise SESSION CONTROL [--draws 2] [--white W] [--set FIELD=VALUE ...]
    python3 benchmarks/bench_pulse_pick.py rig DATA [--set FIELD=VALUE ...] [--edge-mm 80]

The fit (Python prototype, on the core's own outputs: its baseline, its threshold crossing and its picked period,
`_core.extract_batch` through `pipeline.featurize`): on the window from --before periods before the core's threshold
crossing to --after periods after it, the channel (counts, the core's baseline removed) is fitted by

    m(t) = A u^k exp(-u / tau) sin(2 pi f u),  u = t - t0 > 0;  0 before t0

(k fixed, --k; A, t0, f and 1 / tau fitted, with --chirp a linear chirp q too (phase 2 pi f u + q u^2 / 2): a coarse grid of t0 over the window's first part and of tau, A by
linear least squares at each, then --iters Levenberg-damped Gauss-Newton steps on all four). t0 is the pick.
Pickers compared: the core's pick (toa_us: crossing + blend x AIC), the threshold crossing, the AIC onset, the band
pick (when --set band_pick_hz is given), the fit's t0 ("fit") and the fitted sine's last zero before the crossing
("fit zero": the fit's phase, not its envelope), and "fit, shape held": A and t0 alone fitted with each channel's
shape (log f, log 1 / tau, chirp) held at a quadratic in the declared sensor distance, fitted to the free fits of
the clean drops (noise: CONTROL's; rig: DATA's own, in sample): the waveform known up to its distance, an upper
bound of what a shape from the position could give; "fit crossing": where the fitted model first reaches the core's
threshold (the crossing with the noise fitted out). Also printed: the fit's rms misfit over the window's rms.
docs/findings.md "Session 25: pulsefit" reads it.

noise: CONTROL is SESSION's drops without the white noise (bench_loop's `noise` / `noise-control`). Per picker and
channel the robust sd (1.4826 MAD) of the pick on the noisy drops less the same drop's clean pick (the same
settings), for SESSION as recorded and for --draws more draws of --white counts on CONTROL (loop_sessions'
signal model); and the picks' centred residual about a smooth function of position (below), clean and noisy.
rig: each drop's per-channel centred pick (less the drop's mean over its channels) about a smooth function of the
declared position (least squares on the distances to the four sensors, their |dx|, |dy| and a cubic in x, y),
split into the per-case part (robust sd, 1.4826 MAD, of each case's mean residual: what rigc7's timing oracle calls the per-case
bias) and the within-case part, over the plate, within --edge-mm of an edge and beyond.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_noise_picks  # noqa: E402


def core_raw(adc, cfg):
    from impactsense.pipeline import featurize
    return featurize(adc, cfg).raw


# ---- the fit ---------------------------------------------------------------------------------------------------

def _model(u, k, a, w, r, q=0.0):
    """m and its partials (d/dA, d/dt0, d/dw, d/dr, d/dq) at u = t - t0 (zero for u <= 0); r = 1 / tau, w = 2 pi f,
    q the chirp (phase w u + q u^2 / 2)."""
    pos = u > 0
    uu = np.where(pos, u, 0.0)
    e = np.exp(-r * uu)
    ph = w * uu + 0.5 * q * uu * uu
    s, c = np.sin(ph), np.cos(ph)
    uk = uu ** k
    base = uk * e * s
    du = a * e * (k * np.where(pos, uu ** (k - 1), 0.0) * s - r * uk * s + (w + q * uu) * uk * c)
    jac = np.stack([base, -du, a * uk * e * uu * c, -a * uk * uu * e * s, 0.5 * a * uk * e * uu * uu * c], -1)
    return a * base, np.where(pos[..., None], jac, 0.0)


def fit_onsets(x: np.ndarray, crossing: np.ndarray, period: np.ndarray, k: float = 2.0, before: float = 2.0,
               after: float = 1.5, iters: int = 8, fixed: tuple[int, ...] = (), shape=None,
               threshold: np.ndarray | None = None) -> dict:
    """Per row of x [R, N] (counts, baseline removed; crossing, period [R] in samples): t0, the fitted sine's last
    zero before the crossing ("zero"), both in samples, the fit's rms misfit / the window's rms, and the fitted
    shape w (rad / sample), r (1 / tau, 1 / sample), q (chirp). NaN where there is no crossing or the fit leaves the
    window. fixed: parameters (2: w, 3: r, 4: q, 0 at the start) held at the coarse start's values. shape: given
    (w, r, q) arrays [R], the start uses them (t0 on the grid, A by least squares) and only A and t0 are fitted.
    threshold [R] (counts): also "cross", where the fitted model's |m| first reaches it (0.05-sample grid; NaN if
    it does not within the window): the threshold crossing with the noise fitted out."""
    names = ("t0", "zero", "misfit", "w", "r", "q", "cross")
    res_ = {n: np.full(len(x), np.nan) for n in names}
    if shape is not None:
        fixed = (2, 3, 4)
    for i in range(len(x)):
        ic, p = crossing[i], period[i]
        if not (np.isfinite(ic) and np.isfinite(p)) or p <= 1.0:
            continue
        lo, hi = int(np.floor(ic - before * p)), int(np.ceil(ic + after * p)) + 1
        lo, hi = max(lo, 0), min(hi, x.shape[1])
        if hi - lo < 6:
            continue
        t = np.arange(lo, hi, dtype=float)
        y = x[i, lo:hi]
        w0 = 2 * np.pi / p
        shapes = [(w0, 1.0 / (tau_p * p), 0.0) for tau_p in (0.5, 1.0, 2.0, 4.0)]
        if shape is not None:
            if not all(np.isfinite(v[i]) for v in shape):
                continue
            w0 = shape[0][i]
            shapes = [(w0, shape[1][i], shape[2][i])]
        best = (np.inf, None)
        # coarse start: t0 in quarter periods over the window's first part, tau in periods; A by least squares
        for t0 in np.arange(lo - 0.25 * p, ic, 0.25 * p):
            for w_, r, q in shapes:
                b, _ = _model(t - t0, k, 1.0, w_, r, q)
                bb = float(b @ b)
                if bb <= 0:
                    continue
                a = float(b @ y) / bb
                cost = float(np.sum((y - a * b) ** 2))
                if cost < best[0]:
                    best = (cost, np.array([a, t0, w_, r, q]))
        if best[1] is None:
            continue
        th, cost, lam = best[1], best[0], 1e-3
        for _ in range(iters):
            m, j = _model(t - th[1], k, *th[[0, 2, 3, 4]])
            j[:, list(fixed)] = 0.0
            res = y - m
            jtj, jtr = j.T @ j, j.T @ res
            try:
                step = np.linalg.solve(jtj + lam * np.diag(np.diag(jtj) + 1e-12), jtr)
            except np.linalg.LinAlgError:
                break
            cand = th + step
            cand[2] = np.clip(cand[2], 0.3 * w0, 3.0 * w0)
            cand[3] = max(cand[3], 0.0)
            m2, _ = _model(t - cand[1], k, *cand[[0, 2, 3, 4]])
            c2 = float(np.sum((y - m2) ** 2))
            if c2 < cost:
                th, cost, lam = cand, c2, lam * 0.3
            else:
                lam *= 10.0
        if lo - p <= th[1] <= ic:
            half = np.pi / th[2]
            cross = np.nan
            if threshold is not None:
                tt = np.arange(lo, hi, 0.05)
                above = np.abs(_model(tt - th[1], k, *th[[0, 2, 3, 4]])[0]) >= threshold[i]
                cross = tt[np.argmax(above)] if above.any() else np.nan
            for n, v in zip(names, (th[1], th[1] + half * np.floor((ic - th[1]) / half), np.sqrt(cost / float(y @ y)),
                                    th[2], th[3], th[4], cross)):
                res_[n][i] = v
    return res_


def picks(adc, cfg, args, shape=None) -> dict:
    """{picker: ToA us [D, C]} of the core's outputs and the fit; "misfit" the fit's relative misfit and "_w", "_r",
    "_q" its shape [D, C]. shape: (w, r, q) [D, C] given: the fit holds it ("fit, shape held")."""
    raw = core_raw(adc, cfg)
    us = 1e6 / float(cfg.fs_hz)
    x = np.asarray(adc, float) - np.asarray(raw["baseline"], float)[..., None]
    d, c, n = x.shape
    period = np.asarray(raw["pick_period"], float)
    period = np.where(np.isfinite(period), period, np.nanmedian(period))
    cross = np.asarray(raw["toa_threshold"], float)
    # the core's onset threshold (impactcore.h: the larger of onset_threshold_counts and onset_noise_factor x noise)
    thr = np.maximum(float(cfg.onset_threshold_counts), float(cfg.onset_noise_factor) * np.asarray(raw["noise_rms"]))
    fit = fit_onsets(x.reshape(d * c, n), cross.ravel(), period.ravel(), args.k, args.before, args.after,
                     args.iters, tuple(args.fixed) + (() if args.chirp else (4,)), threshold=thr.ravel())
    fit = {k_: v.reshape(d, c) for k_, v in fit.items()}
    out = {"core": np.asarray(raw["toa_us"], float), "crossing": cross * us,
           "aic": np.asarray(raw["toa_aic"], float) * us, "fit": fit["t0"] * us, "fit zero": fit["zero"] * us,
           "fit crossing": fit["cross"] * us, "misfit": fit["misfit"], "_w": fit["w"], "_r": fit["r"], "_q": fit["q"]}
    if shape is not None:
        held = fit_onsets(x.reshape(d * c, n), cross.ravel(), period.ravel(), args.k, args.before, args.after,
                          args.iters, shape=tuple(np.ravel(v) for v in shape))
        out["fit, shape held"] = held["t0"].reshape(d, c) * us
    band = np.asarray(raw["toa_band_us"], float)
    if np.isfinite(band).any():
        out["band"] = band
    return out


def shape_of_distance(p: dict, dist: np.ndarray, dist_new: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each channel's fitted shape (log w, log r, q) as a quadratic in the sensor distance (least squares over the
    drops whose fit is within 3 robust sd of the median), evaluated at dist_new [D, C]: the shape a drop at that
    distance would be fitted with if the waveform depended on the distance only."""
    out = []
    for key, f, inv in (("_w", np.log, np.exp), ("_r", np.log, np.exp), ("_q", None, None)):
        v = p[key] if f is None else f(np.maximum(p[key], 1e-9))
        res = np.full(dist_new.shape, np.nan)
        for ch in range(v.shape[1]):
            ok = np.isfinite(v[:, ch])
            med = np.nanmedian(v[ok, ch])
            sd = max(1.4826 * np.nanmedian(np.abs(v[ok, ch] - med)), 1e-9)
            ok &= np.abs(v[:, ch] - med) < 3 * sd
            if ok.sum() < 10:
                res[:, ch] = med
                continue
            coef = np.polyfit(dist[ok, ch], v[ok, ch], 2)
            res[:, ch] = np.polyval(coef, dist_new[:, ch])
        out.append(res if inv is None else inv(res))
    return tuple(out)


def distances(xy: np.ndarray, sensors: np.ndarray) -> np.ndarray:
    return np.hypot(xy[:, None, 0] - sensors[None, :, 0], xy[:, None, 1] - sensors[None, :, 1])


# ---- smooth functions of position --------------------------------------------------------------------------------

def basis(xy: np.ndarray, sensors: np.ndarray, size: tuple[float, float]) -> np.ndarray:
    dx = xy[:, None, 0] - sensors[None, :, 0]
    dy = xy[:, None, 1] - sensors[None, :, 1]
    u, v = xy[:, 0] / size[0] - 0.5, xy[:, 1] / size[1] - 0.5
    poly = [np.ones_like(u), u, v, u * u, u * v, v * v, u ** 3, u * u * v, u * v * v, v ** 3]
    return np.column_stack([np.hypot(dx, dy), np.abs(dx), np.abs(dy), *poly])


def centred_residual(toa: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Each channel's pick less the drop's mean over its channels, less its least-squares smooth function of position
    (NaN where a channel has no pick)."""
    cen = toa - np.nanmean(toa, 1, keepdims=True)
    out = np.full_like(cen, np.nan)
    for ch in range(toa.shape[1]):
        ok = np.isfinite(cen[:, ch])
        if ok.sum() > b.shape[1] + 5:
            coef, *_ = np.linalg.lstsq(b[ok], cen[ok, ch], rcond=None)
            out[ok, ch] = cen[ok, ch] - b[ok] @ coef
    return out


def parts(res: np.ndarray, case: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(robust sd of the case means, robust sd within the cases) per channel (each drop counts once)."""
    means = np.full_like(res, np.nan)
    for cid in np.unique(case):
        m = case == cid
        means[m] = np.nanmean(res[m], 0)
    within = res - means
    return robust_sd(means), robust_sd(within)


def fmt(v) -> str:
    return " ".join(f"{x:5.2f}" for x in v)


def robust_sd(d):
    return bench_noise_picks.robust_sd(d)


def run_noise(args, cfg) -> None:
    from impactsense.data import load_session

    sess, ctl = load_session(args.session), load_session(args.control)
    assert np.array_equal(sess.case_id, ctl.case_id), "SESSION and CONTROL must be the same drops"
    b = basis(np.asarray(ctl.xy_mm, float), np.asarray(cfg.sensor_xy_mm, float), (ctl.rig.plate_x_mm, ctl.rig.plate_y_mm))
    t = time.time()
    dist = distances(np.asarray(ctl.xy_mm, float), np.asarray(cfg.sensor_xy_mm, float))
    shape = shape_of_distance(picks(ctl.adc, cfg, args), dist, dist)   # the clean drops' shapes by distance
    clean = picks(ctl.adc, cfg, args, shape)
    noisy = [picks(sess.adc, cfg, args, shape)]
    misfit = (clean.pop("misfit"), noisy[0].pop("misfit"))
    for j in range(args.draws):
        truth = {"effect": "noise", "sensor": None, "params": {"noise_counts_rms": args.white}}
        noisy.append(picks(bench_noise_picks.changed_adc(ctl, truth, 1000 + j), cfg, args, shape))
    print(f"{args.session} against {args.control}: {len(ctl)} drops, the session + {args.draws} draws of "
          f"{args.white:g} counts ({time.time() - t:.0f} s); the fit's rms misfit / the window's rms, median: clean "
          f"{np.nanmedian(misfit[0]):.3f}, the session {np.nanmedian(misfit[1]):.3f}")
    print(f"  {'picker':9s} {'noisy - clean, robust sd per channel (us)':44s} {'failed':>6s}  "
          f"{'residual robust sd about position: clean':34s} noisy")
    for name in [k_ for k_ in clean if not k_.startswith("_")]:
        sd = np.nanmean([robust_sd(n[name] - clean[name]) for n in noisy], 0)
        fail = np.mean([np.mean(~np.isfinite(n[name])) for n in noisy])
        rc = robust_sd(centred_residual(clean[name], b))
        rn = np.nanmean([robust_sd(centred_residual(n[name], b)) for n in noisy], 0)
        print(f"  {name:9s} {fmt(sd):24s} (mean {np.mean(sd):5.2f})        {fail:6.3f}  {fmt(rc):24s} "
              f"(mean {np.mean(rc):5.2f})  {fmt(rn)} (mean {np.mean(rn):5.2f})", flush=True)


def run_rig(args, cfg) -> None:
    from impactsense.data import load_session

    s = load_session(args.data)
    xy = np.asarray(s.xy_mm, float)
    b = basis(xy, np.asarray(cfg.sensor_xy_mm, float), (s.rig.plate_x_mm, s.rig.plate_y_mm))
    edge = np.minimum.reduce([xy[:, 0], s.rig.plate_x_mm - xy[:, 0], xy[:, 1], s.rig.plate_y_mm - xy[:, 1]])
    near = edge < args.edge_mm
    t = time.time()
    dist = distances(xy, np.asarray(cfg.sensor_xy_mm, float))
    p = picks(s.adc, cfg, args, shape_of_distance(picks(s.adc, cfg, args), dist, dist))
    misfit = p.pop("misfit")
    print(f"{args.data}: {len(s)} drops, {len(np.unique(s.case_id))} cases, {near.sum()} within {args.edge_mm:g} mm "
          f"of an edge ({time.time() - t:.0f} s); the fit's rms misfit / the window's rms, median "
          f"{np.nanmedian(misfit):.3f}")
    print(f"  {'picker':9s} {'per-case sd per channel (us)':36s} {'near':>6s} {'beyond':>6s}  within-case sd")
    for name, toa in p.items():
        if name.startswith("_"):
            continue
        res = centred_residual(toa, b)
        pc, wc = parts(res, s.case_id)
        pn, _ = parts(np.where(near[:, None], res, np.nan), s.case_id)
        pb, _ = parts(np.where(near[:, None], np.nan, res), s.case_id)
        print(f"  {name:9s} {fmt(pc)} (mean {np.mean(pc):5.2f}) {np.mean(pn):6.2f} {np.mean(pb):6.2f}  {fmt(wc)} "
              f"(mean {np.mean(wc):5.2f}); no pick {np.mean(~np.isfinite(toa)):.3f}", flush=True)


def main(argv=None) -> int:
    from impactsense.data import load_session
    from impactsense.signal import SignalConfig

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="mode", required=True)
    a = sub.add_parser("noise")
    a.add_argument("session")
    a.add_argument("control")
    a.add_argument("--draws", type=int, default=2)
    a.add_argument("--white", type=float, default=9.76)
    r = sub.add_parser("rig")
    r.add_argument("data")
    r.add_argument("--edge-mm", type=float, default=80.0)
    for p in (a, r):
        p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
        p.add_argument("--k", type=float, default=2.0)
        p.add_argument("--before", type=float, default=2.0, help="window start, periods before the crossing")
        p.add_argument("--after", type=float, default=1.5, help="window end, periods after the crossing")
        p.add_argument("--iters", type=int, default=8)
        p.add_argument("--fixed", type=int, nargs="*", default=[], help="hold f (2), 1 / tau (3)")
        p.add_argument("--chirp", action="store_true", help="fit a linear chirp too (held at 0 without it)")
    args = ap.parse_args(argv)
    overrides = {k: (int(v) if v.lstrip("-").isdigit() else float(v)) for k, v in (s.split("=", 1) for s in args.set)}
    rig = load_session(args.control if args.mode == "noise" else args.data).rig
    cfg = SignalConfig.for_rig(rig, **overrides)
    print(f"picks with {overrides or 'the rig configuration'}; fit k {args.k:g}, window {args.before:g} periods "
          f"before the crossing to {args.after:g} after, {args.iters} steps")
    (run_noise if args.mode == "noise" else run_rig)(args, cfg)
    return 0


if __name__ == "__main__":
    sys.exit(main())
