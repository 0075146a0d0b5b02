"""Sub-problem 1 on the FEM: the twin's E from the four drops' AIC DToA, and what two timing observables say
about nu.

The fast model's grid (`plate`, Eq. 16 on the AIC DToA) gives nu and the E basin. The observables are

  r = [ (DToA_AIC sim - meas) / sigma_AIC ,  (DToA_band sim - meas) / sigma_band  for each band (`bands`) ]

over the four drops and six pairs, sigma = the standard error of the measured target (the pooled spread of
the drop's accepted repetitions / sqrt(repetitions), at least `SIGMA_FLOOR_US`). The twin's E is fitted (nu
held) to the AIC part, Eq. 16: the DToA the models learn from; the band arrivals can pull E away from the
AIC's optimum (model error), so they only measure identifiability. `nu_identifiability` measures,
at the fit, how far one 0.01 of nu at fixed bending stiffness moves these observables against sigma, and the
best-case standard deviation of nu with E free. On FEM-made drops (4 drops, 100 kHz) it is ~0.01 and the
end-to-end error on FEM-made drops ~0.04: nu is not identified by these observables, E / (1 - nu^2) is
(docs/findings.md). nu itself comes from the band group delays with each repetition's position and D_s fitted
(`plate_nu`, calibration's `plate_nu` stage). Every FEM evaluation is cached (resumable).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import _core
from ..signal import channel_delays_us, core_samples
from ..outputs import write_file
from ..progress import progress_bar
from . import bands, group_delay, plate

SIGMA_FLOOR_US = 0.5
MISSING_US = 1000.0      # a missing pick costs (1 ms / sigma)^2, as in Eq. 16
# The AIC DToA alone (`onset_observables`, the plate_fem stage's E scan) from a run this long after the first
# touch (plus the end taper) while the picks lie early enough, and the margin past the AIC window's end they
# must keep before the taper (the core looks a few samples past a crossing for a glitch)
ONSET_WINDOW_MS = 1.5
ONSET_MARGIN_SAMPLES = 16


@dataclass
class PlateTargets:
    """Measured timing observables of the four drops: dtoa [4, K, 6] us (K = AIC + bands), sigma [K] us."""

    dtoa: np.ndarray
    sigma: np.ndarray
    names: tuple
    per_rep: list | None = None     # each case's repetitions' observables [r, K, 6] (for `position_free_sigma`)

    def to_json(self) -> dict:
        return {"observables": list(self.names), "dtoa_us": self.dtoa.tolist(), "sigma_us": self.sigma.tolist()}


def names(band_list=None, group_delays=False) -> tuple:
    """The observables' names; with `group_delays`, the band group delays (`group_delay`) appended."""
    band_list = bands.BANDS_HZ if band_list is None else band_list
    out = ("AIC onset",) + tuple(f"envelope {lo / 1e3:g}-{hi / 1e3:g} kHz" for lo, hi in band_list)
    if group_delays:
        out += group_delay.names()
    return out


def _with_group_delays(obs, adc, toa, fs_hz, **kw) -> np.ndarray:
    """obs [r, K, 6] with the band group delays [r, B, 6] appended along K."""
    return np.concatenate([obs, group_delay.group_delays(adc, toa, fs_hz, plate.PAIR_I, plate.PAIR_J, **kw)], axis=1)


def measured_targets(session, targets, feats, cfg, group_delays=False) -> PlateTargets:
    """The observables of the chosen cases' accepted repetitions (median) and their standard errors."""
    per_case, var, reps, per_rep = [], [], [], []
    for recs in targets.recording_ids:
        recs = np.asarray(recs, int)
        toa = feats["toa_us"][recs].astype(float)
        t_band = bands.band_arrivals(session.adc[recs], toa, cfg.fs_hz, channel_delay_us=channel_delays_us(cfg),
                                     baseline_samples=cfg.baseline_samples)
        obs = np.concatenate([(toa[:, plate.PAIR_I] - toa[:, plate.PAIR_J])[:, None],
                              bands.pair_differences(t_band, plate.PAIR_I, plate.PAIR_J)], axis=1)   # [r, K, 6]
        if group_delays:
            obs = _with_group_delays(obs, session.adc[recs], toa, cfg.fs_hz, channel_delay_us=channel_delays_us(cfg),
                                     baseline_samples=cfg.baseline_samples)
        per_rep.append(obs)
        per_case.append(np.nanmedian(obs, axis=0))
        var.append(np.nanvar(obs, axis=0, ddof=1))
        reps.append(len(recs))
    dtoa = np.stack(per_case)
    dtoa[:, 0] = targets.dtoa_us                      # the AIC target is Eq. 16's (the same median)
    spread = np.sqrt(np.nanmean(np.stack(var), axis=(0, 2)))
    sigma = np.maximum(spread / np.sqrt(np.mean(reps)), SIGMA_FLOOR_US)
    return PlateTargets(dtoa=dtoa, sigma=sigma, names=names(group_delays=group_delays), per_rep=per_rep)


