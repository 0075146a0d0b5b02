"""Sub-problem 1's nu stage: E, nu and D_s fitted together to every repetition's band group delays, with each
repetition's own position fitted (issue 4; docs/findings.md, "Can four drops tell nu?").

Why this shape:
- the AIC DToA fix only the bending stiffness E / (1 - nu^2); the band group delays (`group_delay`) see the
  shear end of the A0 branch too, and they move smoothly with a drop's position;
- a drop lands ~1 mm from where it was declared, which moves its group delays by 5-100 us/mm (edge
  reflections make that non-linear), so each repetition's (x, y) is fitted first, re-running the FEM at the
  trial positions (`plate_fem.fit_positions`), and the positions' remaining linear freedom is projected out of
  the residual (`plate_fem._position_projector`);
- the group delays are energy centroids of envelopes damped by exp(-D_s t): a twin whose D_s is 5 % off moves
  nu by up to 0.03. So D_s is a third parameter of the fit, with the envelope-decay estimate (`damping`) as a
  Gaussian prior.

Per round: positions at the current (E, nu, D_s); FEM position derivatives there; then a bounded least squares
(scipy `least_squares`, forward FEM differences with fixed steps) over (ln E, nu, D_s) of the projected,
standardised residuals plus the prior's term. The uncertainty is the Gauss-Newton covariance at the optimum,
scaled by max(1, chi^2 / dof) (model error); how far the errors of nu on FEM-made drops went past it:
docs/findings.md, "Can four drops tell nu?". A nu the data cannot support is not claimed (`identified`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, lsq_linear

from .. import _core
from ..signal import channel_delays_us, core_samples
from . import group_delay, plate, plate_fem
from .problem import DropsAndTwin

OBSERVABLES = "group delays only"   # the AIC onsets bias nu by +0.01-0.02 even at the true positions
# records are cut this long after the latest measured onset before the group delays (measured and twin alike):
# long enough that the group-delay windows (group_delay.BANDS) end well before the cut, leaving the zero-phase
# filters' and the Hilbert transform's edge effects outside them, and far shorter than a full capture
CROP_AFTER_ONSET_MS = 8.0
STEPS = (0.004, 0.004, 8.0)         # forward-difference steps of (ln E, nu, D_s 1/s)
MAX_NFEV = 12                       # trial points of each round's trust-region fit of (ln E, nu, D_s)
POSITION_ITERS = 6                  # Levenberg-Marquardt iterations of each round's position fit
SIGMA_FLOOR_US = 0.2
# a nu is claimed only when the twin explains the group delays (chi^2 / dof at most this) ...
CHI2_DOF_MAX = 3.0
# ... and its scaled standard deviation is below this fraction of the nu grid's range
SD_FRACTION_MAX = 1.0 / 3.0
# after a round whose chi^2 / dof is above this, no further round is run: a round refines the last one's positions
# and (E, nu, D_s) from its optimum (the rig's second round moved chi^2 / dof by 7 %, 612 -> 568), so it cannot
# bring a twin that far off under CHI2_DOF_MAX, and nu is not claimed whatever it returns (docs/findings.md,
# "The cold chain"). Likewise a round's trust-region fit is not run when the linearised fit from its start
# (`predicted_chi2`, from the Jacobian the fit would begin with) stays above this.
STOP_CHI2_DOF = 10 * CHI2_DOF_MAX
# The first round is judged once before its position fit too, from the declared positions with their linear
# freedom projected out: positions move the group delays non-linearly (edge reflections), so that judgement stops
# the round only above this far wider limit; below it the round goes on as before (docs/findings.md, "The cold
# chain's CPU cut")
EARLY_STOP_CHI2_DOF = 10 * STOP_CHI2_DOF
DS_SYSTEMATIC = 0.03                # the decay estimate's systematic error (fraction of D_s) for its prior


@dataclass
class NuFit:
    e_mpa: float
    nu: float
    damping_per_s: float
    sd: dict                        # standard deviations of ln E, nu, D_s (scaled by max(1, chi^2 / dof))
    chi2: float
    dof: int
    x_mm: np.ndarray                # each repetition's fitted position
    y_mm: np.ndarray
    rounds: list

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / max(self.dof, 1)

    def identified(self, nu_bounds) -> tuple[bool, str]:
        """The rule for claiming nu: chi^2 / dof <= CHI2_DOF_MAX and sd(nu) <= SD_FRACTION_MAX of the range."""
        span = float(nu_bounds[1] - nu_bounds[0])
        if not np.isfinite(self.chi2_dof) or self.chi2_dof > CHI2_DOF_MAX:
            return False, (f"chi^2 / dof = {self.chi2_dof:.1f} > {CHI2_DOF_MAX:g}: the twin does not explain the "
                           "group delays, so their nu is the model error's, not the plate's")
        if not self.sd["nu"] <= SD_FRACTION_MAX * span:
            return False, f"sd(nu) = {self.sd['nu']:.3f} > {SD_FRACTION_MAX:.2f} of the grid's range {span:g}"
        return True, (f"chi^2 / dof = {self.chi2_dof:.2f} <= {CHI2_DOF_MAX:g} and sd(nu) = {self.sd['nu']:.4f} "
                      f"<= {SD_FRACTION_MAX:.2f} x {span:g}")

    def to_json(self, x_declared, y_declared, nu_bounds) -> dict:
        ok, why = self.identified(nu_bounds)
        shift = np.hypot(self.x_mm - np.asarray(x_declared, float), self.y_mm - np.asarray(y_declared, float))
        return {"E_mpa": self.e_mpa, "nu": self.nu, "damping_per_s": self.damping_per_s,
                "sd": self.sd, "chi2": self.chi2, "dof": self.dof, "chi2_dof": self.chi2_dof,
                "identified": ok, "rule": why,
                "position_shift_rms_mm": float(np.sqrt(np.mean(shift ** 2))),
                "position_shift_max_mm": float(shift.max()), "x_mm": self.x_mm.tolist(),
                "y_mm": self.y_mm.tolist(), "rounds": self.rounds}


def crop_samples(toa_us, fs_hz, n_samples, channel_delay_us=(0.0, 0.0, 0.0, 0.0)) -> int:
    """Record length used for the group delays: the latest measured onset (record time) + CROP_AFTER_ONSET_MS."""
    raw = np.asarray(toa_us, float) + np.asarray(channel_delay_us, float)[None, :]
    last = np.nanmax(raw) if np.isfinite(raw).any() else 0.0
    return int(min(n_samples, np.ceil((last * 1e-3 + CROP_AFTER_ONSET_MS) * 1e-3 * fs_hz)))


def measured_group_delays(session, targets, feats, cfg) -> tuple[np.ndarray, int]:
    """Every accepted repetition's band group delays [R, B, 6] us (cases in order), and the crop length."""
    recs = np.concatenate([np.asarray(r, int) for r in targets.recording_ids])
    toa = np.asarray(feats["toa_us"], float)[recs]
    n = crop_samples(toa, cfg.fs_hz, session.adc.shape[-1], channel_delays_us(cfg))
    gd = group_delay.group_delays(session.adc[recs][..., :n], toa, cfg.fs_hz, plate.PAIR_I, plate.PAIR_J,
                                  channel_delay_us=channel_delays_us(cfg), baseline_samples=cfg.baseline_samples)
    return gd, n


