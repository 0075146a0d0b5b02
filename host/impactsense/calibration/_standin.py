"""PRIVATE test stand-in for the FEM — NOT the simulator, never used by any command.

It exists so the calibration pipeline can be exercised (tests, benchmark fallback) while or where the C++
FEM is not available. It is the infinite-plate first-arrival model of `arrival` (plate E, nu) times a
mass-proportional damping envelope exp(-D_s t / 2) and a PZT gain g31-like factor |d31| E11 / eps33,
sampled over the rig's full capture and put through the rig's ADC model. Edges are image sources with a fixed loss per bounce; it has no disc stiffness
and no contact dynamics beyond the Hertz pulse: good enough to test that calibration recovers the
parameters that generated the data, nothing more.
"""

from __future__ import annotations

import numpy as np

from . import arrival

GAIN_REF = 1.0e2    # counts per model unit at the seed's PZT (d31 -737.8 pC/N, E11 75.2 GPa, eps33 6320)


def standin_simulate(flat: dict, rig, x_mm, y_mm, height_mm, *, noise=False, seed=None,
                     t_impact_s: float = 1.0e-3) -> np.ndarray:
    x_mm, y_mm, height_mm = (np.atleast_1d(np.asarray(v, float)) for v in (x_mm, y_mm, height_mm))
    # the rectangular plate's edges by image sources (orders -1..1 in x and y), each bounce losing 20 %
    lx, ly = rig.plate_x_mm, rig.plate_y_mm
    ix, iy, refl = [], [], []
    for m in range(-1, 2):
        for sx in (1, -1):
            for n in range(-1, 2):
                for sy in (1, -1):
                    bounces = abs(2 * m - (sx < 0)) + abs(2 * n - (sy < 0))
                    ix.append(2 * m * lx + sx * x_mm)
                    iy.append(2 * n * ly + sy * y_mm)
                    refl.append((-0.8) ** bounces)
    ix, iy, refl = np.array(ix), np.array(iy), np.array(refl)            # [I, n]
    n_img = ix.shape[0]
    setup = arrival.setup_from_rig(rig, ix.ravel(), iy.ravel(), np.tile(height_mm, n_img), n_fft=int(rig.samples))
    setup = arrival.ArrivalSetup(**{**setup.__dict__, "t_impact_s": t_impact_s})
    parts = arrival.synth_unit(setup, [flat["e_pa"]], [flat["nu"]])[0]  # [I*n, 4, S]
    parts = parts.reshape(n_img, x_mm.size, 4, -1) * refl[:, None, None, None]
    unit = parts.sum(axis=0)
    t = np.arange(unit.shape[-1]) / rig.fs_hz
    env = np.exp(-0.5 * flat["damping_per_s"] * np.clip(t - t_impact_s, 0.0, None))
    gain = GAIN_REF * (abs(flat["pzt_d31_pc_n"]) / 737.8) * (flat["pzt_e11_mpa"] / 75200.0) \
        * (6320.2 / flat["pzt_eps33_rel"]) * (1.0 + 0.3 * (flat["pzt_rho_kg_m3"] - 7650.0) / 150.0 * 0.0)
    v = unit * env * gain * 1e9
    if noise:
        v = v + np.random.default_rng(seed).normal(0.0, 1.5, v.shape)
    return np.clip(np.rint(v + rig.bias_counts), 0, rig.adc_max).astype(np.uint16)
