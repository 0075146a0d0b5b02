"""Which travel law a zero-shot chain's localiser lacks on an anisotropic rig (issue 15), and which calibration
drops would read it: a diagnosis of the threshold picks' physics position (the core's localiser throughout).

    python3 benchmarks/bench_travel_law.py DATA --model M [--band-cases K]

M is the chain's model (`train V --out M --test-fraction 0 --site-map auto`; its card names CAL.json, the
calibration drops and V, the virtual set it was trained on). On every drop but the calibration drops: the MAE per
axis over the plate, in the band 40-60 mm from the edges along x (y near 0 or the plate's y size: there the
sensor pairs' lines run) with the median error component toward that edge ("out", + outwards), and over the
drops at least 80 mm from every edge ("inner"). The rows:
- the model's constants (the calibration drops' adaptation), the core's position;
- the distance law: the picks corrected by c1 d + c2 d^2 / 100 (edge_travel's first two bases, d the travel
  distance in the model's metric) and localised again by the core (edge_travel.corrected), with (c1, c2) fitted
  on all the rig's drops at their true positions (an oracle), on the virtual drops (the twin's curve, read with
  the virtual drops' own constants), and the twin's c2 with c1 from the calibration drops (what a zero-shot model
  could use); edge_travel's full bases (the edges' images too) fitted on all drops, an oracle;
- the calibration cases: the ellipse (velocity, delays, metric, dispersion: travel.fit_travel) read from four
  cases, the chain's own and K variants that swap the chain's cases, one or two at a time, for the most
  repeatable usable case in the band of the same plate quadrant (calibrate's case table).
A diagnosis, no target: exits 0.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import chain_model_rows  # noqa: E402

BAND_MM = (40.0, 60.0)
INNER_MM = 80.0


def edge_geometry(xy, rig):
    """Distance to the nearest edge [R], whether that edge runs along x [R], the outward unit vector [R, 2]."""
    px, py = rig.plate_x_mm, rig.plate_y_mm
    gap = np.stack([xy[:, 0], px - xy[:, 0], xy[:, 1], py - xy[:, 1]], 1)
    k = np.argmin(gap, 1)
    return gap.min(1), k >= 2, np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])[k]


class Scorer:
    def __init__(self, xy, rows, rig):
        self.xy, self.rows = xy, rows
        self.dist, along_x, self.out = edge_geometry(xy, rig)
        self.band = (self.dist >= BAND_MM[0]) & (self.dist < BAND_MM[1]) & along_x

    def line(self, name, pos):
        r = self.rows
        err = np.abs(pos[r] - self.xy[r]).mean(1)
        out = np.sum((pos[r] - self.xy[r]) * self.out[r], 1)
        band, inner = self.band[r], self.dist[r] >= INNER_MM
        print(f"  {name:44s} MAE {np.nanmean(err):5.2f} | band {np.nanmean(err[band]):5.1f} / "
              f"{np.nanmedian(out[band]):+5.1f} (n {int(band.sum())}) | inner {np.nanmean(err[inner]):5.2f}", flush=True)


def distance_coefficients(raw, xy, signal, rows) -> np.ndarray:
    """(c1, c2) of the threshold picks' centred residuals at the true positions of `rows` (bool [R]) on
    edge_travel's bases d, d^2 / 100 (Huber, as edge_travel.fit_correction)."""
    from impactsense.edge_travel import HUBER_US, pick_set_arrivals, travel_bases
    from impactsense.travel import travel_distances

    toa, use, scale, v = pick_set_arrivals(raw, signal, "threshold")
    metric = (signal.travel_metric_xx, signal.travel_metric_xy, signal.travel_metric_yy)
    res = toa - travel_distances(xy, signal.sensor_xy_mm, metric) * scale / v
    ok = rows & use.all(1) & np.isfinite(res).all(1)
    r = res[ok] - res[ok].mean(1, keepdims=True)
    b = travel_bases(xy[ok], signal, "threshold")[:, :, :2]
    b = b - b.mean(1, keepdims=True)
    a, y = b.reshape(-1, 2), r.ravel()
    w = np.ones(len(y))
    for _ in range(10):
        c = np.linalg.lstsq(a * np.sqrt(w)[:, None], y * np.sqrt(w), rcond=None)[0]
        w = np.minimum(1.0, HUBER_US / np.maximum(np.abs(y - a @ c), 1e-9))
    return c