def twin_group_delays(adc, cfg_sim, n_samples, noise_counts=0.0, n_noise=1, seed=0) -> np.ndarray:
    """The same group delays [R, B, 6] of simulated records cut to `n_samples`, the rig's noise added (`n_noise`
    seeded realisations averaged; the same seeds for every trial: a smooth objective)."""
    a = np.asarray(adc, float)[..., :n_samples]
    rng = np.random.default_rng(seed)
    acc = []
    for _ in range(max(1, n_noise)):
        x = a + rng.normal(0.0, noise_counts, a.shape) if noise_counts > 0 else a
        q = core_samples(x, cfg_sim)
        toa = _core.extract_batch(q, cfg_sim)["toa_us"].astype(float)
        acc.append(group_delay.group_delays(q, toa, cfg_sim.fs_hz, plate.PAIR_I, plate.PAIR_J,
                                            baseline_samples=cfg_sim.baseline_samples))
    return np.mean(acc, axis=0)


def noise_sigma(adc, cfg_sim, n_samples, noise_counts, n_noise=4, n_seeds=4) -> np.ndarray:
    """The group delays' noise-only standard error [B] us for a residual measured - twin (the twin averaging
    `n_noise` realisations): their spread over `n_seeds` single rig-noise realisations of one FEM run, x sqrt(1
    + 1 / n_noise), floored at SIGMA_FLOOR_US."""
    obs = np.stack([twin_group_delays(adc, cfg_sim, n_samples, noise_counts, 1, 1000 + s) for s in range(n_seeds)])
    sd = np.sqrt(np.nanmean(np.nanvar(obs, axis=0, ddof=1), axis=(0, 2))) * np.sqrt(1 + 1 / max(n_noise, 1))
    return np.maximum(np.nan_to_num(sd, nan=SIGMA_FLOOR_US), SIGMA_FLOOR_US)


