"""sensor_gain: a channel's sensitivity differs (coupling, preamp, disc capacitance). Unitless ratio.

Physical meaning: every sample of channel i is multiplied by `gain`; energies by gain^2. Observable: the
centred log-energy residual of unclipped channels.
"""

import numpy as np

from ..residuals import centre, _robust_lstsq
from ._base import Effect, channel_columns, to_adc, to_float


class SensorGain(Effect):
    name = "sensor_gain"
    units = {"gain": "1"}
    meaning = "amplitude sensitivity of one channel"
    min_change = 0.05

    def fit(self, ref, F, sensor):
        m = ~ref.clip_mask(F)
        r = ref.energy_resid(F)
        col = centre(channel_columns(len(F), sensor), m)
        sol, _ = _robust_lstsq(col[m][:, None], r[m])
        return {"gain": float(np.exp(sol[0] / 2))}

    def add(self, ref, sensor, params):
        out = ref.copy()
        out.gain_log[sensor] += 2 * np.log(params["gain"])
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        a = to_float(adc, ctx["bias"])
        a[:, sensor] *= params["gain"]
        return to_adc(a, ctx["bias"], ctx["adc_max"])

    def material(self, params):
        return abs(params["gain"] - 1.0) >= self.min_change
