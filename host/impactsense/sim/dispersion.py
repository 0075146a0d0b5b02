"""Mindlin plate dispersion: the flexural (A0) branch, phase and group velocity (Mindlin 1951).

Plane wave w, psi ~ exp(i (k x - omega t)) in a Mindlin plate (D = E t^3 / 12(1 - nu^2), S = kappa G t,
I = rho t^3 / 12, m = rho t):
    (S k^2 - m omega^2) (D k^2 + S - I omega^2) - S^2 k^2 = 0,
a quadratic in K = k^2:  K^2 - omega^2 (I/D + m/S) K - (m omega^2 / D)(1 - I omega^2 / S) = 0.
Below the thickness-shear cut-off omega^2 = S / I the positive root is the propagating A0 wave.
"""

from __future__ import annotations

import math

import numpy as np

KAPPA_MINDLIN = math.pi ** 2 / 12


def _consts(e_pa, nu, rho, t_m, kappa):
    g = e_pa / (2 * (1 + nu))
    d = e_pa * t_m ** 3 / (12 * (1 - nu ** 2))
    s = kappa * g * t_m
    return d, s, rho * t_m ** 3 / 12, rho * t_m


def a0_wavenumber(f_hz, e_pa, nu, rho_kg_m3, t_m, kappa=KAPPA_MINDLIN):
    """A0 wavenumber k [rad/m] at frequency f_hz (array-like)."""
    d, s, i, m = _consts(e_pa, nu, rho_kg_m3, t_m, kappa)
    w2 = (2 * np.pi * np.asarray(f_hz, float)) ** 2
    b = w2 * (i / d + m / s)
    c = m * w2 / d * (1 - i * w2 / s)
    big_k = 0.5 * (b + np.sqrt(b * b + 4 * c))
    return np.sqrt(big_k)


def a0_phase_velocity(f_hz, e_pa, nu, rho_kg_m3, t_m, kappa=KAPPA_MINDLIN):
    """Phase velocity omega / k [m/s]."""
    f = np.asarray(f_hz, float)
    return 2 * np.pi * f / a0_wavenumber(f, e_pa, nu, rho_kg_m3, t_m, kappa)


def a0_group_velocity(f_hz, e_pa, nu, rho_kg_m3, t_m, kappa=KAPPA_MINDLIN):
    """Group velocity d omega / d k [m/s] (central difference of k(omega), relative step 1e-5)."""
    f = np.asarray(f_hz, float)
    h = 1e-5 * f
    dk = a0_wavenumber(f + h, e_pa, nu, rho_kg_m3, t_m, kappa) - a0_wavenumber(f - h, e_pa, nu, rho_kg_m3, t_m, kappa)
    return 2 * np.pi * 2 * h / dk


def a0_wavelength(f_hz, e_pa, nu, rho_kg_m3, t_m, kappa=KAPPA_MINDLIN):
    return 2 * np.pi / a0_wavenumber(f_hz, e_pa, nu, rho_kg_m3, t_m, kappa)


def ss_plate_frequencies(a_m, b_m, e_pa, nu, rho_kg_m3, t_m, kappa=KAPPA_MINDLIN, count=10, max_index=12):
    """Lowest natural frequencies [Hz] of a (hard) simply supported rectangular Mindlin plate.

    Navier modes w = W sin(m pi x / a) sin(n pi y / b); each (m, n) gives a 3x3 eigenproblem whose lowest
    root is the flexural mode. Returns (frequencies, [(m, n), ...]) sorted ascending.
    """
    d, s, i, mass = _consts(e_pa, nu, rho_kg_m3, t_m, kappa)
    out = []
    for mi in range(1, max_index + 1):
        for ni in range(1, max_index + 1):
            al, be = mi * np.pi / a_m, ni * np.pi / b_m
            k = np.array([
                [s * (al ** 2 + be ** 2), s * al, s * be],
                [s * al, d * (al ** 2 + (1 - nu) / 2 * be ** 2) + s, d * al * be * (1 + nu) / 2],
                [s * be, d * al * be * (1 + nu) / 2, d * (be ** 2 + (1 - nu) / 2 * al ** 2) + s],
            ])
            mm = np.array([mass, i, i])
            lam = np.linalg.eigvalsh(k / np.sqrt(np.outer(mm, mm)))  # M^-1/2 K M^-1/2
            out.append((math.sqrt(lam.min()) / (2 * np.pi), (mi, ni)))
    out.sort()
    return np.array([f for f, _ in out[:count]]), [mn for _, mn in out[:count]]