@dataclass
class GroupDelaySetup:
    """What comparing twins on the band group delays needs, computed once: every accepted repetition's measured
    group delays per_rep [R, B, 6], the crop length n, the declared x, y, h [R] and the rig-noise sigma [B] (one
    FEM run: the same sigma for every twin compared)."""

    per_rep: np.ndarray
    n: int
    x: np.ndarray
    y: np.ndarray
    h: np.ndarray
    sigma: np.ndarray
    names: tuple

    @classmethod
    def build(cls, drops: DropsAndTwin, params: dict) -> "GroupDelaySetup":
        targets, cfg_sim, noise = drops.targets, drops.cfg_sim, drops.noise
        per_rep, n = measured_group_delays(drops.session, targets, drops.feats, drops.cfg)
        n_rep = [len(r) for r in targets.recording_ids]
        x, y, h = (np.repeat(np.asarray(v, float), n_rep) for v in (targets.x_mm, targets.y_mm, targets.height_mm))
        sigma = noise_sigma(drops.simulate(params, drops.rig, x, y, h), cfg_sim, n, noise[0], noise[1])
        return cls(per_rep, n, x, y, h, sigma, group_delay.names())

    def twin(self, drops: DropsAndTwin, params: dict):
        """obs(x, y, h) -> the twin's group delays [R, B, 6] with `params` at those positions."""
        def obs(xx, yy, hh):
            return twin_group_delays(drops.simulate(params, drops.rig, xx, yy, hh), drops.cfg_sim, self.n,
                                     *drops.noise)
        return obs


def run(drops: DropsAndTwin, params: dict, *, ds_prior=None, e_bounds=(1000.0, 9000.0), nu_bounds=(0.30, 0.40),
        ds_bounds=(200.0, 1200.0), rounds=2, progress=None) -> dict:
    """The nu stage on the chosen drops: every accepted repetition's group delays against the twin with
    `params` (SimParams fields; its e_pa, nu, damping_per_s are the start) and the rig's noise. Returns
    CAL.json's `plate.nu_fit` block. progress(n): called as `fit` runs the twin, n adding up to
    max_evaluations(rounds) (a tqdm bar's update)."""
    setup = GroupDelaySetup.build(drops, params)
    per_rep, n, x, y, h, sigma, names = (setup.per_rep, setup.n, setup.x, setup.y, setup.h, setup.sigma,
                                         setup.names)

    def run_obs(e_mpa, nu, d_s, xx, yy, hh):
        return setup.twin(drops, dict(params, e_pa=e_mpa * 1e6, nu=nu, damping_per_s=d_s))(xx, yy, hh)

    res = fit(run_obs, per_rep, sigma, names, x, y, h,
              (float(params["e_pa"]) / 1e6, float(params["nu"]), float(params["damping_per_s"])),
              ds_prior=ds_prior, e_bounds=e_bounds, nu_bounds=nu_bounds, ds_bounds=ds_bounds, rounds=rounds,
              progress=progress)
    out = res.to_json(x, y, nu_bounds)
    out.update({"sigma_us": dict(zip(names, sigma.tolist())), "repetitions": int(per_rep.shape[0]),
                "damping_prior_per_s": None if ds_prior is None else [float(v) for v in ds_prior],
                "record_samples": n,
                "method": "least squares over (ln E, nu, D_s) of every accepted repetition's band group delays "
                          "(standardised by their rig-noise spread), each repetition's (x, y) fitted non-linearly "
                          "and its remaining linear freedom projected out, the decay D_s as a Gaussian prior; "
                          "sd = Gauss-Newton x sqrt(max(1, chi^2 / dof)); nu claimed only if "
                          f"chi^2 / dof <= {CHI2_DOF_MAX:g} and sd(nu) <= {SD_FRACTION_MAX:.2f} of the grid's nu "
                          "range"})
    return out


