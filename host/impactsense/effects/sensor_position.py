"""sensor_position: the disc is not where rig.json says. Units: mm.

Physical meaning: a bonding offset moves sensor i by (dx, dy). Its ToA changes by -s (u_x dx + u_y dy), u
the unit vector from the sensor to the impact: a direction-dependent timing signature. A shift along the
sensor's mean look direction is nearly a constant delay; the two are rivals, not nested: the selection
compares their held-out log-likelihoods (`channel_delay` on the same sensor), so a move is named only where
the data tell its direction dependence from a constant delay.

The energy model keeps the declared position (`Reference.energy_sensor_xy_mm`): a re-glued disc's energy
did not follow the moved path lengths (on FEM sessions with a known move the true offset's energy term,
geometric law or the reference's site map shifted with the disc, scored below no move at all:
docs/findings.md), so the move is told by its timing alone.

Fit: the linearised timing least squares gives (dx, dy); a 2-D search of the timing log-likelihood (Huber)
around it refines them, with the band picks' log-likelihood added where the reference has them (the move
changes their path too, at their own slowness: `impactsense.band_timing`).

Move or delay (`direction_test`): a constant delay is exactly constant over the impacts, a move is not. The
channel's ToA against the others' (y_k = r_ki - mean_j r_kj: what a change on channel i does to the drop-centred
residual, t0 gone) is regressed on [1, -s u_x, -s u_y]: the constant takes whatever a delay (or a move's mean
part) explains, and the two direction coefficients are the move's direction-dependent part. Their Wald test
uses a standard error that knows where the noise is: the drops of one case share their pick and landing error,
so it is a delete-a-case jackknife (cluster-robust with its small-sample correction, not drop-level), and the
reference itself is uncertain where the session hit (its site terms' posterior covariance at these drops,
`site_reference.SiteTerms.toa_cov`, a smooth error shared across neighbouring cases) and is added. Hotelling's
T² -> F(2, G - 2) with G cases.

Move or delay by the band picks (`band_test`): a delay shifts the channel's whole recording, so its threshold
pick and its band pick (`impactsense.band_timing`) by the same amount; a move changes the path, and each pick
moves by its own slowness times the path change (a dispersive plate's low band travels slower). The band pick's
shift minus the threshold pick's is zero for a delay whatever its size, along the look direction too.

Both pick sets at once (`joint_test`): the threshold and the band picks' contrasts in one regression, a constant
shared by both (a delay) and one move whose signature is each pick set's own slowness times -u. It weighs the
direction dependence of both pick sets and the band picks' larger shift along the look direction together, so
a move that each of the two tests above reads only weakly can still reject a constant (docs/findings.md).
"""

import numpy as np
from scipy import optimize, stats

from ..band_timing import band_resid
from ..residuals import huber_ll
from ._base import Effect, fit_timing, geometry, shift_channels


class SensorPosition(Effect):
    name = "sensor_position"
    units = {"dx_mm": "mm", "dy_mm": "mm", "offset_mm": "mm"}
    meaning = "sensor centre offset from its declared position"
    min_offset_mm = 2.0

    def fit(self, ref, F, sensor):
        _, _, ux, uy = ref.geometry(F)
        s = ref.slowness_us_per_mm
        n = len(F)
        cx, cy = np.zeros((n, 4)), np.zeros((n, 4))
        cx[:, sensor] = -s * ux[:, sensor]
        cy[:, sensor] = -s * uy[:, sensor]
        dx0, dy0 = fit_timing(ref, F, [cx, cy])
        band = band_resid(ref, F) is not None

        def nll(v):
            m = self.add(ref, sensor, {"dx_mm": v[0], "dy_mm": v[1]})
            g = m.ll_groups(F)
            return -float(g["timing"].sum()) - (_band_ll(m, F) if band else 0.0)

        res = optimize.minimize(nll, [dx0, dy0], method="Nelder-Mead",
                                options={"xatol": 0.05, "fatol": 0.01, "maxiter": 120})
        dx, dy = (float(v) for v in res.x) if res.fun <= nll([dx0, dy0]) else (float(dx0), float(dy0))
        return {"dx_mm": dx, "dy_mm": dy, "offset_mm": float(np.hypot(dx, dy))}

    def add(self, ref, sensor, params):
        out = ref.copy()
        if out.energy_sensor_xy_mm is None:
            out.energy_sensor_xy_mm = ref.sensor_xy_mm.copy()
        out.sensor_xy_mm[sensor] += [params["dx_mm"], params["dy_mm"]]
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        d0, _ = geometry(ctx)
        sxy = np.array(ctx["sensor_xy_mm"], float)
        sxy[sensor] += [params["dx_mm"], params["dy_mm"]]
        d1, _ = geometry(ctx, sxy)
        return shift_channels(adc, (d1 - d0) * ctx["slowness_us_per_mm"], ctx)

    def material(self, params):
        return np.hypot(params["dx_mm"], params["dy_mm"]) >= self.min_offset_mm


