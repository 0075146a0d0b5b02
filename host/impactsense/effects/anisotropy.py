"""anisotropy: direction-dependent slowness s(θ) = s (1 + a_cos2 cos 2θ + a_sin2 sin 2θ). Unitless.

Physical meaning: an orthotropic plate (rolled/extruded sheet, residual stress) carries the wave faster
along one axis. θ is the propagation direction from the sensor to the impact... (reciprocal: the same).
"""

import numpy as np

from ._base import Effect, fit_timing, geometry, shift_channels


class Anisotropy(Effect):
    name = "anisotropy"
    per_sensor = False
    units = {"a_cos2": "1", "a_sin2": "1", "amplitude_pct": "%", "fast_axis_deg": "deg"}
    meaning = "direction-dependent wave speed (orthotropic plate)"
    min_amplitude_pct = 0.5

    def fit(self, ref, F, sensor):
        d, th, _, _ = ref.geometry(F)
        s = ref.slowness_us_per_mm
        a, b = fit_timing(ref, F, [s * d * np.cos(2 * th), s * d * np.sin(2 * th)])
        ac, as_ = ref.aniso[0] + a, ref.aniso[1] + b
        return {"a_cos2": float(ac), "a_sin2": float(as_),
                "amplitude_pct": float(100 * np.hypot(a, b)),
                "fast_axis_deg": float(np.degrees(0.5 * np.arctan2(-as_, -ac)) % 180)}

    def add(self, ref, sensor, params):
        out = ref.copy()
        out.aniso = np.array([params["a_cos2"], params["a_sin2"]])
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        d, th = geometry(ctx)
        s = ctx["slowness_us_per_mm"]
        extra = s * d * (params["a_cos2"] * np.cos(2 * th) + params["a_sin2"] * np.sin(2 * th))
        return shift_channels(adc, extra, ctx)

    def material(self, params):
        return params["amplitude_pct"] >= self.min_amplitude_pct