def max_evaluations(rounds: int, max_nfev: int = MAX_NFEV) -> int:
    """At most this many twin runs (run_obs calls, each every repetition through the FEM) in `fit`: per round
    the position fit (one, then three per iteration), the position Jacobian (four), the trust-region fit (at
    most max_nfev trial points, a Jacobian of three forward differences at each accepted one) and the
    Jacobian at its end (three); and once, the first round's judgement at the declared positions (their
    position Jacobian, the start and its three differences: eight)."""
    return rounds * (1 + 3 * POSITION_ITERS + 4 + 4 * max_nfev + 3) + 8


def gauss_newton_sd(jm, chi2, dof) -> np.ndarray:
    """Standard deviations of the parameters from the Jacobian jm of the standardised residuals, scaled by
    max(1, chi^2 / dof) (model error); infinite when jm^T jm is singular."""
    scale = max(1.0, chi2 / max(dof, 1))
    try:
        cov = np.linalg.inv(jm.T @ jm) * scale
        return np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        return np.full(jm.shape[1], np.inf)


def predicted_chi2(r0, j0, theta, lo, hi, n_data) -> float:
    """chi^2 of the first n_data residuals at the bounded Gauss-Newton optimum of the linearised residuals
    r0 + j0 (theta' - theta), lo <= theta' <= hi (scipy `lsq_linear`): what a fit starting at theta can expect to
    reach when the residuals are close to linear in the parameters over the step."""
    lin = lsq_linear(j0, -r0, bounds=(np.minimum(lo - theta, 0.0), np.maximum(hi - theta, 0.0)))
    r = r0 + j0 @ lin.x
    return float(np.sum(r[:n_data] ** 2))


def _forward_jacobian(fun, th, hi) -> np.ndarray:
    """d fun / d theta by forward steps STEPS (backward where a step would leave the upper bound hi)."""
    f0 = fun(th)
    cols = []
    for i, s in enumerate(STEPS):
        step = s if th[i] + s <= hi[i] else -s
        t2 = th.copy()
        t2[i] += step
        cols.append((fun(t2) - f0) / step)
    return np.stack(cols, axis=1)


def _judge_start(r0, j0, theta, lo, hi, n_data, dof) -> tuple[float, float, str | None]:
    """(chi^2 at the start, chi^2 predicted at the linearised optimum, why the round is not run or None): a round
    whose predicted chi^2 / dof stays above STOP_CHI2_DOF cannot make nu claimable."""
    chi2_start = float(np.sum(r0[:n_data] ** 2))
    chi2_pred = predicted_chi2(r0, j0, theta, lo, hi, n_data)
    if chi2_pred / max(dof, 1) <= STOP_CHI2_DOF:
        return chi2_start, chi2_pred, None
    return chi2_start, chi2_pred, (f"chi^2 / dof {chi2_start / max(dof, 1):.1f} at the start, "
                                   f"{chi2_pred / max(dof, 1):.1f} predicted at the fit's linearised optimum, > "
                                   f"{STOP_CHI2_DOF:g}: no (E, nu, D_s) fit can make nu claimable; not run")


