"""wave_speed: a change of the group velocity of the first arrival (temperature, ageing). Unit: m/s.

Physical meaning: a polymer plate's stiffness falls with temperature, so the flexural wave slows on a warmer day;
every ToA changes in proportion to the travel distance. Observable: centred ToA residual ∝ distance.
"""

import numpy as np

from ._base import Effect, fit_timing, geometry, shift_channels


class WaveSpeed(Effect):
    name = "wave_speed"
    per_sensor = False
    units = {"velocity_m_s": "m/s", "change_pct": "%"}
    meaning = "group velocity change of the whole plate (temperature)"
    min_change_pct = 0.5

    def fit(self, ref, F, sensor):
        d, th, _, _ = ref.geometry(F)
        col = d * (1 + ref.aniso[0] * np.cos(2 * th) + ref.aniso[1] * np.sin(2 * th))
        (ds,) = fit_timing(ref, F, [col])
        s_new = ref.slowness_us_per_mm + ds
        return {"velocity_m_s": float(1000.0 / s_new),
                "change_pct": float(100.0 * (ref.slowness_us_per_mm / s_new - 1.0))}

    def add(self, ref, sensor, params):
        out = ref.copy()
        out.slowness_us_per_mm = 1000.0 / params["velocity_m_s"]
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        d, _ = geometry(ctx)
        s_ref = ctx["slowness_us_per_mm"]
        s_new = s_ref / (1.0 + params["change_pct"] / 100.0)
        return shift_channels(adc, d * (s_new - s_ref), ctx)

    def material(self, params):
        return abs(params["change_pct"]) >= self.min_change_pct
