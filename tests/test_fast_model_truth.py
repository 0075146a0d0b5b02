"""calibrate's fast model (calibration.arrival, picked by the core) against a mesh-converged FEM truth: on a thin
steel strip hit by a small hard ball and read by a fast logger (the kind whose 4 mm-mesh synthetic truth put the
fast model's E at the steel entry's upper bound, docs/findings.md "Session 26: calbound"), the E that explains the
FEM's picked DToA best is the FEM's own E within 5 %."""

import numpy as np

from impactsense import _core
from impactsense.calibration import arrival, plate
from impactsense.data import rig_from_dict
from impactsense.signal import core_config, core_samples
from impactsense.sim import SimParams, simulate_voltages

E_TRUE, NU = 193e9, 0.29


def _rig():
    sensors = [(60, 30), (240, 40), (330, 150), (90, 170)]
    return rig_from_dict({
        "plate_material": "stainless steel", "plate_x_mm": 400.0, "plate_y_mm": 200.0, "thickness_mm": 1.5,
        "density_kg_m3": 7900.0, "plate_support": "resting on four rubber feet",
        "sensors": [{"name": f"S{k + 1}", "channel": k, "x_mm": float(x), "y_mm": float(y)}
                    for k, (x, y) in enumerate(sensors)],
        "sensor_type": "PZT disc", "sensor_diameter_mm": 10.0, "ball_material": "silicon nitride",
        "ball_diameter_mm": 5.0, "ball_mass_g": 0.21, "channels": 4, "fs_hz": 500000, "samples": 1500,
        "adc_bits": 12, "vref": 3.3, "bias_counts": 2048})


def test_fast_model_recovers_a_converged_fem_plate_e():
    rig = _rig()
    x, y, h = np.array([150.0, 300.0, 200.0, 120.0]), np.array([100.0, 80.0, 150.0, 60.0]), np.full(4, 60.0)
    pre = 200
    params = SimParams.from_rig(rig).replace(e_pa=E_TRUE, nu=NU, element_mm=1.5, duration_ms=2.0,
                                             pretrigger_samples=pre, damping_per_s=150.0, max_height_mm=60.0)
    volts = simulate_voltages(params, rig, x, y, h, workers=1, progress=False)["volts"]
    rec = np.zeros((4, 4, rig.samples))
    take = min(volts.shape[2], rig.samples - pre)
    rec[:, :, pre:pre + take] = volts[:, :, :take]
    peak = np.full((4, 4), 300.0)
    cfg = core_config(rig, rig_delay_us=[0.0, 0.0, 0.0, 0.0])
    adc = rig.bias_counts + rec * (peak / np.abs(rec).max(-1))[..., None]
    noisy = adc + np.random.default_rng(0).normal(0.0, 1.5, adc.shape)
    toa = _core.extract_batch(core_samples(noisy, cfg), cfg)["toa_us"].astype(float)
    dtoa = toa[:, plate.PAIR_I] - toa[:, plate.PAIR_J]
    setup = arrival.setup_from_rig(rig, x, y, h)
    e_mpa = E_TRUE / 1e6 * np.array([0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15, 1.2])
    loss, _ = plate.fast_loss(setup, plate.cfg_state(cfg, int(rig.bias_counts)), peak, dtoa, e_mpa,
                              np.full(e_mpa.size, NU), noise_counts=1.5, n_noise=2)
    best = e_mpa[np.argmin(loss)]
    assert abs(best * 1e6 / E_TRUE - 1.0) <= 0.05, (e_mpa, loss)