def _round_record(rnd, theta, chi2, dof, fem_runs, **extra) -> dict:
    """One round of `fit` as the calibration's log keeps it (theta = ln E, nu, D_s)."""
    return {"round": rnd + 1, "E_mpa": float(np.exp(theta[0])), "nu": float(theta[1]),
            "damping_per_s": float(theta[2]), "chi2": chi2, "dof": int(dof), "fem_runs": fem_runs, **extra}


class _TwinResiduals:
    """`fit`'s twin runs (each one counted for the progress bar) and its standardised residuals."""

    def __init__(self, run_obs, per_rep, sigma, names, ks, h, ds_prior, progress):
        self.run_obs, self.per_rep, self.sigma, self.names, self.ks = run_obs, per_rep, sigma, names, ks
        self.h, self.ds_prior, self.progress, self.runs = h, ds_prior, progress, 0
        self.w = (1.0 / sigma)[ks][None, :, None]

    def raw(self, th, xx, yy):
        self.runs += 1
        if self.progress is not None:
            self.progress(1)
        return self.run_obs(float(np.exp(th[0])), float(th[1]), float(th[2]), xx, yy, self.h)

    def standardised(self, o):
        r = np.where(np.isfinite(o - self.per_rep), o - self.per_rep, 0.0)[:, self.ks] * self.w
        return r.reshape(r.shape[0], -1)

    def position_free(self, th_now, xp, yp):
        """The standardised residuals' function of theta at positions (xp, yp), their linear freedom there
        projected out (the position Jacobian: four twin runs at th_now), and its evaluations' cache."""
        at = lambda xx, yy, hh: self.raw(th_now, xx, yy)      # noqa: E731
        j_pos = plate_fem.position_jacobian(at, xp, yp, self.h, d_mm=0.25)
        proj = plate_fem._position_projector(j_pos, plate_fem.PlateTargets(self.per_rep, self.sigma, self.names),
                                             self.ks)
        cache = {}

        def fun(th):
            k = tuple(np.round(th, 7))
            if k not in cache:
                r = np.einsum("dij,dj->di", proj, self.standardised(self.raw(th, xp, yp))).ravel()
                if self.ds_prior is not None:
                    r = np.append(r, (th[2] - self.ds_prior[0]) / self.ds_prior[1])
                cache[k] = r
            return cache[k]
        return fun, cache


def _judge_declared(twin: _TwinResiduals, theta, lo, hi, xp, yp):
    """The first round judged before its position fit (its ~19 twin runs), from the declared positions (xp, yp):
    (its record, chi^2, sd, dof) when the linearised optimum stays above EARLY_STOP_CHI2_DOF, else (None, that
    optimum's chi^2 / dof)."""
    fun, cache = twin.position_free(theta.copy(), xp, yp)
    r0, j0 = fun(theta), _forward_jacobian(fun, theta, hi)
    n_data = r0.size - (twin.ds_prior is not None)
    dof = n_data - 2 * twin.per_rep.shape[0] - 3
    chi2_start, chi2_pred, _ = _judge_start(r0, j0, theta, lo, hi, n_data, dof)
    if chi2_pred / max(dof, 1) <= EARLY_STOP_CHI2_DOF:
        return None, chi2_pred / max(dof, 1)
    why = (f"chi^2 / dof {chi2_start / max(dof, 1):.1f} at the declared positions, {chi2_pred / max(dof, 1):.1f} "
           f"predicted at the linearised optimum over (ln E, nu, D_s) and the positions, > {EARLY_STOP_CHI2_DOF:g}: "
           "no fit can make nu claimable; positions not fitted, not run")
    record = _round_record(0, theta, chi2_start, dof, len(cache), chi2_predicted=chi2_pred, positions="declared",
                           stopped=why)
    return record, chi2_start, gauss_newton_sd(j0, chi2_start, dof), dof