def _noisy_records(adc, cfg_sim, noise_counts=0.0, n_noise=1, seed=0):
    """The simulated records as the core takes them, once per seeded realisation of the rig's noise."""
    adc = np.asarray(adc).astype(float)
    rng = np.random.default_rng(seed)
    for _ in range(max(1, n_noise)):
        yield core_samples(adc + rng.normal(0.0, noise_counts, adc.shape) if noise_counts > 0 else adc, cfg_sim)


def sim_observables(adc, cfg_sim, noise_counts=0.0, n_noise=1, seed=0, group_delays=False) -> np.ndarray:
    """The same observables [D, K, 6] of simulated records (no channel delays), with the rig's noise added
    (`n_noise` seeded realisations, averaged; the same seeds for every plate: a smooth objective)."""
    acc = []
    for q in _noisy_records(adc, cfg_sim, noise_counts, n_noise, seed):
        toa = _core.extract_batch(q, cfg_sim)["toa_us"].astype(float)
        t_band = bands.band_arrivals(q, toa, cfg_sim.fs_hz, baseline_samples=cfg_sim.baseline_samples)
        obs = np.concatenate([(toa[:, plate.PAIR_I] - toa[:, plate.PAIR_J])[:, None],
                              bands.pair_differences(t_band, plate.PAIR_I, plate.PAIR_J)], axis=1)
        if group_delays:
            obs = _with_group_delays(obs, q, toa, cfg_sim.fs_hz, baseline_samples=cfg_sim.baseline_samples)
        acc.append(obs)
    return np.mean(acc, axis=0)


def onset_observables(run, sim, cfg_sim, n_obs, noise_counts=0.0, n_noise=1, seed=0) -> np.ndarray:
    """`sim_observables`' AIC DToA (observable 0; the n_obs - 1 others NaN) of the drops `run(duration_ms) ->
    adc` simulates with SimParams `sim`, from a run ONSET_WINDOW_MS after the first touch (+ sim's end taper)
    when that is enough, else from sim's whole window. A channel's pick reads the record only up to a few
    samples past its threshold crossing (the AIC window: aic_before samples before it, aic_after after it; the
    energy of the whole capture only flags a dead channel, whose pick is NaN), and an explicit run's steps do
    not depend on how long it goes on: so when every pick of every noise realisation is finite and lies
    aic_before + aic_after + ONSET_MARGIN_SAMPLES before the short run's taper, the picks are the whole
    window's bit for bit. Otherwise the whole window is run."""
    fs = float(cfg_sim.fs_hz)
    short = float(sim.taper_ms) + ONSET_WINDOW_MS
    for ms in ((short, float(sim.duration_ms)) if short < sim.duration_ms else (float(sim.duration_ms),)):
        toas = np.stack([_core.extract_batch(q, cfg_sim)["toa_us"].astype(float)
                         for q in _noisy_records(run(ms), cfg_sim, noise_counts, n_noise, seed)])
        last = (sim.pretrigger_samples + (ms - sim.taper_ms) * 1e-3 * fs
                - (cfg_sim.aic_before + cfg_sim.aic_after + ONSET_MARGIN_SAMPLES))
        if np.isfinite(toas).all() and float(toas.max()) * 1e-6 * fs < last:
            break
    obs = np.full((toas.shape[1], n_obs, len(plate.PAIR_I)), np.nan)
    obs[:, 0] = np.mean(toas[..., plate.PAIR_I] - toas[..., plate.PAIR_J], axis=0)
    return obs


