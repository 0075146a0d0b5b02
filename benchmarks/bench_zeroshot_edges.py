"""Where a zero-shot chain's model loses near the plate's edges (issue 15), and which of the localiser's constants
from the calibration drops moves it.

    python3 benchmarks/bench_zeroshot_edges.py DATA --model M

M is the chain's model (`train V --out M --test-fraction 0 --site-map auto`; its card names CAL.json and the
calibration drops). On every drop but the calibration drops, by the distance to the nearest edge and by which
edge is nearest (the edges along x, y = 0 or the plate's y size, or the edges along y):
- the MAE per axis and the median error component toward that edge ("out", mm: positive = placed outwards) of
  the physics position, the threshold and band picks' own positions and the reported position;
- the class accuracy, and the share of drops called high against the share that is high;
- the threshold picks' physics position with the model's constants (the calibration drops' adaptation) and with
  each of them replaced by the rig's own travel fit over all its drops at their true positions (the slowness law:
  velocity and dispersion together; the channel delays; the metric): an oracle no zero-shot model has, which tells the constant that moves the edge bias.
A diagnosis, no target: exits 0.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import chain_model_rows  # noqa: E402

BANDS = ((0, 40), (40, 60), (60, 80), (80, 120), (120, 1e9))


def edge_geometry(xy, rig):
    """Distance to the nearest edge [R], whether it is an edge along x [R], and the outward unit vector [R, 2]."""
    px, py = rig.plate_x_mm, rig.plate_y_mm
    gap = np.stack([xy[:, 0], px - xy[:, 0], xy[:, 1], py - xy[:, 1]], 1)
    k = np.argmin(gap, 1)
    out = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])[k]
    return gap.min(1), k >= 2, out


def by_band(values, err, dist, along_x, what):
    cells = []
    for lo, hi in BANDS:
        for ax in (True, False):
            m = np.isfinite(err) & (dist >= lo) & (dist < hi) & (along_x == ax)
            if m.any():
                cells.append(f"{lo:.0f}-{'' if hi > 1e8 else f'{hi:.0f}'}{'x' if ax else 'y'} {what(values, err, m)}")
    return " | ".join(cells)


def position_table(name, pos, xy, dist, along_x, out):
    err = np.abs(pos - xy).mean(1)
    outward = np.sum((pos - xy) * out, 1)
    cell = lambda v, e, m: f"{np.mean(e[m]):.1f}/{np.median(v[m]):+.1f} (n {int(m.sum())})"  # noqa: E731
    print(f"  {name:14s} MAE {np.nanmean(err):5.2f} | " + by_band(outward, err, dist, along_x, cell))


def oracle_swaps(session, model, rows, xy, dist, along_x, out):
    from impactsense.pipeline import SignalConfig, featurize
    from impactsense.travel import fit_travel, picks

    base = SignalConfig.from_dict(model.signal.to_dict())
    base.band_velocity_mm_per_us, base.band_pick_hz = 0.0, 0.0       # the threshold picks' localiser alone
    toa, period = picks(session.adc[rows], base, with_period=True)   # record time: the delays are the fit's
    fit = fit_travel(toa, xy, base.sensor_xy_mm, True, period, base.fs_hz)
    a = lambda q: (q[0] - q[2]) / 2  # noqa: E731
    print(f"  model: v {base.velocity_mm_per_us:.3f} mm/us, delays {np.round(base.rig_delay_us, 1).tolist()} us, "
          f"metric a {a((base.travel_metric_xx, 0, base.travel_metric_yy)):+.3f}, dispersion "
          f"{base.dispersion_exponent:.2f}; the rig's all-drops fit: v {fit.velocity_mm_per_us:.3f}, delays "
          f"{np.round(fit.delays_us, 1).tolist()}, a {a(fit.metric):+.3f}, dispersion {fit.dispersion_exponent:.2f}")
    swaps = {"model": {}, "all four": None,
             "slowness law": {"velocity_mm_per_us": fit.velocity_mm_per_us,   # its velocity and dispersion together
                              "dispersion_exponent": fit.dispersion_exponent, "dispersion_ref_hz": fit.dispersion_ref_hz},
             "delays": {"rig_delay_us": list(fit.delays_us)},
             "metric": dict(zip(("travel_metric_xx", "travel_metric_xy", "travel_metric_yy"), fit.metric))}
    swaps["all four"] = {k: v for s in list(swaps.values())[2:] for k, v in s.items()}
    for name, fields in swaps.items():
        sig = SignalConfig.from_dict({**base.to_dict(), **fields})
        position_table(name, featurize(session.adc[rows], sig).phys_xy_mm, xy, dist, along_x, out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data")
    ap.add_argument("--model", required=True)
    a = ap.parse_args()
    from impactsense.models import impact_energy_j
    from impactsense.position_members import member_positions

    chain = chain_model_rows(a.data, a.model)
    if chain is None:
        return 2
    session, model, rows, _ = chain
    xy = session.xy_mm[rows].astype(float)
    dist, along_x, out = edge_geometry(xy, session.rig)
    f = model.featurize(session.adc[rows])
    p = model.predict(f)
    print(f"{a.data}: {len(rows)} drops, MAE/out (mm) by the nearest edge's distance (x: an edge along x)")
    members = member_positions(f) or {}
    for name, pos in (("physics", f.phys_xy_mm), *((f"{k} picks", v) for k, v in members.items()),
                      ("reported", p["xy_mm"])):
        position_table(name, np.asarray(pos, float), xy, dist, along_x, out)
    truth = (impact_energy_j(session.height_mm[rows], session.rig.ball_mass_g) >= model.energy_threshold_j)
    cls = np.asarray(p["energy_class"])
    ok = (cls >= 0).astype(float)
    ok[cls < 0] = np.nan
    print("  class (accuracy, called high / high): " + by_band(
        cls, ok, dist, along_x,
        lambda c, e, m: f"{np.mean(c[m] == truth[m]):.2f} ({np.mean(c[m] == 1):.2f}/{np.mean(truth[m]):.2f})"))
    print("the threshold picks' physics position, the model's constants against the rig's all-drops fit (oracle)")
    oracle_swaps(session, model, rows, xy, dist, along_x, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
