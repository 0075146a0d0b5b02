"""damping: the plate's wave field decays faster or slower (support, temperature, loading). Unit: 1/s.

Physical meaning: mass-proportional damping D_s adds exp(-D_s t / 2) to every mode: the log-envelope slope
of every channel changes by the same `extra_decay_per_s`. Observable: the decay rate 1..8 ms after onset.
"""

import numpy as np

from ._base import Effect, to_adc, to_float

PRETRIGGER_NOISE_SAMPLES = 64   # the record's first samples: before any impact (the noise level)


class Damping(Effect):
    name = "damping"
    per_sensor = False
    units = {"extra_decay_per_s": "1/s", "decay_per_s": "1/s"}
    meaning = "envelope decay rate of the plate"
    min_change_pct = 5.0

    def fit(self, ref, F, sensor):
        r = ref.decay_resid(F)
        d = float(np.nanmedian(r)) if np.isfinite(r).any() else float("nan")   # NaN: no decay read
        return {"extra_decay_per_s": d, "decay_per_s": float(ref.decay0_per_s + d),
                "change_pct": float(100 * d / ref.decay0_per_s)}

    def add(self, ref, sensor, params):
        out = ref.copy()
        out.decay0_per_s += params["extra_decay_per_s"]
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        """The wave field decays faster after the onset; the amplifier's noise does not: what the decay takes
        from the recorded noise is given back as fresh noise of the pre-trigger's level."""
        rng = np.random.default_rng(rng)
        a = to_float(adc, ctx["bias"])
        on = ctx["onset_samples"]  # [R, 4] from the core
        t = (np.arange(a.shape[-1])[None, None, :] - on[..., None]) / ctx["fs_hz"]
        g = np.exp(-params["extra_decay_per_s"] * np.clip(t, 0, None))
        pre = a[..., :PRETRIGGER_NOISE_SAMPLES]
        sigma = pre.std(axis=-1, keepdims=True)
        a = a * g + sigma * np.sqrt(np.clip(1.0 - g ** 2, 0.0, None)) * rng.standard_normal(a.shape)
        return to_adc(a, ctx["bias"], ctx["adc_max"])

    def material(self, params):
        return abs(params["change_pct"]) >= self.min_change_pct