def residuals(obs_sim, meas: PlateTargets) -> np.ndarray:
    err = np.where(np.isfinite(obs_sim - meas.dtoa), obs_sim - meas.dtoa, MISSING_US)
    return (err / meas.sigma[None, :, None]).ravel()


class Evaluations:
    """FEM evaluations of the observables {(E, nu): [D, K, 6]}, cached in a JSON file (resumable)."""

    def __init__(self, run_obs, cache_path=None, key="", progress=False, desc="FEM plate (E, nu)", workers=1):
        self.run_obs, self.path, self.key, self.workers = run_obs, cache_path, key, int(workers)
        self.obs = {}
        if cache_path and Path(cache_path).exists():
            try:
                obj = json.loads(Path(cache_path).read_text())
                if obj.get("key") == key:
                    self.obs = {tuple(json.loads(k)): np.array(v) for k, v in obj["obs"].items()}
            except (OSError, ValueError):
                self.obs = {}
        self.bar = progress_bar(progress, desc=desc, unit="run")

    @staticmethod
    def _key(e_mpa, nu) -> tuple:
        return round(float(e_mpa), 2), round(float(nu), 5)

    def _save(self) -> None:
        if self.path:
            write_file(self.path, json.dumps({"key": self.key, "obs": {json.dumps(list(kk)): v.tolist()
                                                                      for kk, v in self.obs.items()}}))

    def __call__(self, e_mpa, nu):
        k = self._key(e_mpa, nu)
        if k not in self.obs:
            self.obs[k] = np.asarray(self.run_obs(*k), float)
            self._save()
            self.bar.update(1)
        return self.obs[k]

    def prefetch(self, points) -> None:
        """Evaluates the (E, nu) points not cached yet side by side (`fem.points_concurrently`, `workers` at a
        time): the same observables as one call each, one after the other."""
        from .fem import points_concurrently

        todo = list(dict.fromkeys(k for k in (self._key(e, nu) for e, nu in points) if k not in self.obs))
        if len(todo) < 2 or self.workers < 2:
            return
        for k, obs in zip(todo, points_concurrently(lambda kk: self.run_obs(*kk), todo, self.workers)):
            self.obs[k] = np.asarray(obs, float)
            self.bar.update(1)
        self._save()


def chi2(obs_sim, meas: PlateTargets, observables=None) -> float:
    """Sum of squared standardised residuals over `observables` (indices into meas.names; default all)."""
    r = residuals(obs_sim, meas).reshape(meas.dtoa.shape)
    return float(np.sum((r if observables is None else r[:, list(observables)]) ** 2))


def e_scan(evals: Evaluations, meas: PlateTargets, e_start, nu, e_bounds, ratios=(0.7, 0.8, 0.9, 1.0, 1.1),
           walk=1.1, observables=None, loss=None) -> tuple[float, dict]:
    """Twin's E at fixed nu: chi^2 at E = e_start x ratios (clipped to the grid's range), walked on by `walk`
    while the minimum sits at the scanned edge, then at the vertex of a parabola in ln E through the best three.
    `loss(obs_sim) -> float` replaces chi^2 over `observables` (e.g. `chi2_position_free`).
    Returns (E [MPa], {E: chi^2})."""
    lo, hi = e_bounds
    scan = {}

    def at(e):
        e = float(np.clip(e, lo, hi))
        if e not in scan:
            obs = evals(e, nu)
            scan[e] = chi2(obs, meas, observables) if loss is None else float(loss(obs))
        return scan[e]

    evals.prefetch([(float(np.clip(e_start * r, lo, hi)), nu) for r in ratios])   # independent: side by side
    for r in ratios:
        at(e_start * r)
    for _ in range(15):
        es = sorted(scan)
        i = int(np.argmin([scan[e] for e in es]))
        if 0 < i < len(es) - 1 or es[i] in (lo, hi):
            break
        at(es[i] / walk if i == 0 else es[i] * walk)
    es = sorted(scan)
    i = int(np.argmin([scan[e] for e in es]))
    if 0 < i < len(es) - 1:
        c2, c1, _ = np.polyfit(np.log(es[i - 1:i + 2]), [scan[e] for e in es[i - 1:i + 2]], 2)
        if c2 > 0:
            at(round(float(np.exp(-c1 / (2 * c2))), 1))
    return min(scan, key=scan.get), scan