def with_prior_constants(signal, prior: dict):
    """`signal` with the virtual drops' travel constants (the refit's prior in the card) and unit gains."""
    from impactsense.signal import SignalConfig
    from impactsense.travel import metric_of

    out = SignalConfig.from_dict(signal.to_dict())
    out.velocity_mm_per_us, out.rig_delay_us = prior["velocity_mm_per_us"], list(prior["delays_us"])
    out.travel_metric_xx, out.travel_metric_xy, out.travel_metric_yy = metric_of(prior["metric_a"], prior["metric_b"])
    out.dispersion_exponent, out.channel_gain = prior["alpha"], [1.0, 1.0, 1.0, 1.0]
    return out


def distance_law(session, model, sig, raw, phys, score, calibration):
    from impactsense import edge_travel
    from impactsense.data import load_session
    from impactsense.pipeline import featurize
    from impactsense.travel import travel_distances

    n = edge_travel.N_BASES
    xy = score.xy
    corrected = lambda c: edge_travel.corrected(raw, sig, "threshold", phys, np.r_[c, np.zeros(n - len(c))])  # noqa: E731
    every = np.ones(len(xy), bool)
    c_all = distance_coefficients(raw, xy, sig, every)
    score.line(f"d, d^2 on all drops (oracle: {c_all[0]:+.3f}, {c_all[1]:+.4f})", corrected(c_all))
    cal = np.zeros(len(xy), bool)
    cal[calibration] = True
    c_cal = distance_coefficients(raw, xy, sig, cal)
    score.line(f"d, d^2 on the calibration drops ({c_cal[0]:+.3f}, {c_cal[1]:+.4f})", corrected(c_cal))
    prior = (model.card.get("travel_refit_on_calibration_drops") or {}).get("threshold", {}).get("prior")
    if prior and model.card.get("trained_on"):
        virtual = load_session(model.card["trained_on"])
        vsig = with_prior_constants(sig, prior)
        c_twin = distance_coefficients(featurize(virtual.adc, vsig).raw, virtual.xy_mm.astype(float), vsig,
                                       np.ones(len(virtual), bool))
        # the twin's curvature, the linear part (a slowness change) read again on the calibration drops
        toa_c2 = c_twin[1]
        b = edge_travel.travel_bases(xy, sig, "threshold")
        toa, use, scale, v = edge_travel.pick_set_arrivals(raw, sig, "threshold")
        metric = (sig.travel_metric_xx, sig.travel_metric_xy, sig.travel_metric_yy)
        res = toa - travel_distances(xy, sig.sensor_xy_mm, metric) * scale / v - toa_c2 * b[:, :, 1]
        ok = cal & use.all(1) & np.isfinite(res).all(1)
        r, d = res[ok] - res[ok].mean(1, keepdims=True), b[ok, :, 0] - b[ok, :, 0].mean(1, keepdims=True)
        c1 = float(np.sum(r * d) / np.sum(d * d))
        score.line(f"the twin's d^2 ({toa_c2:+.4f}), d from calibration ({c1:+.3f})", corrected(np.r_[c1, toa_c2]))
        score.line(f"the twin's d, d^2 ({c_twin[0]:+.3f}, {c_twin[1]:+.4f})", corrected(c_twin))
    c_edge = edge_travel.fit_correction(raw, xy, sig, "threshold")
    if c_edge is not None:
        score.line("edge_travel's bases on all drops (oracle)", edge_travel.corrected(raw, sig, "threshold", phys, c_edge))


