"""The calibration's search ranges from the rig's plate material (`materials.material_for_rig`), not from any
one plate: the plate grid's E and nu span the material's priors.

Isotropic: E over the prior of e_pa, nu over the prior of nu. An orthotropic laminate: the plate grid (the
fast first-arrival model is isotropic) spans the prior of E1 scaled to the isotropic-equivalent modulus of
the typical laminate, and nu a narrow band about the typical nu12 in steps of LAMINATE_NU_STEP (the flexural
first arrivals barely see nu12; the `plate_laminate` stage then fits E1, E2 and G12 at that nu12).
"""

from __future__ import annotations

import math

from ..materials import equivalent_isotropic_ratio, material_for_rig

NU_RANGE = (0.0, 0.499)
LAMINATE_NU_BAND = 0.02      # a laminate's plate grid: nu12 +- this ...
LAMINATE_NU_STEP = 0.01      # ... in these steps (5 points)


def plate_grid_range(rig) -> dict:
    """e_min_mpa, e_max_mpa, nu_min, nu_max of the plate grid for the rig's material (a laminate's also its
    nu_step_min)."""
    mat = material_for_rig(rig)
    if mat.orthotropic:
        r = equivalent_isotropic_ratio(mat)
        e, nu = mat.e1_pa, mat.nu12
        e_lo, e_hi = e.lo * r, e.hi * r
        nu = type(nu)(nu.value, max(nu.lo, nu.value - LAMINATE_NU_BAND), min(nu.hi, nu.value + LAMINATE_NU_BAND))
    else:
        e, nu = mat.e_pa, mat.nu
        e_lo, e_hi = e.lo, e.hi
    nu_lo, nu_hi = max(nu.lo, NU_RANGE[0]), min(nu.hi, NU_RANGE[1])
    if e_hi <= e_lo:                         # a pinned constant: a narrow band around it
        e_lo, e_hi = 0.95 * e_lo, 1.05 * e_hi
    if nu_hi <= nu_lo:
        nu_lo, nu_hi = max(nu_lo - 0.02, NU_RANGE[0]), min(nu_hi + 0.02, NU_RANGE[1])
    out = {"e_min_mpa": math.floor(e_lo / 1e6), "e_max_mpa": math.ceil(e_hi / 1e6), "nu_min": round(nu_lo, 3),
           "nu_max": round(nu_hi, 3)}
    if mat.orthotropic:
        out["nu_step_min"] = LAMINATE_NU_STEP
    return out
