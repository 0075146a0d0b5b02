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
    return a0_wavenumber_ds(f_hz, *_consts(e_pa, nu, rho_kg_m3, t_m, kappa))


def a0_wavenumber_ds(f_hz, d, s, i, m):
    """A0 wavenumber from the plate's bending stiffness d [N m], shear stiffness s [N/m], rotary inertia i
    [kg] and mass m [kg/m^2] per area: along a principal axis of an orthotropic plate, d = D11 (or D22) and
    s = S_xx (or S_yy)."""
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


def ss_orthotropic_frequencies(a_m, b_m, dm, sm, rho_kg_m3, t_m, count=10, max_index=12):
    """Lowest natural frequencies [Hz] of a hard simply supported, specially orthotropic (D16 = D26 = 0,
    S_xy = 0) rectangular plate: Mindlin (Navier modes, 3x3 per (m, n)) and Kirchhoff
    f_mn = (pi / 2) sqrt(D11 (m/a)^4 + 2 (D12 + 2 D66) (m/a)^2 (n/b)^2 + D22 (n/b)^4) / sqrt(rho t).
    dm: 3x3 bending matrix [N m], sm: 2x2 shear matrix [N/m]. Returns (mindlin, kirchhoff, [(m, n)]) in the
    order of the Mindlin frequencies."""
    d11, d12, d22, d66 = dm[0][0], dm[0][1], dm[1][1], dm[2][2]
    sx, sy = sm[0][0], sm[1][1]
    mass, i = rho_kg_m3 * t_m, rho_kg_m3 * t_m ** 3 / 12
    out = []
    for mi in range(1, max_index + 1):
        for ni in range(1, max_index + 1):
            al, be = mi * np.pi / a_m, ni * np.pi / b_m
            k = np.array([
                [sx * al ** 2 + sy * be ** 2, sx * al, sy * be],
                [sx * al, d11 * al ** 2 + d66 * be ** 2 + sx, (d12 + d66) * al * be],
                [sy * be, (d12 + d66) * al * be, d66 * al ** 2 + d22 * be ** 2 + sy],
            ])
            mm = np.array([mass, i, i])
            lam = np.linalg.eigvalsh(k / np.sqrt(np.outer(mm, mm)))
            f_k = math.pi / 2 * math.sqrt(d11 * (mi / a_m) ** 4 + 2 * (d12 + 2 * d66) * (mi / a_m) ** 2 * (ni / b_m) ** 2
                                          + d22 * (ni / b_m) ** 4) / math.sqrt(mass)
            out.append((math.sqrt(lam.min()) / (2 * np.pi), f_k, (mi, ni)))
    out.sort()
    out = out[:count]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out]), [o[2] for o in out]
