"""A lightly damped plate (glass on rubber pads, D_s ~40 1/s): calibrate's decay stage keeps what it measures. Before,
the estimate was clipped to the PZT design's screening range (200..1200 1/s), so the twin of a plate that rings
for the whole record was 5x too damped (docs/findings.md "Session 25: newuser6")."""

from types import SimpleNamespace

import numpy as np
import pytest

from impactsense.calibration import design, fem, stages
from impactsense.calibration.damping import FLOOR_PER_S
from impactsense.data import rig_from_dict
from impactsense.signal import SignalConfig

FS, N, PRE, BIAS = 96000, 2048, 300, 32768


def _rig():
    sensors = [{"name": f"S{k + 1}", "channel": k, "x_mm": x, "y_mm": y}
               for k, (x, y) in enumerate([(118, 64), (532, 131), (488, 402), (71, 318)])]
    return rig_from_dict({"plate_material": "soda-lime glass", "plate_x_mm": 600.0, "plate_y_mm": 450.0,
                          "thickness_mm": 6.0, "density_kg_m3": 2500.0, "plate_support": "four rubber pads",
                          "sensors": sensors, "channels": 4, "sensor_diameter_mm": 20.0,
                          "ball_material": "steel", "ball_diameter_mm": 10.0, "ball_mass_g": 4.07,
                          "fs_hz": FS, "samples": N, "adc_bits": 16, "vref": 20.0, "bias_counts": BIAS})


def _ring(d_s, n_cases, seed):
    """Records [n, 4, N]: a dense ring (many modes, random phases) from PRE whose amplitude decays as
    exp(-d_s t / 2) (the mass-proportional damping), peak ~2000 counts."""
    rng = np.random.default_rng(seed)
    t = (np.arange(N) - PRE) / FS
    f = rng.uniform(2e3, 20e3, (n_cases, 4, 40, 1))
    ph = rng.uniform(0, 2 * np.pi, f.shape)
    x = np.sin(2 * np.pi * f * np.clip(t, 0, None) + ph).sum(axis=2) * np.where(t >= 0, 1.0, 0.0)
    x *= np.exp(-0.5 * d_s * np.clip(t, 0, None)) * 2000.0 / np.abs(x).max(axis=-1, keepdims=True)
    return x


@pytest.mark.parametrize("truth", [40.0, 600.0])
def test_decay_stage_keeps_a_light_damping(truth):
    rig = _rig()
    cfg = SignalConfig.for_rig(rig).core()
    rng = np.random.default_rng(0)
    meas = np.clip(np.rint(BIAS + _ring(truth, 4, 1) + rng.normal(0, 2.0, (4, 4, N))), 0, 65535).astype(np.uint16)
    targets = SimpleNamespace(recording_ids=[[k] for k in range(4)], x_mm=np.zeros(4), y_mm=np.zeros(4),
                              height_mm=np.full(4, 150.0), noise_rms=np.full((4, 4), 2.0),
                              peak=np.abs(meas.astype(float) - BIAS).max(axis=-1))

    def simulate(p, rig_, x, y, h):   # the "twin": the same ring at the D_s it is asked for
        return np.clip(np.rint(BIAS + _ring(p["damping_per_s"], 4, 1)), 0, 65535).astype(np.uint16)

    class _Session(SimpleNamespace):
        def __len__(self):
            return len(self.adc)

    problem = SimpleNamespace(targets=targets, session=_Session(adc=meas), rig=rig, cfg=cfg, cfg_sim=cfg,
                              params={"damping_per_s": 1086.0}, simulate=simulate, noise=(2.0, 1, 0))
    got = stages._damping(problem, None)
    assert got["damping_per_s"] == pytest.approx(truth, abs=max(8.0, 0.05 * truth))
    assert got["in_range"] == (truth >= fem.factor_range("damping_per_s")[0])


def test_the_design_holds_a_light_damping_where_it_was_measured():
    """The design's optimisation and infill hold D_s at the decay's value: under the screening range too."""
    i = fem.FACTOR_NAMES.index("damping_per_s")
    for d_s, held in ((40.0, 40.0), (282.0, 282.0), (913.0, 913.0), (2.0, FLOOR_PER_S), (5000.0, 1200.0)):
        u = np.full(len(fem.FACTORS), 0.5)
        u[i] = design.unit_damping(d_s)
        assert design.unit_to_params(u)[i] == pytest.approx(held)
    assert stages._ds_bounds(40.0) == (40.0, 1200.0) and stages._ds_bounds(282.0) == (200.0, 1200.0)
