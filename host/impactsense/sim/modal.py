"""Drops by modal superposition (the reduced-order twin, `solver="modal"`): the same plate, ball and discs as
the direct finite-element run, with the plate in its modes (`modal_basis`).

Each mode k (mass-normalised, natural frequency omega_k) is a damped oscillator q'' + 2 s_k q' + omega_k^2 q =
phi_k(x_c) F(t) with s_k = D_s / 2 + eta omega_k / 2 (the FEM's mass-proportional damping D_s, plus an optional
loss factor eta, SimParams.loss_factor); its impulse response g_k(t) = sum over its poles p of
Re[rho_p exp(lambda_p t)]. By default (SimParams.modal_poles "fem_step") the poles are those of the direct
solver's central-difference step (its frequencies ~ (omega dt)^2 / 24 above omega: 0.4 % at 30 kHz on a 5 mm
mesh), so the modal twin reproduces the direct one, whose dispersion the calibration has absorbed; "exact":
the continuous-time poles.

Contact (batched over drops): F(t) piecewise linear on the FEM's step tau (hats phi_j centred at t_j = j tau).
The plate under the ball, w_c(t_n) = sum_j H(n - j) F_j + R F_n with H the point receptance to a hat
(sum_k phi_k(x_c)^2 x the hat response of mode k, closed form) and R the residual flexibility of the modes
above the cut-off (quasi-static); the ball z(t_n) = v0 t_n + g t_n^2 / 2 - (1 / m) sum_j F_j B(n - j) with
B the hat's double integral. At each step the Hertz law F_n = k (z - w_c)_+^1.5 is solved for F_n
(Newton, monotone from below). The window ends as the FEM's contact window does (the ball clearly gone).

Outputs: the disc functionals applied to the modes give modal output gains c_sk; after the last force hat each
mode decays freely, so every later record sample is a matrix product over the modes' poles, sampled with the
FEM's own record weights (hats over its steps: the Fejer factor [sinh(m z) / (m sinh z)]^2, z = lambda tau / 2);
the samples during the contact window are the direct convolution of F with the hat responses on the step grid,
plus the truncated modes' quasi-static output (the sensors' residual flexibility at the contact point x F(t)):
without it the kept modes alone answer at every disc from the first instant (a non-causal precursor of
~0.5 % of the peak).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft
import scipy.sparse as sp

from .model import Model
from .modal_basis import ModalBasis
from .simulate import QUIET_AFTER_CONTACT_FRACTION, QUIET_AFTER_CONTACT_S   # as the FEM's contact window
NEWTON_ITERATIONS = 8
CHUNK_STEPS = 256                # contact kernel columns computed at a time


def _sinhc(z):
    """sinh(z) / z for complex z (series near 0)."""
    z = np.asarray(z, complex)
    small = np.abs(z) < 1e-4
    out = np.ones_like(z)
    zz = np.where(small, 1.0, z)
    out = np.where(small, 1 + z * z / 6, np.sinh(zz) / zz)
    return out


def _expm1_x_over_x2(x):
    """(exp(x) - 1 - x) / x^2 (series near 0)."""
    x = np.asarray(x, complex)
    small = np.abs(x) < 1e-3
    xx = np.where(small, 1.0, x)
    return np.where(small, 0.5 + x / 6 + x * x / 24, (np.exp(xx) - 1 - xx) / (xx * xx))


class Poles:
    """The poles of every mode: lam [P] complex, rho [P] complex, mode [P] (index of the mode)."""

    def __init__(self, omega: np.ndarray, damping_per_s: float, loss_factor: float = 0.0,
                 fem_step_s: float | None = None):
        s = 0.5 * damping_per_s + 0.5 * loss_factor * omega
        disc = omega ** 2 - s ** 2
        under = disc > (1e-6 * np.maximum(s, 1.0)) ** 2
        lam, rho, mode = [], [], []
        k_u = np.flatnonzero(under)
        wd = np.sqrt(disc[k_u])
        if fem_step_s:
            # the poles of the FEM's central-difference step (u_{n+1} = u_n + a (u_n - u_{n-1}) - b w^2 u_n,
            # a = (1 - c) / (1 + c), b = dt^2 / (1 + c), c = D_s dt / 2): z = exp(lambda dt) of
            # z^2 - (1 + a - b w^2) z + a = 0; its frequency is above omega by ~ (omega dt)^2 / 24
            dt = fem_step_s
            c = 0.5 * damping_per_s * dt
            a, b = (1 - c) / (1 + c), dt * dt / (1 + c)
            bb = 1 + a - b * omega[k_u] ** 2
            z = 0.5 * (bb + np.sqrt((bb * bb - 4 * a).astype(complex)))
            wd = np.abs(np.angle(z)) / dt
            s = s.copy()
            s[k_u] = -np.log(np.abs(z)) / dt + 0.5 * loss_factor * omega[k_u]
        lam.append(-s[k_u] + 1j * wd)
        rho.append(-1j / wd)                          # g = Im(exp(lam t)) / omega_d
        mode.append(k_u)
        k_o = np.flatnonzero(~under)                  # rigid-body or overdamped: two real poles
        if k_o.size:
            r = np.sqrt(np.maximum(-disc[k_o], (1e-6 * np.maximum(s[k_o], 1.0)) ** 2))
            lp, lm = -s[k_o] + r, -s[k_o] - r
            lam += [lp + 0j, lm + 0j]
            rho += [1 / (lp - lm) + 0j, -1 / (lp - lm) + 0j]
            mode += [k_o, k_o]
        self.lam = np.concatenate(lam)
        self.rho = np.concatenate(rho)
        self.mode = np.concatenate(mode)
        n = omega.size
        self.to_modes = sp.csr_matrix((np.ones(self.mode.size), (self.mode, np.arange(self.mode.size))),
                                      shape=(n, self.mode.size))

    def hat_response(self, tau: float, lags: np.ndarray) -> np.ndarray:
        """Displacement of every mode at lag l tau after a unit hat force centred at 0 (half-width tau):
        [modes, len(lags)] float64 (lag 0: the hat's first half only)."""
        lags = np.asarray(lags)
        z = self.lam * tau
        full = self.rho * tau * _sinhc(z / 2) ** 2                  # rho L_tau(lam)
        half = self.rho * tau * _expm1_x_over_x2(z)                # rho M_0(lam)
        e = np.exp(np.outer(self.lam, lags * tau))
        vals = (full[:, None] * e).real
        vals[:, lags == 0] = half.real[:, None]
        vals[:, lags < 0] = 0.0
        return np.asarray(self.to_modes @ vals)


def _record_weights(m: int, n_fine: int, n_q: int) -> sp.csr_matrix:
    """The FEM's record operator: sample q = sum_n V(t_n) (1 - |n/m - q|) / m over the steps, [n_q, n_fine]."""
    rows, cols, vals = [], [], []
    for q in range(n_q):
        for r in range(-(m - 1), m):
            n = q * m + r
            if 0 <= n < n_fine:
                rows.append(q)
                cols.append(n)
                vals.append((1 - abs(r) / m) / m)
    return sp.csr_matrix((vals, (rows, cols)), shape=(n_q, n_fine))


def _cached(basis: ModalBasis, key, make):
    """A value derived from the basis, kept on it (the gains of a model's sensors, across batches)."""
    store = basis.__dict__.setdefault("_derived", {})
    if key not in store:
        store[key] = make()
    return store[key]


def _hertz_force(pred, comp, k_h):
    """F solving F = k_h (pred - comp F)_+^1.5 per drop (Newton from 0: monotone from below, f concave)."""
    f = np.zeros(pred.size)
    on = pred > 0
    if on.any():
        pp, cc = pred[on], comp[on]
        ff = np.zeros(pp.size)
        for _ in range(NEWTON_ITERATIONS):
            d = np.maximum(pp - cc * ff, 0.0)
            sq = np.sqrt(d)
            ff = ff - (ff - k_h * d * sq) / (1 + 1.5 * k_h * cc * sq)
        f[on] = ff
    return f


def contact_window(model: Model, poles: Poles, phi_c, resid, v0) -> dict:
    """The ball on the plate (batched) until every ball has clearly left: force per step [B, steps + 1]."""
    p, tau = model.params, model.dt_s
    n_b = v0.size
    phi2 = phi_c * phi_c
    mass, k_h, g = model.ball_mass_kg, model.k_hertz, p.g_m_s2
    max_steps = int(math.ceil(p.contact_window_ms * 1e-3 / tau))
    force = np.zeros((n_b, max_steps + 1))
    h_cols = np.zeros((n_b, max_steps + 1))           # H(l) for l = 0.., filled CHUNK_STEPS at a time
    h_done = 0
    s0 = np.zeros(n_b)                                # sum_{j<n} F_j
    s1 = np.zeros(n_b)                                # sum_{j<n} j F_j
    t_first = np.full(n_b, -1.0)
    t_last = np.full(n_b, -1.0)
    touching = np.zeros(n_b, bool)
    touches = np.zeros(n_b, int)
    active = np.arange(n_b)                           # drops whose ball has not clearly left yet
    n = 0
    for n in range(1, max_steps + 1):
        if n >= h_done:
            lags = np.arange(h_done, min(h_done + CHUNK_STEPS, max_steps + 1))
            h_cols[:, lags] = phi2 @ poles.hat_response(tau, lags)
            h_done = lags[-1] + 1
        t = n * tau
        a = active
        hist = np.einsum("bj,bj->b", force[a, 1:n], h_cols[a, n - 1:0:-1]) if n > 1 else 0.0
        pred = v0[a] * t + 0.5 * g * t * t - tau * tau / mass * (n * s0[a] - s1[a]) - hist
        f = _hertz_force(pred, tau * tau / (6 * mass) + h_cols[a, 0] + resid[a], k_h)
        force[a, n] = f
        now = f > 0
        touches[a] += now & ~touching[a]
        t_first[a] = np.where(now & (t_first[a] < 0), t, t_first[a])
        t_last[a] = np.where(now, t, t_last[a])
        touching[a] = now
        s0[a] += f
        s1[a] += n * f
        v_ball = v0[a] + g * t - tau / mass * (s0[a] - 0.5 * f)
        gone = (t_first[a] >= 0) & ~now & (v_ball < 0) & \
            (t - t_last[a] > np.maximum(QUIET_AFTER_CONTACT_S, QUIET_AFTER_CONTACT_FRACTION * (t_last[a] - t_first[a])))
        if gone.any():
            active = a[~gone]
            if active.size == 0:
                break
    touched = np.flatnonzero(np.any(force[:, :n + 1] > 0, axis=0))
    n_last = int(touched[-1]) if touched.size else 1      # the last step with a force: outputs need no more
    return dict(force_n=force[:, :n_last + 1], contacts=touches, contact_start_s=t_first, contact_end_s=t_last,
                steps=n)


def _early_samples(model: Model, poles: Poles, coef, out_resid, force, q0: int) -> np.ndarray:
    """Record samples 0..q0-1 (the force still acting): F convolved with the hat responses on the step grid,
    plus the truncated modes' quasi-static output; [B, S, q0]."""
    tau, m = model.dt_s, model.record_every
    n_b, n_s = out_resid.shape
    n_last = force.shape[1] - 1
    n_early = q0 * m
    g_resp = (coef.astype(np.float32) @ poles.hat_response(tau, np.arange(n_early)).astype(np.float32))
    n_fft = scipy.fft.next_fast_len(n_early + n_last)
    spec_f = scipy.fft.rfft(force[:, 1:], n_fft, axis=1)                   # F_j, j = 1..
    spec_g = scipy.fft.rfft(g_resp.reshape(n_b, n_s, n_early), n_fft, axis=2)
    conv = scipy.fft.irfft(spec_g * spec_f[:, None, :], n_fft, axis=2)[:, :, :n_early]   # index n - 1
    v_fine = np.zeros((n_b, n_s, n_early))
    v_fine[:, :, 1:] = conv[:, :, :n_early - 1]
    n_f = min(force.shape[1], n_early)
    v_fine[:, :, :n_f] += out_resid[:, :, None] * force[:, None, :n_f]
    w = _record_weights(m, n_early, q0)
    return (w @ v_fine.reshape(n_b * n_s, n_early).T).T.reshape(n_b, n_s, q0)


def _late_samples(model: Model, poles: Poles, coef, force, q0: int, n_rec: int, n_s: int) -> np.ndarray:
    """Record samples q0.. (every force hat over): each pole's free decay from its state at the last force
    step, sampled with the FEM's record weights (Fejer factor); [B, S, n_rec - q0]."""
    tau, m = model.dt_s, model.record_every
    n_b = force.shape[0]
    n_last = force.shape[1] - 1
    lam = poles.lam
    t_end = n_last * tau
    j = np.arange(1, n_last + 1)
    e_hist = np.exp(np.outer((t_end - j * tau), lam))                  # [J, P]
    a = force[:, 1:] @ e_hist.real + 1j * (force[:, 1:] @ e_hist.imag)   # [B, P]
    z = lam * tau / 2
    fejer = (np.sinh(m * z) / (m * np.sinh(np.where(np.abs(z) > 0, z, 1e-30)))) ** 2
    fejer = np.where(np.abs(z) > 1e-12, fejer, 1.0)
    per_pole = poles.rho * tau * _sinhc(z) ** 2 * fejer                  # rho L_tau W
    zc = ((coef.reshape(n_b, n_s, -1)[:, :, poles.mode] * per_pole) * a[:, None, :]).reshape(n_b * n_s, -1)
    q = np.arange(q0, n_rec)
    e_out = np.exp(np.outer(lam, q * m * tau - t_end))                  # [P, Q]
    lhs = np.hstack([zc.real, -zc.imag]).astype(np.float32)
    rhs = np.vstack([e_out.real, e_out.imag]).astype(np.float32)
    return (lhs @ rhs).reshape(n_b, n_s, -1)


def modal_drops(model: Model, basis: ModalBasis, x_m, y_m, v0, *, n_record: int | None = None,
                sensors=None) -> dict:
    """Drops at (x_m, y_m) [n] with impact speeds v0 [n]: volts [n, sensors, n_record] on the ADC grid from
    the first touch, the force per step [n, steps], contact start/end and touches, as the direct run."""
    p = model.params
    x_m = np.atleast_1d(np.asarray(x_m, float))
    y_m = np.atleast_1d(np.asarray(y_m, float))
    v0 = np.atleast_1d(np.asarray(v0, float))
    n_rec = model.n_record if n_record is None else int(n_record)
    sensors = model.sensors if sensors is None else sensors
    poles = Poles(basis.omega, p.damping_per_s, p.loss_factor,
                  fem_step_s=model.dt_s if p.modal_poles == "fem_step" else None)
    phi_c, resid, out_resid = basis.contact(model, x_m, y_m)
    out = contact_window(model, poles, phi_c, resid, v0)
    force = out["force_n"]
    gains = _cached(basis, ("gains", id(sensors)), lambda: basis.sensor_gains(sensors))   # [S, modes]
    n_s = gains.shape[0]
    out_resid = out_resid * basis.output_scales(sensors)[None, :]   # [B, S]: truncated modes, quasi-static
    coef = (gains[None, :, :] * phi_c[:, None, :]).reshape(x_m.size * n_s, -1)   # c_sk phi_k(x_c)
    q0 = min(int(math.ceil(force.shape[1] / model.record_every)) + 1, n_rec)    # first sample after the force
    volts = np.zeros((x_m.size, n_s, n_rec))
    if q0 > 0:
        volts[:, :, :q0] = _early_samples(model, poles, coef, out_resid, force, q0)
    if q0 < n_rec:
        volts[:, :, q0:] = _late_samples(model, poles, coef, force, q0, n_rec, n_s)
    out["volts"] = volts
    return out