def fit(run_obs, per_rep, sigma, names, x_mm, y_mm, h_mm, start, *, ds_prior=None, e_bounds=(1000.0, 9000.0),
        nu_bounds=(0.30, 0.40), ds_bounds=(200.0, 1200.0), rounds=2, max_nfev=MAX_NFEV, progress=None) -> NuFit:
    """E, nu, D_s and every repetition's position from the repetitions' observables per_rep [R, K, 6].

    run_obs(e_mpa, nu, d_s, x, y, h) -> [R, K, 6]: the twin's observables (deterministic: seeded noise).
    start = (E MPa, nu, D_s 1/s); x_mm, y_mm, h_mm [R]: the declared positions; ds_prior = (mean, sd) 1/s.
    progress(n): n = 1 after every run_obs call; when the fit is done, the rest of max_evaluations(rounds,
    max_nfev) (a fit that converges early ends at its total all the same).
    """
    if rounds < 1:
        raise ValueError(f"plate_nu.fit needs at least one round, got {rounds}")
    ks = plate_fem.observable_sets(names).get(OBSERVABLES, list(range(len(names))))
    per_rep = np.asarray(per_rep, float)
    sigma = np.asarray(sigma, float)
    h = np.asarray(h_mm, float)
    xf, yf = np.asarray(x_mm, float).copy(), np.asarray(y_mm, float).copy()
    lo = np.array([np.log(e_bounds[0]), nu_bounds[0], ds_bounds[0]])
    hi = np.array([np.log(e_bounds[1]), nu_bounds[1], ds_bounds[1]])
    theta = np.clip(np.array([np.log(start[0]), start[1], start[2]], float), lo, hi)
    twin = _TwinResiduals(run_obs, per_rep, sigma, names, ks, h, ds_prior, progress)
    log = []
    for rnd in range(rounds):
        th_now = theta.copy()
        early = _judge_declared(twin, theta, lo, hi, xf, yf) if rnd == 0 else (None, None)
        if early[0] is not None:
            record, chi2, sd, dof = early
            log.append(record)
            break
        declared = {} if early[1] is None else {"chi2_dof_predicted_at_declared_positions": early[1]}
        at = lambda xx, yy, hh, th=th_now: twin.raw(th, xx, yy)      # noqa: E731
        xf, yf = plate_fem.fit_positions(at, per_rep, sigma, xf, yf, h, ks, iters=POSITION_ITERS)
        fun, cache = twin.position_free(th_now, xf, yf)

        def jac(th, fun=fun):
            return _forward_jacobian(fun, th, hi)

        # the trust-region fit's first step, predicted: its Jacobian at the start (the fit's own first one, so
        # nothing is wasted when it goes on) and the bounded linear least squares over (ln E, nu, D_s)
        r0, j0 = fun(theta), jac(theta)
        n_data = r0.size - (ds_prior is not None)
        dof = n_data - 2 * per_rep.shape[0] - 3
        chi2_start, chi2_pred, stopped = _judge_start(r0, j0, theta, lo, hi, n_data, dof)
        if stopped:
            chi2, sd = chi2_start, gauss_newton_sd(j0, chi2_start, dof)
            log.append(_round_record(rnd, theta, chi2, dof, len(cache), chi2_predicted=chi2_pred, stopped=stopped,
                                     **declared))
            break
        sol = least_squares(fun, theta, jac=jac, bounds=(lo, hi), x_scale=np.array(STEPS), max_nfev=max_nfev,
                            method="trf")
        theta = sol.x
        r = fun(theta)
        chi2 = float(np.sum(r[:n_data] ** 2))
        sd = gauss_newton_sd(jac(theta), chi2, dof)
        log.append(_round_record(rnd, theta, chi2, dof, len(cache), chi2_start=chi2_start, chi2_predicted=chi2_pred,
                                 **declared))
        if rnd + 1 < rounds and chi2 / max(dof, 1) > STOP_CHI2_DOF:
            log[-1]["stopped"] = (f"chi^2 / dof {chi2 / max(dof, 1):.1f} > {STOP_CHI2_DOF:g}: the later rounds "
                                  "cannot make nu claimable")
            break
    if progress is not None and twin.runs < max_evaluations(rounds, max_nfev):
        progress(max_evaluations(rounds, max_nfev) - twin.runs)
    return NuFit(e_mpa=float(np.exp(theta[0])), nu=float(theta[1]), damping_per_s=float(theta[2]),
                 sd={"ln_E": float(sd[0]), "nu": float(sd[1]), "damping_per_s": float(sd[2])},
                 chi2=chi2, dof=int(dof), x_mm=xf, y_mm=yf, rounds=log)


