"""sensor_position: the disc is not where rig.json says. Units: mm.

Physical meaning: a bonding offset moves sensor i by (dx, dy). Its ToA changes by -s (u_x dx + u_y dy), u
the unit vector from the sensor to the impact: a direction-dependent timing signature. A shift along the
sensor's mean look direction is nearly a constant delay; the two are rivals, not nested: the selection
compares their held-out log-likelihoods (`channel_delay` on the same sensor), so a move is named only where
the data tell its direction dependence from a constant delay.

The energy model keeps the declared position (`Reference.energy_sensor_xy_mm`): a re-glued disc's energy
did not follow the moved path lengths (on FEM sessions with a known move the true offset's energy term,
geometric law or the reference's site map shifted with the disc, scored below no move at all:
docs/findings.md), so the move is told by its timing alone.

Fit: the linearised timing least squares gives (dx, dy); a 2-D search of the timing log-likelihood (Huber)
around it refines them.
"""

import numpy as np
from scipy import optimize

from ._base import Effect, fit_timing, geometry, shift_channels


class SensorPosition(Effect):
    name = "sensor_position"
    units = {"dx_mm": "mm", "dy_mm": "mm", "offset_mm": "mm"}
    meaning = "sensor centre offset from its declared position"
    min_offset_mm = 2.0

    def fit(self, ref, F, sensor):
        _, _, ux, uy = ref.geometry(F)
        s = ref.slowness_us_per_mm
        n = len(F)
        cx, cy = np.zeros((n, 4)), np.zeros((n, 4))
        cx[:, sensor] = -s * ux[:, sensor]
        cy[:, sensor] = -s * uy[:, sensor]
        dx0, dy0 = fit_timing(ref, F, [cx, cy])

        def nll(v):
            m = self.add(ref, sensor, {"dx_mm": v[0], "dy_mm": v[1]})
            g = m.ll_groups(F)
            return -float(g["timing"].sum())

        res = optimize.minimize(nll, [dx0, dy0], method="Nelder-Mead",
                                options={"xatol": 0.05, "fatol": 0.01, "maxiter": 120})
        dx, dy = (float(v) for v in res.x) if res.fun <= nll([dx0, dy0]) else (float(dx0), float(dy0))
        return {"dx_mm": dx, "dy_mm": dy, "offset_mm": float(np.hypot(dx, dy))}

    def add(self, ref, sensor, params):
        out = ref.copy()
        if out.energy_sensor_xy_mm is None:
            out.energy_sensor_xy_mm = ref.sensor_xy_mm.copy()
        out.sensor_xy_mm[sensor] += [params["dx_mm"], params["dy_mm"]]
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        d0, _ = geometry(ctx)
        sxy = np.array(ctx["sensor_xy_mm"], float)
        sxy[sensor] += [params["dx_mm"], params["dy_mm"]]
        d1, _ = geometry(ctx, sxy)
        return shift_channels(adc, (d1 - d0) * ctx["slowness_us_per_mm"], ctx)

    def material(self, params):
        return np.hypot(params["dx_mm"], params["dy_mm"]) >= self.min_offset_mm
