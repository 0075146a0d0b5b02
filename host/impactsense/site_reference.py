"""The reference at the noise floor: each channel's arrival time and energy as smooth functions of where the
ball hit, learned from the reference session.

The physics reference (`residuals.Reference`: straight rays, one velocity, per-channel delays and gains)
leaves a residual that depends on the impact's position and height (the picked onset's dispersion with
distance and amplitude, the plate's edges, the disc's aperture). That systematic part is larger than a moved
sensor's signature, so it is learned: one Gaussian process per channel and group (the drop-centred ToA
residual in µs, the drop-centred log-energy residual) on (x, y, height), fitted to the reference session's
case means (kernel: constant x anisotropic RBF + white noise, hyper-parameters by marginal likelihood).
Its prediction at a session's declared positions rides with the features (`Features.site_toa_us`,
`Features.site_log_energy`) and is added to the physics prediction.

The residual scales the likelihood uses are cross-fitted: each half of the reference's cases is scored
with the terms learned on the other half, so an unchanged session is not judged against an in-sample
(too small) scale. `halves()` gives the same split's DToA residual, the within-case repeatability (the
pick noise no reference can go below) and the reference's own excess over it.

The picks themselves are chosen here too (`choose_picker`): among a few onset thresholds and AIC blends of the
core, the one whose reference (physics + site terms) explains held-out halves of the reference session best.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from . import residuals as R

SCALE_MM = 100.0   # inputs in units of 100 mm: the RBF length-scale bounds below are in these units


def _gp(X, y):
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    import warnings

    from sklearn.exceptions import ConvergenceWarning

    k = (ConstantKernel(1.0, (1e-3, 1e2)) * RBF([1.0, 1.0, 1.0], (0.3, 30.0))
         + WhiteKernel(0.3, (1e-4, 10.0)))
    with warnings.catch_warnings():   # a length-scale at its bound is an answer (flat or rough), not a fault
        warnings.simplefilter("ignore", ConvergenceWarning)
        return GaussianProcessRegressor(k, normalize_y=True, n_restarts_optimizer=0, random_state=0).fit(X, y)


def _inputs(F: R.Features) -> np.ndarray:
    return np.stack([F.x_mm, F.y_mm, F.height_mm], axis=1) / SCALE_MM


def _case_means(F: R.Features, r: np.ndarray, mask: np.ndarray):
    """Per case: mean inputs and the mean of each channel's residual over its masked-in drops."""
    ids, inv = np.unique(F.case_id, return_inverse=True)
    X = np.zeros((len(ids), 3))
    np.add.at(X, inv, _inputs(F))
    X /= np.bincount(inv)[:, None]
    m = mask & np.isfinite(r)
    num = np.zeros((len(ids), 4))
    den = np.zeros((len(ids), 4))
    np.add.at(num, inv, np.where(m, r, 0.0))
    np.add.at(den, inv, m.astype(float))
    return X, num / np.maximum(den, 1), den > 0


@dataclass
class SiteTerms:
    """Per-channel GPs of the ToA (µs) and log-energy residuals of a reference model."""

    toa: list
    energy: list

    def predict(self, F: R.Features) -> tuple[np.ndarray, np.ndarray]:
        X = _inputs(F)
        t = np.stack([g.predict(X) for g in self.toa], axis=1)
        e = np.stack([g.predict(X) for g in self.energy], axis=1)
        return t - t.mean(axis=1, keepdims=True), e

    def attach(self, F: R.Features) -> R.Features:
        t, e = self.predict(F)
        return replace(F, site_toa_us=t, site_log_energy=e)

    def toa_cov(self, F: R.Features, channel: int) -> np.ndarray:
        """[R, R] posterior covariance (µs²) of channel `channel`'s ToA site term at F's drops: how far the
        learned smooth function may be off where F hit (its white-noise part left out: that is the drops'
        own scatter, not the reference's)."""
        g = self.toa[channel]
        _, cov = g.predict(_inputs(F), return_cov=True)
        scale = float(np.atleast_1d(getattr(g, "_y_train_std", 1.0))[0]) ** 2
        white = next((k.noise_level for k in (g.kernel_.k1, g.kernel_.k2) if hasattr(k, "noise_level")), 0.0)
        return np.asarray(cov) - white * scale * np.eye(len(F))