# `calibrate --support auto`: the candidate supports (SimParams fields) whose group delays are compared
SUPPORT_CANDIDATES = (
    {"support": "simply_supported"},
    {"support": "free"},
    {"support": "clamped"},
    *({"support": "elastic_rim", "rim_stiffness_n_m2": k} for k in (1.0e8, 1.0e9, 1.0e10)),
)


def support_label(fields: dict) -> str:
    if fields.get("support") == "elastic_rim":
        return f"elastic_rim {fields.get('rim_stiffness_n_m2', 0.0):.3g} N/m2"
    return str(fields["support"])


def score_candidate(drops: DropsAndTwin, setup: GroupDelaySetup, params: dict, fields: dict) -> dict:
    """One candidate twin (params with SimParams `fields` on top): every repetition's position fitted to its
    group delays (`plate_fem.fit_positions`), then chi^2 / dof (dof = observables - 2 x repetitions), the rms
    residual per band and the positions' rms shift."""
    per_rep, sigma, names = setup.per_rep, setup.sigma, setup.names
    x, y, h = setup.x, setup.y, setup.h
    p = {k: v for k, v in params.items() if not k.startswith("rim_")}
    p.update(fields)
    obs = setup.twin(drops, p)
    xf, yf = plate_fem.fit_positions(obs, per_rep, sigma, x, y, h, list(range(len(names))))
    r = obs(xf, yf, h) - per_rep
    ok = np.isfinite(r)
    dof = int(ok.sum()) - 2 * len(x)
    chi2 = float(np.sum(np.where(ok, r / sigma[None, :, None], 0.0) ** 2))
    rms = np.sqrt(np.nanmean(np.where(ok, r, np.nan) ** 2, axis=(0, 2)))
    return {"fields": dict(fields), "chi2": chi2, "dof": dof, "chi2_dof": chi2 / max(dof, 1),
            "rms_us": dict(zip(names, rms.tolist())),
            "position_shift_rms_mm": float(np.sqrt(np.mean((xf - x) ** 2 + (yf - y) ** 2)))}


def choose_support(drops: DropsAndTwin, params: dict, candidates=SUPPORT_CANDIDATES, progress=None) -> dict:
    """The plate support that best explains the rig's band group delays: for each candidate (SimParams
    fields), every accepted repetition's position fitted (`plate_fem.fit_positions`) at params' E, nu and D_s,
    then chi^2 / dof of the group delays (rig-noise sigma, the same for every candidate; dof = observables - 2
    x repetitions) and the rms residual per band. Returns the table and the candidate with the lowest chi^2."""
    setup = GroupDelaySetup.build(drops, params)
    table = []
    for fields in candidates:
        table.append({"label": support_label(fields), **score_candidate(drops, setup, params, fields)})
        if progress is not None:
            progress()
    best = min(table, key=lambda row: row["chi2_dof"])
    return {"chosen": best["label"], "fields": best["fields"], "candidates": table,
            "sigma_us": dict(zip(setup.names, setup.sigma.tolist())),
            "repetitions": int(setup.per_rep.shape[0]),
            "method": "each candidate support: every accepted repetition's position fitted to its band group delays "
                      "at the plate's E, nu and D_s, chi^2 / dof of the group delays (rig-noise sigma); lowest wins"}