def nu_identifiability(evals: Evaluations, meas: PlateTargets, e_mpa, nu, *, d_ln_e=0.03, d_nu=0.03,
                       nu_bounds=(0.30, 0.40), j_pos=None, e_ratios=None) -> dict:
    """How well the drops fix nu once E is free: central differences of the observables along ln E and along
    nu at fixed bending stiffness D ~ E / (1 - nu^2) (4 FEM runs), then the Fisher information of nu with E
    profiled out, for independent errors of the targets' standard errors (a best case: the jitter of a drop's
    position moves all its observables together) scaled by max(1, chi^2 / dof) (model error).
    On drops the FEM made with known values the end-to-end errors of nu went well past this best case
    (docs/findings.md): it bounds what the drops can tell, it does not certify a fitted nu.
    e_ratios = (low, high): the ln E difference between E x low and E x high (default exp(-+d_ln_e)); an E
    scan's own outer ratios around e_mpa make them runs the scan has already made."""
    nu_c = float(np.clip(nu, nu_bounds[0] + d_nu, nu_bounds[1] - d_nu))
    stiff = e_mpa / (1 - nu ** 2)
    lo_r, hi_r = e_ratios if e_ratios is not None else (np.exp(-d_ln_e), np.exp(d_ln_e))
    evals.prefetch([(e_mpa * hi_r, nu), (e_mpa * lo_r, nu), (stiff * (1 - (nu_c + d_nu) ** 2), nu_c + d_nu),
                    (stiff * (1 - (nu_c - d_nu) ** 2), nu_c - d_nu), (e_mpa, nu)])
    j_e = (evals(e_mpa * hi_r, nu) - evals(e_mpa * lo_r, nu)) / float(np.log(hi_r / lo_r))
    j_nu = (evals(stiff * (1 - (nu_c + d_nu) ** 2), nu_c + d_nu)
            - evals(stiff * (1 - (nu_c - d_nu) ** 2), nu_c - d_nu)) / (2 * d_nu)
    r = residuals(evals(e_mpa, nu), meas)
    dof = max(1, r.size - 2)
    scale = max(1.0, float(np.sum(r ** 2)) / dof)
    w = 1.0 / meas.sigma[None, :, None]
    out = {"sd_at_target_error": {}, "sd": {}, "per_0.01_nu_at_fixed_D_us": {}, "per_1pct_E_us": {},
           "model_error_scale": scale, "definition": "sd(nu) with E free = 1 / |J_nu - projection on J_lnE| in "
           "target-standard-error units (independent errors: a best case), x sqrt(max(1, chi^2 / dof))"}
    sets = observable_sets(meas.names)
    for label, ks in sets.items():
        a = (j_e * w)[:, ks].ravel()
        b = (j_nu * w)[:, ks].ravel()
        b_orth = b - a * (a @ b) / (a @ a)
        sd = 1.0 / max(float(np.linalg.norm(b_orth)), 1e-12)
        out["sd_at_target_error"][label] = sd
        out["sd"][label] = sd * np.sqrt(scale)
    for k, n in enumerate(meas.names):
        out["per_0.01_nu_at_fixed_D_us"][n] = float(np.sqrt(np.mean(j_nu[:, k] ** 2)) * 0.01)
        out["per_1pct_E_us"][n] = float(np.sqrt(np.mean(j_e[:, k] ** 2)) * 0.01)
    out["sd_nu"] = out["sd"]["AIC onset + bands"]
    if j_pos is not None:
        # each drop's position profiled out, the targets' errors re-estimated without the position scatter
        sig = position_free_sigma(meas, j_pos)
        m2 = PlateTargets(dtoa=meas.dtoa, sigma=sig, names=meas.names)
        out["position_free"] = {
            "sigma_us": sig.tolist(),
            "sd_at_target_error": {label: fisher_sd_nu(j_e, j_nu, m2, ks, j_pos)
                                   for label, ks in observable_sets(meas.names).items()},
            "definition": "as sd, with each drop's (x, y) free (linearised, FEM central differences) and the "
                          "targets' standard errors from the repetitions' spread with their own positions "
                          "profiled out"}
    return out