def fit_site(ref: R.Reference, F: R.Features) -> SiteTerms:
    """The site terms of `ref` learned on the session `F` (features without site terms)."""
    ok = np.all(np.isfinite(F.toa_us), axis=1)
    rt = np.where(ok[:, None], ref.toa_resid(F), np.nan)
    re = ref.energy_resid(F)
    unclipped = ~ref.clip_mask(F)
    X, mt, okt = _case_means(F, rt, np.ones_like(unclipped))
    Xe, me, oke = _case_means(F, re, unclipped)
    toa = [_gp(X[okt[:, c]], mt[okt[:, c], c]) for c in range(4)]
    energy = [_gp(Xe[oke[:, c]], me[oke[:, c], c]) for c in range(4)]
    return SiteTerms(toa, energy)


def _half_split(case_id: np.ndarray, seed: int):
    cases = np.unique(case_id)
    rng = np.random.default_rng(seed)
    a = rng.permutation(cases)[: len(cases) // 2]
    in_a = np.isin(case_id, a)
    return np.flatnonzero(in_a), np.flatnonzero(~in_a)


def cross_fitted(ref: R.Reference, F: R.Features, seed: int = 0) -> R.Features:
    """F with each half's site terms predicted by the terms learned on the other half."""
    a, b = _half_split(F.case_id, seed)
    t = np.zeros((len(F), 4))
    e = np.zeros((len(F), 4))
    for train, test in ((a, b), (b, a)):
        site = fit_site(ref, F.subset(train))
        t[test], e[test] = site.predict(F.subset(test))
    return replace(F, site_toa_us=t, site_log_energy=e)


def noise_floor_reference(ref: R.Reference, F: R.Features, seed: int = 0) -> tuple[SiteTerms, dict]:
    """Site terms learned on all of F, and the cross-fitted residual scales that go with them
    (sigma['timing'], sigma['energy'] for `ref.sigma`)."""
    site, sig, _ = noise_floor(ref, F, seed)
    return site, sig


def noise_floor(ref: R.Reference, F: R.Features, seed: int = 0) -> tuple[SiteTerms, dict, dict]:
    """`noise_floor_reference` and, from the same cross-fitted residuals, how much one case's drops share
    their error per position group (`case_correlation.reference_icc`, for `Reference.case_icc`)."""
    from .case_correlation import reference_icc

    Fx = cross_fitted(ref, F, seed)
    rt = ref.toa_resid(Fx)
    sig = {"timing": R.robust_sigma(rt[np.all(np.isfinite(rt), axis=1)]),
           "energy": R.robust_sigma(ref.energy_resid(Fx)[~ref.clip_mask(Fx)])}
    return fit_site(ref, F), sig, reference_icc(ref, Fx)


def dtoa_rms(ref: R.Reference, F: R.Features) -> float:
    pred = ref.toa_pred(F)
    r = (F.toa_us[:, R.PAIR_I] - F.toa_us[:, R.PAIR_J]) - (pred[:, R.PAIR_I] - pred[:, R.PAIR_J])
    return float(np.sqrt(np.nanmean(r ** 2)))


def within_case_dtoa_rms(F: R.Features) -> float:
    """The DToA scatter of repeated drops at one declared position (all pairs pooled): the pick noise plus
    the ball's landing scatter, the floor no reference can go below on single drops."""
    dt = F.toa_us[:, R.PAIR_I] - F.toa_us[:, R.PAIR_J]
    dev, dof = 0.0, 0
    for c in np.unique(F.case_id):
        x = dt[F.case_id == c]
        if len(x) > 1:
            dev += float(np.nansum((x - np.nanmean(x, axis=0)) ** 2))
            dof += (len(x) - 1) * x.shape[1]
    return float(np.sqrt(dev / dof)) if dof else float("nan")


def case_mean_dtoa(ref: R.Reference, F: R.Features) -> tuple[float, float]:
    """(rms over cases of the case-mean DToA residual, the mean 1 / repeats of those cases): what a reference
    is scored on when each position's repeated drops are averaged first (their pick noise / sqrt(repeats))."""
    pred = ref.toa_pred(F)
    r = (F.toa_us[:, R.PAIR_I] - F.toa_us[:, R.PAIR_J]) - (pred[:, R.PAIR_I] - pred[:, R.PAIR_J])
    sq, inv_n = [], []
    for c in np.unique(F.case_id):
        x = r[F.case_id == c]
        n = np.sum(np.isfinite(x), axis=0)
        ok = n > 0
        sq.extend((np.nansum(x[:, ok], axis=0) / n[ok]) ** 2)
        inv_n.extend(1.0 / n[ok])
    return float(np.sqrt(np.mean(sq))), float(np.mean(inv_n))


def halves(F: R.Features, seed: int = 0) -> dict:
    """The reference's DToA residual on held-out halves of one session (reference and site terms fitted on
    one half of the cases, scored on the other, both ways), against the physics reference alone; per drop and
    (`site_case_mean`) on the held-out cases' means, with the share of the pick noise left in such a mean
    (`case_mean_floor`: the within-case floor / sqrt(repeats))."""
    a, b = _half_split(F.case_id, seed)
    sq = {"physics": 0.0, "site": 0.0, "site_case_mean": 0.0}
    directions = []   # (physics, site) scored on the second half, then on the first
    inv_n = 0.0
    for train, test in ((a, b), (b, a)):
        Ftr, Fte = F.subset(train), F.subset(test)
        ref = R.fit_reference(Ftr, "calibrated")
        Fsite = fit_site(ref, Ftr).attach(Fte)
        one = (dtoa_rms(ref, Fte), dtoa_rms(ref, Fsite))
        directions.append(one)
        sq["physics"] += one[0] ** 2 * len(test)
        sq["site"] += one[1] ** 2 * len(test)
        cm, k = case_mean_dtoa(ref, Fsite)
        sq["site_case_mean"] += cm ** 2 * len(test)
        inv_n += k * len(test)
    out = {k: float(np.sqrt(v / len(F))) for k, v in sq.items()}
    out["directions"] = directions
    floor = within_case_dtoa_rms(F)
    out["within_case"] = floor
    out["case_mean_floor"] = float(floor * np.sqrt(inv_n / len(F)))
    out["excess_physics"] = float(np.sqrt(max(out["physics"] ** 2 - floor ** 2, 0.0)))
    out["excess_site"] = float(np.sqrt(max(out["site"] ** 2 - floor ** 2, 0.0)))
    return out



def _null_direction(p_mm: np.ndarray, sensor_xy_mm: np.ndarray, slowness_us_per_mm: float) -> np.ndarray:
    """The unit 4-vector of channel times no change of origin time or of impact position (to first order)
    can make at p_mm: orthogonal to the ones and to the two columns of d ToA / d position."""
    diff = p_mm[None, :] - sensor_xy_mm
    grad = slowness_us_per_mm * diff / np.maximum(np.hypot(diff[:, 0], diff[:, 1]), 1e-6)[:, None]
    q, _ = np.linalg.qr(np.column_stack([np.ones(4), grad]), mode="complete")
    return q[:, 3]


def floor_parts(F: R.Features, ref: R.Reference | None = None) -> dict:
    """What the within-case floor and the reference's excess over it are made of (µs of DToA rms unless named).

    Repeated drops of one case share the declared position; the ball lands a little apart. A landing offset
    moves the four times along d ToA / d position, an origin time along the ones: the one direction left
    (`_null_direction`) holds only timing that no position explains. With independent picks of equal spread
    sigma per channel that direction carries sigma², so:
    - pick_noise: sqrt(2) sigma (the picks' own DToA spread), landing: what the within-case floor holds beyond
      it (0 when the floor is all pick noise);
    - case_timing: the case means' excess in that direction over sigma² / n (x sqrt 2): a per-case timing
      error no mis-marked or scattered position makes (the picks' waveform-dependent bias at that spot);
    - case_shift_mm: the rms position shift per axis the case means ask for beyond their pick noise's share
      (a mis-marked position);
    - case_near / case_far: the case means' DToA residual semivariance (sqrt, less the within-case part) for
      neighbouring cases (closer than 1.5 x the median nearest-case spacing) and for all pairs: equal means
      the per-case error is white at the cases' spacing, which no smooth function of position learns."""
    ref = R.fit_reference(F, "calibrated") if ref is None else ref
    r = F.toa_us - ref.toa_pred(F)
    ids, inv = np.unique(F.case_id, return_inverse=True)
    null_dev, case_null, shifts, means, xy, counts = [], [], [], [], [], []
    for c in range(len(ids)):
        rows = np.flatnonzero(inv == c)
        x = r[rows][np.all(np.isfinite(r[rows]), axis=1)]
        if len(x) < 2:
            continue
        p = np.array([F.x_mm[rows[0]], F.y_mm[rows[0]]])
        nvec = _null_direction(p, F.sensor_xy_mm, ref.slowness_us_per_mm)
        m = x.mean(axis=0)
        null_dev.append(float(np.sum(((x - m) @ nvec) ** 2)) / (len(x) - 1))
        case_null.append(((m @ nvec) ** 2, len(x)))
        diff = p[None, :] - F.sensor_xy_mm
        grad = ref.slowness_us_per_mm * diff / np.hypot(diff[:, 0], diff[:, 1])[:, None]
        design = np.column_stack([np.ones(4), grad])
        sol = np.linalg.lstsq(design, m, rcond=None)[0]
        # the shift's share of the case mean's pick noise (sigma² / n, sigma from the null direction below)
        shifts.append((sol[1:] ** 2, np.diag(np.linalg.inv(design.T @ design))[1:] / len(x)))
        means.append(m - m.mean())
        xy.append(p)
        counts.append(len(x))
    sigma2 = float(np.mean(null_dev))
    floor = within_case_dtoa_rms(F)
    cn = np.array(case_null)
    out = {"within_case": floor, "pick_noise": float(np.sqrt(2.0 * sigma2)),
           "landing": float(np.sqrt(max(floor ** 2 - 2.0 * sigma2, 0.0))),
           "case_timing": float(np.sqrt(2.0 * max(np.mean(cn[:, 0] - sigma2 / cn[:, 1]), 0.0))),
           "case_shift_mm": float(np.sqrt(max(np.mean([sq - sigma2 * unit for sq, unit in shifts]), 0.0)))}
    means, xy, counts = np.array(means), np.array(xy), np.array(counts, float)
    dt = means[:, R.PAIR_I] - means[:, R.PAIR_J]
    dist = np.hypot(xy[:, 0, None] - xy[:, 0], xy[:, 1, None] - xy[:, 1])
    iu = np.triu_indices(len(xy), 1)
    semi = 0.5 * np.mean((dt[:, None, :] - dt[None, :, :]) ** 2, axis=2)[iu]
    noise = 0.5 * floor ** 2 * (1.0 / counts[:, None] + 1.0 / counts[None, :])[iu]
    near = dist[iu] < 1.5 * np.median(np.sort(dist, axis=1)[:, 1])
    out["case_near"] = float(np.sqrt(max(np.mean((semi - noise)[near]), 0.0))) if near.any() else float("nan")
    out["case_far"] = float(np.sqrt(max(np.mean(semi - noise), 0.0)))
    return out


# Timing pickers tried on the reference session: multiples of the rig's onset threshold and AIC blends (1: the
# AIC onset, the default; the rig's configured blend; 0: the threshold crossing), and, when asked for
# (`choose_picker`'s level_sets, e.g. MEAN_LEVEL_SETS), for the crossings (blend < 1) the mean of the picks at
# several multiples (`residuals.core_picks`). Off in `diagnose`: it lowers the held-out DToA on every reference
# tried, and the loop gains on the bundled sessions but loses on another rig's (docs/findings.md, "What the
# reference's floor is made of"). Another than the default is kept when its held-out DToA is below
# PICKER_GAIN x the default's.
PICKER_THRESHOLD_FACTORS = (1.0, 2.0, 3.0)
MEAN_LEVEL_SETS = ((1.0, 2.0), (1.0, 1.5, 2.0, 3.0))
PICKER_BLENDS = (1.0, 0.0)
PICKER_GAIN = 0.9
_PICKERS: dict = {}


def choose_picker(session, F: R.Features | None = None, seed: int = 0,
                  level_sets: tuple = ()) -> tuple[dict | None, list[dict]]:
    """The timing picker (`residuals.extract`'s: core settings and, where the travel fit keeps it, the picks'
    dispersion; None: the default AIC onset) whose reference has the smallest held-out DToA on `session`
    (`halves`, physics + site terms), and the trials. level_sets (tuples of threshold multiples): also the
    mean of the core's picks at each set's thresholds."""
    import hashlib

    from .signal import core_config

    key = (hashlib.sha1(np.ascontiguousarray(session.adc).tobytes()).hexdigest(),
           hashlib.sha1(np.asarray([session.x_mm, session.y_mm, session.height_mm], float).tobytes()).hexdigest(),
           repr(session.rig.to_dict()), seed, tuple(map(tuple, level_sets)))
    if key in _PICKERS:   # a deterministic function of the session: chosen once per baseline
        return _PICKERS[key]
    F = R.extract(session) if F is None else F
    cfg = core_config(session.rig)
    base_thr, rig_blend = float(cfg.onset_threshold_counts), float(cfg.aic_blend)
    blends = list(dict.fromkeys([float(b) for b in (PICKER_BLENDS[0], rig_blend) + PICKER_BLENDS[1:]]))
    candidates = [{"onset_threshold_counts": base_thr * f, "aic_blend": blend}
                  for f in PICKER_THRESHOLD_FACTORS for blend in blends]
    candidates += [{"onset_threshold_counts": base_thr * levels[0], "aic_blend": blend,
                    R.LEVELS_KEY: [base_thr * f for f in levels]}
                   for levels in level_sets for blend in blends if blend < 1.0]
    trials = []
    for picker in candidates:
        is_default = picker == {"onset_threshold_counts": base_thr, "aic_blend": R.TIMING_PICKER["aic_blend"]}
        Fp = F if is_default else R.repick(session, F, picker)
        if np.all(np.isfinite(Fp.toa_us), axis=1).sum() < 8:
            continue
        trials.append({"picker": picker, "heldout_dtoa_us": halves(Fp, seed)["site"]})
        disp = _dispersion(Fp)
        if disp:
            Fd = R.repick(session, F, {**picker, **disp})
            trials.append({"picker": Fd.picker, "heldout_dtoa_us": halves(Fd, seed)["site"]})
    default = trials[0]
    best = min(trials, key=lambda t: t["heldout_dtoa_us"])
    keep = best is not default and best["heldout_dtoa_us"] < PICKER_GAIN * default["heldout_dtoa_us"]
    table = [{**t["picker"], "heldout_dtoa_us": t["heldout_dtoa_us"]} for t in trials]
    _PICKERS[key] = (dict(best["picker"]) if keep else None), table
    return _PICKERS[key]


def _dispersion(F: R.Features) -> dict:
    """The picks' dispersion ({dispersion_exponent, dispersion_ref_hz}) when the travel fit keeps it
    (`travel.fit_travel` with the picked cycles' periods: DISPERSION_GAIN), else {}."""
    from .travel import fit_travel

    try:
        fit = fit_travel(F.toa_us, np.stack([F.x_mm, F.y_mm], axis=1), F.sensor_xy_mm, False, F.pick_period,
                         F.fs_hz)
    except ValueError:
        return {}
    if fit.dispersion_exponent <= 0.0:
        return {}
    return {"dispersion_exponent": fit.dispersion_exponent, "dispersion_ref_hz": fit.dispersion_ref_hz,
            "dispersion_slowness_us_per_mm": 1.0 / fit.velocity_mm_per_us}
