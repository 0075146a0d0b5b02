"""The plate's stiffness matrices from `SimParams`: isotropic (E, nu) or orthotropic (E1, E2, G12, nu12 in the
material axes, transverse shear G13, G23; axis 1 at `material_axes_deg` from the plate's x axis), as the
simulator takes them: a reference bending stiffness d and shear stiffness s (per element, scaled under the
discs) and the ratios of the plate's matrices to them (`_sim.Plate(material=...)`).

Homogeneous orthotropic plate (a laminate's smeared properties; no bending-stretching coupling):
    Q11 = E1 / (1 - nu12 nu21), Q22 = E2 / (1 - nu12 nu21), Q12 = nu12 Q22, Q66 = G12,  nu21 = nu12 E2 / E1,
    D = Q t^3 / 12 rotated into the plate's axes (the transformed reduced stiffness, theta = material_axes_deg),
    S = kappa t R diag(G13, G23) R^T  (R the in-plane rotation by theta).
Isotropic: D11 = D22 = D = E t^3 / 12 (1 - nu^2), D12 = nu D, D66 = (1 - nu) D / 2, S = kappa G t, and the
simulator's own isotropic element (no ratios: the isotropic twin is computed exactly as before).
"""

from __future__ import annotations

import math

import numpy as np

from ..materials import equivalent_isotropic_ratio, material_for_rig


def _q_matrix(e1, e2, g12, nu12):
    nu21 = nu12 * e2 / e1
    den = 1.0 - nu12 * nu21
    q11, q22, q12 = e1 / den, e2 / den, nu12 * e2 / den
    return q11, q22, q12, g12


def rotated_q(e1, e2, g12, nu12, theta_deg):
    """The reduced stiffness of a ply with axis 1 at theta_deg from x, in the x, y axes:
    (Q11, Q22, Q12, Q66, Q16, Q26) [Pa], the moments' convention M = D (k_xx, k_yy, 2 k_xy)."""
    q11, q22, q12, q66 = _q_matrix(e1, e2, g12, nu12)
    th = math.radians(theta_deg)
    c, s = math.cos(th), math.sin(th)
    c2, s2 = c * c, s * s
    b11 = q11 * c2 * c2 + 2 * (q12 + 2 * q66) * s2 * c2 + q22 * s2 * s2
    b22 = q11 * s2 * s2 + 2 * (q12 + 2 * q66) * s2 * c2 + q22 * c2 * c2
    b12 = (q11 + q22 - 4 * q66) * s2 * c2 + q12 * (s2 * s2 + c2 * c2)
    b66 = (q11 + q22 - 2 * q12 - 2 * q66) * s2 * c2 + q66 * (s2 * s2 + c2 * c2)
    b16 = (q11 - q12 - 2 * q66) * s * c * c2 + (q12 - q22 + 2 * q66) * s * s2 * c
    b26 = (q11 - q12 - 2 * q66) * s * s2 * c + (q12 - q22 + 2 * q66) * s * c * c2
    return b11, b22, b12, b66, b16, b26


def orthotropic(p) -> bool:
    return p.e2_pa is not None


def shear_moduli(p):
    """(G13, G23) [Pa]: SimParams g13_pa / g23_pa, each defaulting to G12."""
    return (p.g13_pa if p.g13_pa is not None else p.g12_pa,
            p.g23_pa if p.g23_pa is not None else p.g12_pa)


def bending_matrix(p) -> np.ndarray:
    """The plate's 3x3 bending matrix [N m] in the plate's axes (rows M_xx, M_yy, M_xy)."""
    t = p.thickness_mm * 1e-3
    if not orthotropic(p):
        d = p.e_pa * t ** 3 / (12 * (1 - p.nu ** 2))
        return d * np.array([[1, p.nu, 0], [p.nu, 1, 0], [0, 0, (1 - p.nu) / 2]])
    b11, b22, b12, b66, b16, b26 = rotated_q(p.e_pa, p.e2_pa, p.g12_pa, p.nu, p.material_axes_deg)
    return t ** 3 / 12 * np.array([[b11, b12, b16], [b12, b22, b26], [b16, b26, b66]])


def shear_matrix(p) -> np.ndarray:
    """The plate's 2x2 transverse shear matrix kappa t G [N/m] in the plate's axes (Q_x, Q_y from gamma_xz,
    gamma_yz)."""
    t = p.thickness_mm * 1e-3
    if not orthotropic(p):
        return p.shear_factor * p.e_pa / (2 * (1 + p.nu)) * t * np.eye(2)
    g13, g23 = shear_moduli(p)
    th = math.radians(p.material_axes_deg)
    r = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    return p.shear_factor * t * r @ np.diag([g13, g23]) @ r.T