def observable_sets(obs_names) -> dict:
    """Named index sets of the observables: the AIC onset, the band 30 % crossings, the band group delays."""
    env = [k for k, n in enumerate(obs_names) if n.startswith("envelope")]
    gd = [k for k, n in enumerate(obs_names) if n.startswith("group delay")]
    out = {"AIC onset only": [0], "bands only": env, "AIC onset + bands": [0] + env}
    if gd:
        out.update({"group delays only": gd, "AIC onset + group delays": [0] + gd})
    return out


# ------------------------------------------------------------------------------------------------------------
# Each drop's true position as a nuisance parameter (issue 4's identifiability of nu)
#
# A drop lands ~1 mm from its declared position; that moves every observable of the drop together (by the
# distance change over each observable's own speed) and, left as error, it masks nu. Linearised at the declared
# position, the position moves the drop's standardised residual vector (K observables x 6 pairs) within the span
# of two columns d r / d x, d r / d y (FEM central differences); projecting that span out of each drop's
# residual before summing squares is the profile likelihood over the drop's position (the pair differences
# already remove the origin time).


def position_jacobian(run_obs_at, x_mm, y_mm, h_mm, d_mm=1.0) -> np.ndarray:
    """d obs / d position [D, K, 6, 2] us/mm by central differences; run_obs_at(x, y, h) -> obs [D, K, 6]
    (called four times with the drops shifted, so seeded noise is common to the +- runs)."""
    x, y, h = (np.asarray(v, float) for v in (x_mm, y_mm, h_mm))
    jx = (run_obs_at(x + d_mm, y, h) - run_obs_at(x - d_mm, y, h)) / (2 * d_mm)
    jy = (run_obs_at(x, y + d_mm, h) - run_obs_at(x, y - d_mm, h)) / (2 * d_mm)
    return np.stack([jx, jy], axis=-1)


def _position_projector(j_pos, meas: PlateTargets, observables=None) -> np.ndarray:
    """Per drop, the projector [D, M, M] onto the complement of the standardised position columns (M = the
    chosen observables x 6 pairs)."""
    ks = list(range(len(meas.names))) if observables is None else list(observables)
    w = (1.0 / meas.sigma)[ks][None, :, None, None]
    a = np.nan_to_num((j_pos[:, ks] * w).reshape(j_pos.shape[0], -1, j_pos.shape[-1]))    # [D, M, 2]
    out = []
    for ad in a:
        q, s, _ = np.linalg.svd(ad, full_matrices=False)
        q = q[:, s > 1e-9 * max(s.max(), 1e-300)]
        out.append(np.eye(ad.shape[0]) - q @ q.T)
    return np.stack(out)


def chi2_position_free(obs_sim, meas: PlateTargets, j_pos, observables=None) -> float:
    """chi^2 with each drop's position profiled out (linearised): sum over drops of |P_d r_d|^2."""
    ks = list(range(len(meas.names))) if observables is None else list(observables)
    r = residuals(obs_sim, meas).reshape(meas.dtoa.shape)[:, ks].reshape(meas.dtoa.shape[0], -1)
    proj = _position_projector(j_pos, meas, ks)
    return float(np.sum(np.einsum("dij,dj->di", proj, r) ** 2))


def fisher_sd_nu(j_e, j_nu, meas: PlateTargets, observables, j_pos=None) -> float:
    """Best-case sd(nu) with ln E free (independent errors of the targets' standard errors); with `j_pos`,
    each drop's position free as well (its two directions projected out of every drop's block)."""
    ks = list(observables)
    w = (1.0 / meas.sigma)[ks][None, :, None]
    a = np.stack([(j_e[:, ks] * w).reshape(j_e.shape[0], -1), (j_nu[:, ks] * w).reshape(j_nu.shape[0], -1)], -1)
    if j_pos is not None:
        a = np.einsum("dij,djp->dip", _position_projector(j_pos, meas, ks), a)
    f = np.einsum("dip,diq->pq", a, a)
    return float(np.sqrt(np.linalg.inv(f)[1, 1])) if np.linalg.cond(f) < 1e12 else float("inf")


