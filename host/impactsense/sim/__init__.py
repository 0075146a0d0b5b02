"""The rig's finite-element twin: plate (MITC4 Mindlin, C++ in sim/), Hertz ball, PZT discs, ADC.

    from impactsense.data import load_rig
    from impactsense.sim import SimParams, simulate_drops
    rig = load_rig("session-folder")
    adc = simulate_drops(SimParams.from_rig(rig), rig, [160.0], [150.0], [150.0])   # uint16 [1, 4, samples]
"""

from . import dispersion
from .params import SimParams
from .simulate import SimulationError, clear_cache, simulate_drops, simulate_voltages, to_adc

__all__ = ["SimParams", "simulate_drops", "simulate_voltages", "to_adc", "dispersion", "SimulationError", "clear_cache"]
