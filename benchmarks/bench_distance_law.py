"""The threshold picks' travel residual by the distance to the sensor, and what a distance term in the travel law
gives the core's physics position (issue 15): a diagnosis.

    python3 benchmarks/bench_distance_law.py DATA --model M

M is a model trained on DATA (`impactsense train DATA --out M`; its card's split says which drops were held out).
Printed:
- the centred residual of the usable drops' threshold picks at their true positions (minus the drop's median over
  its channels), by the distance to the sensor: under the model's own travel law (velocity, channel delays and the
  dispersion factor (f / f_ref)^-alpha of each pick's cycle, what the core's localiser reads) and under the velocity
  and delays alone (no dispersion factor), with the picked cycle's median frequency;
- the physics position's MAE per axis on the held-out and the training drops for travel laws fitted on the training
  drops at their true positions (edge_travel.fit_correction's Huber fit of the centred residuals on a law's bases),
  each the core's localiser re-run on the picks less the law's term at its last position (edge_travel.corrected):
  the model's law; d and d^2; edge_travel's bases (d, d^2, the edges' images: the physics_edge member's law);
  near-field bases exp(-d / L); edge_travel's with the near field; a piecewise-linear curve in d (any law of the
  distance alone);
- the dispersion factor of a pick whose cycle's period the core did not find (impactcore pick_period: NaN, so
  factor 1, the reference frequency's speed): that factor fitted on the training drops (soft-L1 of the centred
  residuals at the true positions, as travel.fit_travel) in place of 1 (a period giving that factor put in the
  picks, the core's localiser run again);
- each law's out-of-fold gain over the model's law on the training drops (5 site folds, the law fitted without
  the fold's sites; the per-site gain in standard errors, signed: choose_by_gain's rule would keep a law above +1).
With --train LAW (d2: d and d^2; curve: the piecewise-linear curve in d; near: the near-field bases; none: zero
coefficients, the control: the same wrapping with nothing subtracted, so the host's dispersion factors and the re-run
localiser's own float differences from process_event are measured apart from the law) the law's
coefficients fitted on M's training drops are put into the physics position the forests read, and the model is
trained again on M's split and evaluated (MAE per axis, class, physics): an emulation of the law inside the
core's localiser (the core's process_batch wrapped: the threshold picks localised again through localise_batch on
the picks less the law's term, edge_travel.corrected, averaged with the band picks' position as process_event
does; the feature vector's phys_x_mm / phys_y_mm replaced). Host only: the board's localiser is not changed.
A diagnosis, no target: exits 0.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

DISTANCE_BINS_MM = (0, 60, 100, 150, 250, 400, 1e9)
NEAR_FIELD_MM = (20.0, 60.0)
CURVE_KNOTS_MM = (0, 40, 80, 120, 160, 220, 300, 400, 550, 800)
FOLDS = 5
TRAIN_LAWS = {"d2": "d, d^2", "curve": "a curve in d (piecewise linear)", "near": "near field exp(-d/20), exp(-d/60)",
              "none": "d, d^2"}


def _near(xy, signal, pick_set):
    from impactsense.edge_travel import _metric
    from impactsense.travel import travel_distances

    d = travel_distances(np.asarray(xy, float).reshape(-1, 2), signal.sensor_xy_mm, _metric(signal, pick_set))
    return np.stack([np.exp(-d / scale) for scale in NEAR_FIELD_MM], 2)


def _curve(xy, signal, pick_set):
    """Hat functions of the distance on CURVE_KNOTS_MM: a piecewise-linear curve in d."""
    from impactsense.edge_travel import _metric
    from impactsense.travel import travel_distances

    d = travel_distances(np.asarray(xy, float).reshape(-1, 2), signal.sensor_xy_mm, _metric(signal, pick_set))
    knots = np.asarray(CURVE_KNOTS_MM, float)
    return np.stack([np.interp(d, knots, np.eye(len(knots))[k]) for k in range(len(knots))], 2)


def laws():
    from impactsense.edge_travel import travel_bases

    return {
        "d, d^2": lambda xy, s, p: travel_bases(xy, s, p)[:, :, :2],
        "edge_travel's (d, d^2, edges' images)": travel_bases,
        "near field exp(-d/20), exp(-d/60)": _near,
        "edge_travel's + near field": lambda xy, s, p: np.concatenate([travel_bases(xy, s, p), _near(xy, s, p)], 2),
        "a curve in d (piecewise linear)": _curve,
    }


def unknown_period_factor(raw, signal, xy) -> float:
    """The travel-time factor of the picks without a period that fits the drops (at their true positions) best."""
    from scipy.optimize import minimize_scalar

    from impactsense.edge_travel import _metric, pick_set_arrivals
    from impactsense.travel import travel_distances

    toa, use, scale, v = pick_set_arrivals(raw, signal, "threshold")
    unknown = _unknown(raw) & use
    rows = use.all(1)
    d = travel_distances(xy, signal.sensor_xy_mm, _metric(signal, "threshold"))

    def loss(c):
        r = (toa - d * np.where(unknown, c, scale) / v)[rows]
        r = r - r.mean(1, keepdims=True)
        return float(np.sum(2.0 * (np.sqrt(1.0 + (r / 3.0) ** 2) - 1.0)))

    return float(minimize_scalar(loss, bounds=(0.5, 3.0), method="bounded").x)


def _unknown(raw) -> np.ndarray:
    period = np.asarray(raw["pick_period"], float)
    return ~(np.isfinite(period) & (period > 0))


def with_unknown_factor(raw, signal, factor: float) -> dict:
    """raw with each unknown period replaced by the period whose dispersion factor is `factor`."""
    alpha, ref = float(signal.dispersion_exponent), float(signal.dispersion_ref_hz)
    period = np.asarray(raw["pick_period"], float).copy()
    period[_unknown(raw)] = float(signal.fs_hz) / (ref * factor ** (-1.0 / alpha))
    return {**raw, "pick_period": period}


def _rows(raw: dict, rows: np.ndarray, n: int) -> dict:
    return {k: (np.asarray(v)[rows] if isinstance(v, np.ndarray) and len(v) == n else v) for k, v in raw.items()}


def residual_table(raw, signal, xy) -> None:
    from impactsense.edge_travel import _metric, pick_set_arrivals
    from impactsense.travel import travel_distances

    toa, use, scale, v = pick_set_arrivals(raw, signal, "threshold")     # the core removed the channel delays
    d = travel_distances(xy, signal.sensor_xy_mm, _metric(signal, "threshold"))
    period = np.asarray(raw["pick_period"], float)
    freq = np.where(period > 0, float(signal.fs_hz) / np.where(period > 0, period, 1.0), np.nan)
    print(f"velocity {v:.4f} mm/us, dispersion exponent {float(signal.dispersion_exponent):.3f} "
          f"(f_ref {float(signal.dispersion_ref_hz):.0f} Hz)")
    print("| distance (mm) | picks | residual, model's law (us) | IQR | residual, no dispersion factor (us) | "
          "picked f (kHz) | factor |")
    print("|---|---|---|---|---|---|---|")
    res = {}
    for name, factor in (("law", scale), ("plain", np.ones_like(scale))):
        r = np.where(use, toa - d * factor / v, np.nan)
        res[name] = r - np.nanmedian(r, 1, keepdims=True)
    ok = use.all(1)
    for lo, hi in zip(DISTANCE_BINS_MM[:-1], DISTANCE_BINS_MM[1:]):
        sel = ok[:, None] & (d >= lo) & (d < hi)
        if not sel.any():
            continue
        q = np.percentile(res["law"][sel], [25, 75])
        band = f"{lo:.0f}-{hi:.0f}" if hi < 1e8 else f">= {lo:.0f}"
        print(f"| {band} | {int(sel.sum())} | {np.median(res['law'][sel]):+.1f} | {q[1] - q[0]:.1f} | "
              f"{np.median(res['plain'][sel]):+.1f} | {np.nanmedian(freq[sel]) / 1e3:.1f} | "
              f"{np.median(scale[sel]):.3f} |")


def train_with_law(session, model, law: str) -> dict:
    """M's split trained again with `law` in the physics position the forests read (the module docstring)."""
    import impactsense as isn
    from impactsense import _core
    from impactsense.edge_travel import _localise, corrected, fit_correction
    from impactsense.pipeline import FEATURE_NAMES

    signal, bases = model.signal, laws()[TRAIN_LAWS[law]]
    train = np.asarray(model.card["split"]["train_recordings"], int)
    raw, n = model.featurize(session.adc).raw, len(session.adc)
    xy = np.c_[session.x_mm, session.y_mm].astype(float)
    coef = fit_correction(_rows(raw, train, n), xy[train], signal, "threshold", bases)
    if law == "none":
        coef = [0.0] * len(coef)
    cols = [list(FEATURE_NAMES).index(k) for k in ("phys_x_mm", "phys_y_mm")]
    process = _core.process_batch

    def with_law(a16, core, loc):
        ev = process(a16, core, loc)
        same = (abs(loc.velocity_mm_per_us - signal.velocity_mm_per_us) < 1e-4
                and abs(core.onset_threshold_counts - signal.onset_threshold_counts) < 1e-4
                and loc.localiser_starts == signal.localiser_starts and loc.posterior_grid == signal.posterior_grid)
        if not same:       # another configuration's trial (the threshold's, the starts', a level member's)
            return ev
        r = _core.extract_batch(a16, core)
        thr = corrected(r, signal, "threshold", _localise(r, signal, "threshold", 0.0), coef, bases=bases)
        band = np.asarray(ev["band_xy_mm"], float)
        phys = np.where(np.isfinite(band).all(1)[:, None], 0.5 * (thr + band), thr)
        old = np.asarray(ev["phys_xy_mm"])
        phys = np.where((np.isfinite(old).all(1) & np.isfinite(phys).all(1))[:, None], phys, old)
        vec = np.array(ev["vector"], copy=True)
        vec[:, cols] = phys
        ev["phys_xy_mm"], ev["vector"] = phys.astype(old.dtype), vec
        return ev

    _core.process_batch = with_law
    try:
        trained = isn.train(session, seed=int(model.card["split"]["seed"]), site_map="none")
        ev = isn.evaluate(trained, session)
    finally:
        _core.process_batch = process
    return {"coef": coef, "mae_mm": ev["all"]["mae_mm"], "class": ev["energy_class_accuracy"],
            "physics_mm": ev["physics"]["all"]["mae_mm"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data")
    ap.add_argument("--model", required=True)
    ap.add_argument("--train", choices=sorted(TRAIN_LAWS), default=None,
                    help="train M's split again with this law in the forests' physics position (an emulation)")
    args = ap.parse_args(argv)

    from sklearn.model_selection import GroupKFold

    import impactsense as isn
    from impactsense.correction_scale import _gain_sigmas, _per_site, drop_sites
    from impactsense.edge_travel import _localise, corrected, fit_correction

    session = isn.load_session(args.data)
    model = isn.load_model(args.model)
    signal = model.signal
    split = model.card.get("split", {})
    train = np.asarray(split.get("train_recordings", []), int)
    test = np.asarray(split.get("test_recordings", []), int)
    if not len(train):
        print(f"{args.model}: the card has no split (train_recordings)", file=sys.stderr)
        return 2
    if args.train:
        before = isn.evaluate(model, session)
        after = train_with_law(session, model, args.train)
        name = "zero coefficients (control)" if args.train == "none" else TRAIN_LAWS[args.train]
        print(f"{args.train} ({name}) in the physics position, {args.model}'s split (seed "
              f"{model.card['split']['seed']}): MAE {before['all']['mae_mm']:.2f} -> {after['mae_mm']:.2f} mm, class "
              f"{before['energy_class_accuracy']:.3f} -> {after['class']:.3f}, physics "
              f"{before['physics']['all']['mae_mm']:.2f} -> {after['physics_mm']:.2f}")
        return 0
    feats = model.featurize(session.adc)
    raw, n = feats.raw, len(session.adc)
    xy = np.c_[session.x_mm, session.y_mm].astype(float)
    residual_table(raw, signal, xy)

    start = _localise(raw, signal, "threshold", 0.0)      # the threshold picks' core position

    def err(pos, rows):
        e = np.abs(pos[rows] - xy[rows]).mean(1)
        return np.where(np.isfinite(e), e, np.abs(start[rows] - xy[rows]).mean(1))

    placed = np.isfinite(start).all(1)
    train, test = train[placed[train]], test[placed[test]]
    sites = drop_sites(xy[train])
    base = err(start, train)
    print(f"\nthreshold picks' physics position, MAE per axis (mm): {len(test)} held-out, {len(train)} training drops")
    print("| travel law | held-out | training (in sample) | out of fold | gain (s.e.) |")
    print("|---|---|---|---|---|")
    print(f"| the model's | {err(start, test).mean():.2f} | {base.mean():.2f} | {base.mean():.2f} | - |")
    for name, bases in laws().items():
        coef = fit_correction(_rows(raw, train, n), xy[train], signal, "threshold", bases)
        if coef is None:
            print(f"| {name} | no fit | | | |")
            continue
        pos = corrected(raw, signal, "threshold", start, coef, bases=bases)
        oof = np.full(len(train), np.nan)
        for fit_rows, held in GroupKFold(FOLDS).split(train, groups=sites):
            c = fit_correction(_rows(raw, train[fit_rows], n), xy[train[fit_rows]], signal, "threshold", bases)
            rows = train[held]
            fold_pos = corrected(_rows(raw, rows, n), signal, "threshold", start[rows], c, bases=bases)
            oof[held] = np.where(np.isfinite(fold_pos).all(1), np.abs(fold_pos - xy[rows]).mean(1), base[held])
        z = _gain_sigmas(_per_site(base - oof, sites))       # choose_by_gain's figure, signed
        print(f"| {name} | {err(pos, test).mean():.2f} | {err(pos, train).mean():.2f} | {oof.mean():.2f} | {z:+.2f} |")
    unknown = _unknown(raw) & np.isfinite(np.asarray(raw["toa_us"], float))
    print(f"\npicks without a period: {int(unknown.sum())} of {int(np.isfinite(np.asarray(raw['toa_us'], float)).sum())}")
    if float(signal.dispersion_exponent) <= 0 or not unknown[train].any():
        print("(no dispersion term or no such training pick: the factor is not fitted)")
        return 0
    factor = unknown_period_factor(_rows(raw, train, n), signal, xy[train])
    pos = _localise(with_unknown_factor(raw, signal, factor), signal, "threshold", 0.0)
    oof = np.full(len(train), np.nan)
    folds = []
    for fit_rows, held in GroupKFold(FOLDS).split(train, groups=sites):
        c = unknown_period_factor(_rows(raw, train[fit_rows], n), signal, xy[train[fit_rows]])
        folds.append(c)
        rows = train[held]
        fold_pos = _localise(with_unknown_factor(_rows(raw, rows, n), signal, c), signal, "threshold", 0.0)
        oof[held] = np.where(np.isfinite(fold_pos).all(1), np.abs(fold_pos - xy[rows]).mean(1), base[held])
    z = _gain_sigmas(_per_site(base - oof, sites))
    print("| travel law | held-out | training (in sample) | out of fold | gain (s.e.) |")
    print("|---|---|---|---|---|")
    print(f"| unknown period's factor {factor:.2f} (folds {min(folds):.2f}-{max(folds):.2f}) | {err(pos, test).mean():.2f} | "
          f"{err(pos, train).mean():.2f} | {oof.mean():.2f} | {z:+.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