def position_free_sigma(meas: PlateTargets, j_pos) -> np.ndarray:
    """The targets' standard errors [K] us once each repetition's own position is profiled out: each
    repetition's deviation from its case's mean, with the case's position directions (each observable scaled
    by its raw spread) projected out, pooled per observable (corrected for the 2 of 3K independent pair dimensions the projection removes and
    for the case mean), over sqrt(repetitions). What is left is the picks' noise, not the position scatter."""
    if meas.per_rep is None:
        raise ValueError("position_free_sigma needs the targets' per-repetition observables (measured_targets)")
    k = len(meas.names)
    # the position directions in units of each observable's raw spread (observables of very different scatter
    # would otherwise let the largest decide the directions)
    raw = np.sqrt(np.nanmean([np.nanvar(o, axis=0, ddof=1).mean(axis=-1) for o in meas.per_rep], axis=0))
    unit = PlateTargets(dtoa=meas.dtoa, sigma=np.where(raw > 0, raw, 1.0), names=meas.names)
    proj = _position_projector(j_pos, unit)
    ss, n, reps = np.zeros(k), 0.0, []
    for d, obs in enumerate(meas.per_rep):
        r = obs.shape[0]
        dev = np.nan_to_num(obs - np.nanmean(obs, axis=0, keepdims=True)).reshape(r, -1)
        pd = (dev @ proj[d].T).reshape(r, k, -1)
        ss += np.sum(pd ** 2, axis=(0, 2)) * r / max(r - 1, 1)
        n += r * pd.shape[-1]
        reps.append(r)
    var = ss / n * (3 * k) / (3 * k - 2)
    return np.maximum(np.sqrt(var / np.mean(reps)), SIGMA_FLOOR_US)


def fit_positions(run_obs_at, obs_rep, sigma, x_mm, y_mm, h_mm, observables, *, iters=6, d_mm=0.25,
                  max_step_mm=1.0, bound_mm=3.0) -> tuple[np.ndarray, np.ndarray]:
    """Each repetition's own (x, y) fitted non-linearly to its observables obs_rep [R, K, 6] (issue 4, step b):
    Levenberg-Marquardt per repetition, re-simulating at the trial positions (FEM finite differences, `d_mm`),
    steps capped at `max_step_mm`, positions kept within `bound_mm` of the declared ones. run_obs_at(x, y, h)
    -> [R, K, 6] for all repetitions at once (three calls per iteration). Returns the fitted (x, y)."""
    ks = list(observables)
    x0, y0, h = (np.asarray(v, float) for v in (x_mm, y_mm, h_mm))
    x, y = x0.copy(), y0.copy()
    w = (1.0 / np.asarray(sigma, float))[ks][None, :, None]

    def res(o):
        r = np.where(np.isfinite(o - obs_rep), o - obs_rep, 0.0)[:, ks] * w
        return r.reshape(r.shape[0], -1)

    lam = np.full(x.size, 1e-2)
    r0 = res(run_obs_at(x, y, h))
    for _ in range(iters):
        jx = (res(run_obs_at(x + d_mm, y, h)) - r0) / d_mm
        jy = (res(run_obs_at(x, y + d_mm, h)) - r0) / d_mm
        j = np.stack([jx, jy], -1)                                              # [R, M, 2]
        a = np.einsum("rmp,rmq->rpq", j, j)
        g = np.einsum("rmp,rm->rp", j, r0)
        step = -np.linalg.solve(a + lam[:, None, None] * np.eye(2) * np.trace(a, axis1=1, axis2=2)[:, None, None]
                                / 2 + 1e-12 * np.eye(2), g[..., None])[..., 0]
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        step *= np.minimum(1.0, max_step_mm / np.maximum(norm, 1e-12))
        xt = np.clip(x + step[:, 0], x0 - bound_mm, x0 + bound_mm)
        yt = np.clip(y + step[:, 1], y0 - bound_mm, y0 + bound_mm)
        rt = res(run_obs_at(xt, yt, h))
        better = (rt ** 2).sum(1) < (r0 ** 2).sum(1)
        x, y = np.where(better, xt, x), np.where(better, yt, y)
        r0 = np.where(better[:, None], rt, r0)
        lam = np.where(better, lam / 3, lam * 4)
    return x, y
