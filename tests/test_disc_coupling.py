"""The discs' mechanical coupling apart from their sensing (SimParams.disc_patch_diameter_mm, disc_stiffness_scale,
disc_mass_scale): the defaults are the perfectly bonded disc bit for bit, a zero scale is the switch turned off,
and the plate's low modes move as Rayleigh's min-max principle says: added stiffness over a larger patch (or a
stiffer bond) can only raise every natural frequency, added mass only lower it, and a smaller patch brings the
plate back towards the bare plate. Coarse meshes; seconds each."""

from __future__ import annotations

import json
from itertools import pairwise

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from impactsense.data import load_session, rig_from_dict
from impactsense.errors import ConfigError
from impactsense.sim import SimParams
from impactsense.sim.model import build_model, support_masks
from impactsense.sim.simulate import simulate_voltages
from test_sim_physics import PMMA, assembled_stiffness

MESH_MM = 6.0
N_MODES = 12


@pytest.fixture(scope="module")
def rig():
    return load_session("bundled").rig


def base(rig, **kw):
    # disc_inertia_factor 1: no rotary inertia raised under the discs (a numerical device that grows with the
    # stiffened area), so each case adds exactly the ceramic's stiffness and mass
    return SimParams.from_rig(rig, **PMMA, element_mm=MESH_MM, damping_per_s=0.0, disc_inertia_factor=1.0, **kw)


def frequencies(p, rig, n=N_MODES):
    """The n lowest natural frequencies (Hz) of the plate with its discs (simply supported; fixed dofs out)."""
    m = build_model(p, rig, duration_ms=0.1)
    k = assembled_stiffness(m.plate, m.nx, m.ny)
    held = np.concatenate([a.ravel() for a in support_masks(m.nx, m.ny, p.support)]).astype(bool)
    keep = np.flatnonzero(~held)
    dm = sp.diags(1 / np.sqrt(np.concatenate([m.mass_w, m.mass_r, m.mass_r])[keep]))
    lam = spla.eigsh(dm @ k[keep][:, keep] @ dm, k=n, sigma=-1.0, which="LM", return_eigenvectors=False)
    return np.sort(np.sqrt(np.clip(lam, 0, None))) / (2 * np.pi)


def volts(p, rig):
    p = p.replace(duration_ms=1.0, taper_ms=0.3)
    return simulate_voltages(p, rig, [80.0], [200.0], [150.0], method="direct", workers=1)["volts"]


def test_defaults_are_the_bonded_disc_bit_for_bit(rig):
    p = base(rig)
    same = p.replace(disc_patch_diameter_mm=float(rig.sensor_diameter_mm), disc_stiffness_scale=1.0,
                     disc_mass_scale=1.0)
    assert np.array_equal(volts(p, rig), volts(same, rig))


def test_zero_scale_is_the_switch_off(rig):
    p = base(rig)
    assert np.array_equal(volts(p.replace(disc_stiffness_scale=0.0), rig), volts(p.replace(disc_stiffness=False), rig))
    assert np.array_equal(volts(p.replace(disc_mass_scale=0.0), rig), volts(p.replace(disc_mass=False), rig))


def test_the_patch_moves_the_modes_by_min_max(rig):
    """Stiffness only: every frequency rises with the patch and the bond; mass only: every one falls; both:
    the shift from the bare plate shrinks with the patch. The sensing circle does not enter the modes."""
    bare = frequencies(base(rig, disc_stiffness=False, disc_mass=False), rig)
    patches = (8.0, 14.0, 20.0)
    stiff = [frequencies(base(rig, disc_mass=False, disc_patch_diameter_mm=d), rig) for d in patches]
    heavy = [frequencies(base(rig, disc_stiffness=False, disc_patch_diameter_mm=d), rig) for d in patches]
    tol = 1e-9 * bare.max()                                           # the eigensolver's, far below the shifts
    for lo, hi in zip([bare] + stiff, stiff):
        assert np.all(hi >= lo - tol)
    for lo, hi in zip([bare] + heavy, heavy):
        assert np.all(hi <= lo + tol)
    # the rig's 20 mm ceramic moves the low modes measurably (the test can fail)
    assert np.max(stiff[-1] / bare - 1) > 1e-3 and np.max(1 - heavy[-1] / bare) > 1e-3
    bonds = [frequencies(base(rig, disc_mass=False, disc_stiffness_scale=s), rig) for s in (0.25, 0.5, 1.0)]
    for lo, hi in pairwise(bonds):
        assert np.all(hi >= lo - tol)
    both = [frequencies(base(rig, disc_patch_diameter_mm=d), rig) for d in patches]
    shift = [np.sqrt(np.mean((f / bare - 1) ** 2)) for f in both]
    assert shift[0] < shift[1] < shift[2]
    # the patch, not the sensing circle: a 20 mm patch under an 8 mm sensing disc has the 20 mm disc's modes
    small_rig = rig_with_disc(rig, 8.0)
    assert np.allclose(frequencies(base(small_rig, disc_patch_diameter_mm=20.0), small_rig), both[-1], rtol=1e-9)


def rig_with_disc(rig, diameter_mm):
    raw = json.loads(json.dumps(rig.raw))
    raw["sensor_diameter_mm"] = diameter_mm
    return rig_from_dict(raw)


@pytest.mark.parametrize("field, value", [("disc_patch_diameter_mm", 0.0), ("disc_patch_diameter_mm", -5.0),
                                          ("disc_stiffness_scale", -0.1), ("disc_mass_scale", float("nan")),
                                          ("disc_stiffness_scale", "1")])
def test_bad_coupling_names_the_field(field, value):
    with pytest.raises(ConfigError, match=field):
        SimParams.from_dict({field: value})
