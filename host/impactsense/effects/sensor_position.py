"""sensor_position: the disc is not where rig.json says. Units: mm.

Physical meaning: a bonding offset moves sensor i by (dx, dy); its ToA changes by -s (u_x dx + u_y dy),
u the unit vector from the sensor to the impact. Because every impact lies in the sensor's quadrant, a
shift along the sensor's mean look direction is nearly a constant delay and cannot be told from one
with a few-µs picker. The fit therefore estimates the offset across the look direction (identifiable) and
a free channel delay (which absorbs the along-look part); the selection keeps a position only when it
beats `channel_delay` on the same sensor on held-out drops. Reported dx, dy are the across-look offset.
"""

import numpy as np

from ._base import Effect, channel_columns, fit_timing, geometry, shift_channels


class SensorPosition(Effect):
    name = "sensor_position"
    units = {"dx_mm": "mm", "dy_mm": "mm", "delay_us": "µs"}
    meaning = "sensor centre offset from its declared position"
    nests = "channel_delay"
    min_offset_mm = 2.0

    def fit(self, ref, F, sensor):
        _, _, ux, uy = ref.geometry(F)
        s = ref.slowness_us_per_mm
        n = len(F)
        look = np.array([np.mean(ux[:, sensor]), np.mean(uy[:, sensor])])
        across = np.array([-look[1], look[0]]) / np.hypot(*look)
        col = np.zeros((n, 4))
        col[:, sensor] = -s * (ux[:, sensor] * across[0] + uy[:, sensor] * across[1])
        off, dl = fit_timing(ref, F, [col, channel_columns(n, sensor)])
        return {"dx_mm": float(off * across[0]), "dy_mm": float(off * across[1]),
                "offset_mm": float(abs(off)), "delay_us": float(dl)}

    def add(self, ref, sensor, params):
        out = ref.copy()
        out.sensor_xy_mm[sensor] += [params["dx_mm"], params["dy_mm"]]
        out.delay_us[sensor] += params["delay_us"]
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        d0, _ = geometry(ctx)
        sxy = np.array(ctx["sensor_xy_mm"], float)
        sxy[sensor] += [params["dx_mm"], params["dy_mm"]]
        d1, _ = geometry(ctx, sxy)
        return shift_channels(adc, (d1 - d0) * ctx["slowness_us_per_mm"]
                              + np.eye(4)[sensor] * params.get("delay_us", 0.0), ctx)

    def material(self, params):
        return np.hypot(params["dx_mm"], params["dy_mm"]) >= self.min_offset_mm
