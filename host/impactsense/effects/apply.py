"""Putting diagnosed effects to work: into recordings, into the simulator's output, into the core's config.

`effects` is the list of a diagnose JSON (`result["effects"]`; only the significant entries are used) or
any list of {"effect", "sensor", "params"} dicts.
"""

from __future__ import annotations

import numpy as np

from .. import _core
from ..residuals import TIMING_PICKER
from ..signal import core_config, core_offset, core_samples, settings
from . import EFFECTS
from ._base import context


def _significant(effects):
    return [e for e in effects if e.get("significant", True) and e["effect"] in EFFECTS]


def apply_effects(adc: np.ndarray, effects, ctx: dict, seed=0) -> np.ndarray:
    """Recordings (uint16 [R, 4, S]) with each effect's signal model applied in turn."""
    for e in _significant(effects):
        if e["effect"] == "damping":
            off = core_offset(ctx["adc_max"])
            cfg = core_config(fs_hz=ctx["fs_hz"], adc_min=-off, adc_max=ctx["adc_max"] - off, sample_offset=off,
                              **TIMING_PICKER)
            f = _core.extract_batch(core_samples(adc, cfg), cfg)
            ctx = {**ctx, "onset_samples": np.nan_to_num(np.asarray(f["toa_aic"], float))}
        adc = EFFECTS[e["effect"]].apply_signal(adc, e["sensor"], e["params"], ctx, rng=seed)
    return adc


def simulate_with_effects(sim_params, rig, x_mm, y_mm, height_mm, effects, *, noise=True, seed=0,
                          slowness_us_per_mm=1.0 / 0.98, **kw) -> np.ndarray:
    """impactsense.sim.simulate_drops, then the diagnosed effects the simulator does not model."""
    from ..sim import simulate_drops

    adc = simulate_drops(sim_params, rig, x_mm, y_mm, height_mm, noise=noise, seed=seed, **kw)
    ctx = {"x_mm": np.asarray(x_mm, float), "y_mm": np.asarray(y_mm, float),
           "sensor_xy_mm": rig.sensor_xy_mm.astype(float), "fs_hz": float(rig.fs_hz),
           "bias": float(rig.bias_counts), "adc_max": int(rig.adc_max),
           "slowness_us_per_mm": float(slowness_us_per_mm)}
    return apply_effects(adc, effects, ctx, seed)


def core_config_with_effects(rig, effects, **overrides):
    """The core's CoreConfig for `rig` (signal.core_config with `overrides`) with the picker corrections of the
    effects (channel delays) added."""
    values = settings(rig, **overrides)
    for e in _significant(effects):
        values = EFFECTS[e["effect"]].core_overrides(values, e["sensor"], e["params"])
    return core_config(**values)


__all__ = ["apply_effects", "simulate_with_effects", "core_config_with_effects", "context"]