def _band_ll(model, F) -> float:
    """The band picks' log-likelihood (Huber, their reference scale) under `model`: a move's path change
    moves them too, at their own slowness (`impactsense.band_timing`)."""
    return float(band_ll(model, F).sum())


def band_ll(model, F) -> np.ndarray | None:
    """Per drop, the band picks' log-likelihood (Huber, their reference scale) under `model`; 0 on a drop
    missing a band pick; None without band picks."""
    r = band_resid(model, F)
    if r is None:
        return None
    ok = np.all(np.isfinite(r), axis=1)
    out = np.zeros(len(r))
    out[ok] = huber_ll(r[ok] / model.band["sigma_us"]).sum(axis=1)
    return out


def _huber_weights(r: np.ndarray, k: float = 2.5) -> np.ndarray:
    mad = 1.4826 * np.median(np.abs(r - np.median(r))) + 1e-9
    return 1.0 / np.maximum(1.0, np.abs(r) / (k * mad))


def direction_test(model, F, sensor: int) -> dict:
    """Is channel `sensor`'s timing change direction dependent (a move) or constant (a delay)? Returns the
    p-value of the direction-dependent part (module docstring), the constant and the direction coefficients
    (µs, mm) and the number of cases. Huber-weighted least squares (iteratively reweighted), a delete-a-case
    jackknife covariance plus the reference's site-term covariance when `model.site` holds them."""
    r = model.toa_resid(F)
    ok = np.all(np.isfinite(r), axis=1)
    others = [j for j in range(4) if j != sensor]
    y = (r[:, sensor] - r[:, others].mean(axis=1))[ok]
    _, _, ux, uy = model.geometry(F)
    s = model.slowness_us_per_mm
    X = np.c_[np.ones(len(F)), -s * ux[:, sensor], -s * uy[:, sensor]][ok]
    case = np.asarray(F.case_id)[ok]
    w = np.ones(len(y))
    for _ in range(6):
        b = np.linalg.lstsq(X * np.sqrt(w)[:, None], y * np.sqrt(w), rcond=None)[0]
        w = _huber_weights(y - X @ b)
    V, G = _case_jackknife(X, y, w, case)
    site = getattr(model, "site", None)
    if site is not None:   # the contrast's reference error: its own channel's site term and 1/9 of the others'
        cov = _contrast_site_cov(site, F.subset(np.flatnonzero(ok)), sensor)
        B = np.linalg.pinv((X * w[:, None]).T @ X) @ (X * w[:, None]).T
        V = V + B @ cov @ B.T
    out = {"delay_us": float(b[0]), "dx_mm": float(b[1]), "dy_mm": float(b[2]), "cases": G}
    return {**out, "p_value": _move_wald_p(b[1:], V[1:, 1:], G)}


def _case_jackknife(X, y, w, case) -> tuple[np.ndarray, int]:
    """Delete-a-case jackknife covariance of the weighted least squares (the weights held): the cluster-robust
    covariance with its small-sample correction (CR3), which the plain sandwich understates at ~40 cases; and
    the number of cases."""
    _, inv = np.unique(case, return_inverse=True)
    G = int(inv.max()) + 1
    Xw = X * w[:, None]
    XtX, Xty = Xw.T @ X, Xw.T @ y
    loo = np.array([np.linalg.lstsq(XtX - Xw[inv == g].T @ X[inv == g], Xty - Xw[inv == g].T @ y[inv == g],
                                    rcond=None)[0] for g in range(G)])
    return (G - 1) / G * (loo - loo.mean(axis=0)).T @ (loo - loo.mean(axis=0)), G


def _contrast_site_cov(site, F, sensor: int) -> np.ndarray:
    """The reference's error on channel `sensor`'s contrast at F's drops: its own site term's posterior
    covariance and 1/9 of each other channel's."""
    return site.toa_cov(F, sensor) + sum(site.toa_cov(F, j) for j in range(4) if j != sensor) / 9.0


def _move_wald_p(b: np.ndarray, V: np.ndarray, G: int) -> float:
    """Hotelling's T² of the move's two coefficients -> F(2, G - 2) with G cases; 1 below 4 cases."""
    if G < 4:
        return 1.0
    t2 = float(b @ np.linalg.solve(V, b))
    return float(stats.f.sf(t2 / 2.0 * (G - 2) / (G - 1), 2, G - 2))