def case_choices(session, sig, toa, period, score, chain_cases, k_variants):
    from impactsense.calibration.drops import case_table, extract
    from impactsense.pipeline import featurize
    from impactsense.signal import SignalConfig
    from impactsense.travel import fit_travel

    table, _ = case_table(session, extract(session))
    rig = session.rig
    quadrant = lambda r: (r["x"] >= rig.plate_x_mm / 2, r["y"] >= rig.plate_y_mm / 2)  # noqa: E731
    dist, along_x, _ = edge_geometry(np.array([[r["x"], r["y"]] for r in table.values()]), rig)
    in_band = {c: bool(BAND_MM[0] - 10 <= d < BAND_MM[1] + 10 and ax) for c, d, ax in zip(table, dist, along_x)}

    def read(cases, label):
        drops = np.flatnonzero(np.isin(session.case_id, cases))
        f = fit_travel(toa[drops], score.xy[drops], sig.sensor_xy_mm, True, period[drops], sig.fs_hz)
        s = SignalConfig.from_dict(sig.to_dict())
        s.velocity_mm_per_us, s.rig_delay_us = f.velocity_mm_per_us, list(f.delays_us)
        s.travel_metric_xx, s.travel_metric_xy, s.travel_metric_yy = f.metric
        s.dispersion_exponent, s.dispersion_ref_hz = f.dispersion_exponent, f.dispersion_ref_hz
        where = " ".join(f"{c}({table[c]['x']:.0f},{table[c]['y']:.0f})" for c in cases)
        score.line(f"{label}: a {(f.metric[0] - f.metric[2]) / 2:+.3f} {where}", featurize(session.adc, s).phys_xy_mm)

    read(chain_cases, "chain's cases")
    swaps = []
    for i, c in enumerate(chain_cases):
        q = quadrant(table[c])
        cands = sorted((b for b, r in table.items() if r["usable"] and in_band[b] and quadrant(r) == q
                        and b not in chain_cases), key=lambda b: table[b]["spread_us"])
        if cands:
            swaps.append((i, cands[0]))
    variants = [list(s) for n in (1, 2) for s in itertools.combinations(swaps, n)][:k_variants]
    for v in variants:
        cases = list(chain_cases)
        for i, b in v:
            cases[i] = b
        read(cases, f"swap {'+'.join(str(b) for _, b in v)}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data")
    ap.add_argument("--model", required=True)
    ap.add_argument("--band-cases", type=int, default=6, metavar="K")
    a = ap.parse_args()
    from impactsense.pipeline import featurize
    from impactsense.signal import SignalConfig
    from impactsense.travel import picks

    chain = chain_model_rows(a.data, a.model)
    if chain is None:
        return 2
    session, model, rows, calibration = chain
    xy = session.xy_mm.astype(float)
    score = Scorer(xy, rows, session.rig)
    sig = SignalConfig.from_dict(model.signal.to_dict())
    sig.band_velocity_mm_per_us, sig.band_pick_hz = 0.0, 0.0     # the threshold picks' localiser alone
    f = featurize(session.adc, sig)
    phys = np.asarray(f.phys_xy_mm, float)
    print(f"{a.data}: {len(rows)} drops; the threshold picks' physics position, MAE per axis (mm) | band "
          f"{BAND_MM[0]:.0f}-{BAND_MM[1]:.0f} mm from the edges along x: MAE / out | inner (>= {INNER_MM:.0f} mm)")
    score.line("the model's constants", phys)
    distance_law(session, model, sig, f.raw, phys, score, calibration)
    base = SignalConfig.from_dict(sig.to_dict())
    toa, period = picks(session.adc, base, with_period=True)
    chain_cases = [int(c) for c in np.unique(session.case_id[calibration])]
    case_choices(session, sig, toa, period, score, chain_cases, a.band_cases)
    return 0


if __name__ == "__main__":
    sys.exit(main())
