"""clipping: a channel saturates below the ADC rails (preamp headroom, a protection diode). Unit: counts.

Physical meaning: channel i cannot exceed rail_hi_counts (or go below rail_lo_counts). Observable: runs of
equal samples at a channel's extreme that sit at a level other than the model's rails.
"""

import numpy as np

from ._base import Effect


def _mode(v):
    v = v[v >= 0]
    if v.size == 0:
        return None, 0
    vals, cnt = np.unique(np.rint(v), return_counts=True)
    k = int(np.argmax(cnt))
    return float(vals[k]), int(cnt[k])


class Clipping(Effect):
    name = "clipping"
    units = {"rail_lo_counts": "counts", "rail_hi_counts": "counts"}
    meaning = "saturation of one channel below the ADC range"

    def fit(self, ref, F, sensor):
        hi = F.plateau_hi[:, sensor]
        lo = F.plateau_lo[:, sensor]
        vh, nh = _mode(np.where(np.abs(hi - ref.rail_hi[sensor]) > 1, hi, -1))
        vl, nl = _mode(np.where(np.abs(lo - ref.rail_lo[sensor]) > 1, lo, -1))
        return {"rail_lo_counts": float(vl if nl >= 2 else ref.rail_lo[sensor]),
                "rail_hi_counts": float(vh if nh >= 2 else ref.rail_hi[sensor]),
                "clipped_drops": int(max(nh, nl))}

    def add(self, ref, sensor, params):
        out = ref.copy()
        out.rail_lo[sensor] = params["rail_lo_counts"]
        out.rail_hi[sensor] = params["rail_hi_counts"]
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        out = adc.copy()
        out[:, sensor] = np.clip(adc[:, sensor], params["rail_lo_counts"], params["rail_hi_counts"])
        return out

    def material(self, params):
        return params["clipped_drops"] >= 2