def element_constants(p):
    """(d, s, ratios): the reference bending and shear stiffness per element and the material ratios for
    `_sim.Plate` (None for an isotropic plate: the simulator's isotropic element, exactly as before)."""
    t = p.thickness_mm * 1e-3
    if not orthotropic(p):
        g = p.e_pa / (2 * (1 + p.nu))
        return p.e_pa * t ** 3 / (12 * (1 - p.nu ** 2)), p.shear_factor * g * t, None
    dm, sm = bending_matrix(p), shear_matrix(p)
    d, s = float(dm[0, 0]), float(sm[0, 0])
    ratios = np.array([dm[0, 0], dm[0, 1], dm[1, 1], dm[2, 2], dm[0, 2], dm[1, 2]]) / d
    ratios = np.concatenate([ratios, np.array([sm[0, 0], sm[1, 1], sm[0, 1]]) / s])
    return d, s, np.ascontiguousarray(ratios, float)


def directional_bending(p, angle_deg) -> np.ndarray:
    """D(phi) [N m]: the bending stiffness a straight-crested flexural wave travelling at angle_deg from x
    feels (Kirchhoff), n^T-weighted: D11 c^4 + 4 D16 c^3 s + 2 (D12 + 2 D66) c^2 s^2 + 4 D26 c s^3 + D22 s^4."""
    dm = bending_matrix(p)
    phi = np.radians(np.asarray(angle_deg, float))
    c, s = np.cos(phi), np.sin(phi)
    return (dm[0, 0] * c ** 4 + 4 * dm[0, 2] * c ** 3 * s + 2 * (dm[0, 1] + 2 * dm[2, 2]) * c ** 2 * s ** 2
            + 4 * dm[1, 2] * c * s ** 3 + dm[1, 1] * s ** 4)


def softest(p):
    """(D, S): the smallest directional bending stiffness and the smallest principal shear stiffness, the
    pair that gives the shortest flexural wavelength (mesh size, Eq. 1)."""
    d_min = float(np.min(directional_bending(p, np.arange(0.0, 180.0, 1.0))))
    return d_min, float(np.min(np.linalg.eigvalsh(shear_matrix(p))))


def contact_modulus(p) -> tuple[float, float]:
    """(E, nu) of the plate for the Hertz contact: E (isotropic) or the transverse modulus E2 with nu12 (a
    laminate's indentation stiffness is set by its matrix-dominated through-thickness modulus, ~E2)."""
    return (p.e2_pa if orthotropic(p) else p.e_pa), p.nu


MATERIAL_FIELDS = ("e_pa", "nu", "e2_pa", "g12_pa", "g13_pa", "g23_pa", "material_axes_deg")


def fields_for_rig(rig, defaults, overrides: dict) -> dict:
    """SimParams' material fields for the rig's plate (`materials.material_for_rig`: rig.json plate_material,
    optional material_axes / material_properties) with `overrides` applied: an orthotropic material's typical
    E1, E2, G12, nu12 and fibre angle; an isotropic material's typical E and nu, unless the defaults
    (`defaults`, a SimParams) lie inside the material's priors, which keeps them (they are a calibrated
    plate's values). A laminate given a bare e_pa (no e2_pa: the calibration's plate modulus, which its
    isotropic first-arrival grid fits) takes it as the isotropic-equivalent modulus
    (`equivalent_isotropic_ratio`): the table's laminate, every modulus scaled alike."""
    mat = material_for_rig(rig)
    typ = mat.typical()
    given = {k: overrides[k] for k in MATERIAL_FIELDS if k in overrides}
    if not mat.orthotropic:
        inside = all(getattr(mat, n).lo <= getattr(defaults, n) <= getattr(mat, n).hi for n in ("e_pa", "nu"))
        return {**({} if inside else dict(e_pa=typ["e_pa"], nu=typ["nu"])), **given}
    out = dict(e_pa=typ["e1_pa"], nu=typ["nu12"], e2_pa=typ["e2_pa"], g12_pa=typ["g12_pa"],
               material_axes_deg=float(mat.axis_deg))
    if "e_pa" in given and "e2_pa" not in given:
        scale = given.pop("e_pa") / (typ["e1_pa"] * equivalent_isotropic_ratio(mat))
        out.update(e_pa=typ["e1_pa"] * scale, e2_pa=typ["e2_pa"] * scale, g12_pa=typ["g12_pa"] * scale)
    return {**out, **given}