def band_test(model, F, sensor: int) -> dict:
    """Is channel `sensor`'s timing change the same on its threshold and its band picks (a delay shifts the
    whole recording: every pick alike) or does each pick move by its own slowness (a moved disc changes the
    path: `band_timing`)? The channel's contrast (its residual against the other channels' mean) on both
    picks; per case the mean of band minus threshold (a case's drops share their position error), Huber-clipped
    at 3 MAD; a one-sided t-test over the cases in the direction a move predicts ((s_band / s - 1) x the
    threshold picks' mean change). Returns the p-value, the mean difference and the move's predicted one (µs);
    p 1 without band picks."""
    rb = band_resid(model, F)
    out = {"p_value": 1.0, "difference_us": 0.0, "move_predicts_us": 0.0}
    if rb is None:
        return out
    ro = model.toa_resid(F)
    others = [j for j in range(4) if j != sensor]
    yb = rb[:, sensor] - rb[:, others].mean(axis=1)
    yo = ro[:, sensor] - ro[:, others].mean(axis=1)
    ok = np.isfinite(yb) & np.isfinite(yo)
    case = np.asarray(F.case_id)[ok]
    cases = np.unique(case)
    if len(cases) < 4:
        return out
    v = (yb - yo)[ok]
    means = np.array([v[case == c].mean() for c in cases])
    med = np.median(means)
    mad = 1.4826 * np.median(np.abs(means - med)) + 1e-9
    means = np.clip(means, med - 3 * mad, med + 3 * mad)
    predicted = (model.band["slowness_us_per_mm"] / model.slowness_us_per_mm - 1.0) * float(np.mean(yo[ok]))
    t = stats.ttest_1samp(means, 0.0, alternative="greater" if predicted >= 0 else "less")
    return {"p_value": float(t.pvalue), "difference_us": float(means.mean()), "move_predicts_us": predicted}


def joint_test(model, F, sensor: int) -> dict:
    """Is channel `sensor`'s change a constant, on the evidence of both pick sets at once? The channel's
    contrast on the threshold picks and on the band picks, stacked: one constant shared by both (a delay shifts
    the whole recording: every pick alike) and one move (dx, dy) whose signature is -s u on the threshold picks
    and -s_band u on the band picks (each pick at its own slowness). A move shows in two ways here: its
    direction dependence on either pick set and, along the look direction, the band picks' larger shift, which a
    shared constant cannot take. Each pick set is Huber-weighted at its own robust scale; Wald test of (dx, dy)
    with the delete-a-case jackknife plus the reference's site-term covariance (the band picks' taken as the
    threshold picks' at the ratio of their scales: the band picks carry no site terms of their own). Returns
    the p-value and the move's coefficients (mm); p 1 without band picks."""
    rb = band_resid(model, F)
    if rb is None:
        return {"p_value": 1.0, "dx_mm": 0.0, "dy_mm": 0.0}
    ro = model.toa_resid(F)
    others = [j for j in range(4) if j != sensor]
    yo = ro[:, sensor] - ro[:, others].mean(axis=1)
    yb = rb[:, sensor] - rb[:, others].mean(axis=1)
    idx = np.flatnonzero(np.isfinite(yo) & np.isfinite(yb))
    m = len(idx)
    if m < 4:   # the channel's band picks missing (a strong bond's low-pass loses them): no evidence
        return {"p_value": 1.0, "dx_mm": 0.0, "dy_mm": 0.0}
    _, _, ux, uy = model.geometry(F)
    u = np.c_[ux[idx, sensor], uy[idx, sensor]]
    X = np.r_[np.c_[np.ones(m), -model.slowness_us_per_mm * u],
              np.c_[np.ones(m), -model.band["slowness_us_per_mm"] * u]]
    y = np.r_[yo[idx], yb[idx]]
    band_rows = np.r_[np.zeros(m, bool), np.ones(m, bool)]
    w, scale = np.ones(2 * m), np.ones(2 * m)
    for _ in range(6):
        b = np.linalg.lstsq(X * np.sqrt(w)[:, None], y * np.sqrt(w), rcond=None)[0]
        r = y - X @ b
        for rows in (~band_rows, band_rows):
            scale[rows] = 1.4826 * np.median(np.abs(r[rows] - np.median(r[rows]))) + 1e-9
        w = _huber_weights(r / scale) / scale ** 2
    case = np.asarray(F.case_id)[idx]
    V, G = _case_jackknife(X, y, w, np.r_[case, case])
    site = getattr(model, "site", None)
    if site is not None:
        cov = _contrast_site_cov(site, F.subset(idx), sensor)
        C = np.zeros((2 * m, 2 * m))
        C[:m, :m] = cov
        C[m:, m:] = cov * (np.median(scale[band_rows]) / np.median(scale[~band_rows])) ** 2
        B = np.linalg.pinv((X * w[:, None]).T @ X) @ (X * w[:, None]).T
        V = V + B @ C @ B.T
    return {"p_value": _move_wald_p(b[1:], V[1:, 1:], G), "dx_mm": float(b[1]), "dy_mm": float(b[2])}
