"""noise: the noise floor rises (white, counts rms) and/or mains hum appears (amplitude, counts, 50/60 Hz).

Physical meaning: a ground loop, a longer cable, a noisy supply. Observables: the core's pre-trigger noise
RMS (white part) and a least-squares lock-in at 50 and 60 Hz over the quiet tail (the pre-trigger is
1.3 ms, too short to see 50 Hz; the baseline removal hides it there). sensor None: every channel.
"""

import numpy as np

from ..residuals import HUM_HZ
from ._base import Effect, to_adc, to_float


class Noise(Effect):
    name = "noise"
    units = {"white_rms_counts": "counts", "hum_counts": "counts", "hum_hz": "Hz"}
    meaning = "noise floor and mains hum"
    min_white_counts = 0.5
    min_hum_counts = 0.5

    def candidates(self):
        return [None, 0, 1, 2, 3]

    def _chans(self, sensor):
        return [0, 1, 2, 3] if sensor is None else [sensor]

    def fit(self, ref, F, sensor):
        ch = self._chans(sensor)
        rms2 = np.exp(2 * F.log_noise[:, ch]).mean()
        ref2 = np.exp(2 * ref.log_noise[ch]).mean()
        white = float(np.sqrt(max(rms2 - ref2, 0.0)))
        a2 = (F.hum_counts[:, ch, :] ** 2).mean(axis=(0, 1)) - ref.hum2[ch].mean(axis=0)
        k = int(np.argmax(a2))
        return {"white_rms_counts": white, "hum_counts": float(np.sqrt(max(a2[k], 0.0))),
                "hum_hz": float(HUM_HZ[k])}

    def add(self, ref, sensor, params):
        out = ref.copy()
        ch = self._chans(sensor)
        out.log_noise[ch] = 0.5 * np.log(np.exp(2 * out.log_noise[ch]) + params["white_rms_counts"] ** 2)
        k = HUM_HZ.index(params["hum_hz"])
        out.hum2[ch, k] += params["hum_counts"] ** 2
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        rng = np.random.default_rng(rng)
        a = to_float(adc, ctx["bias"])
        ch = self._chans(sensor)
        t = np.arange(a.shape[-1]) / ctx["fs_hz"]
        for c in ch:
            a[:, c] += rng.normal(0, params["white_rms_counts"], size=a[:, c].shape)
            ph = rng.uniform(0, 2 * np.pi, size=(a.shape[0], 1))
            a[:, c] += params["hum_counts"] * np.sin(2 * np.pi * params["hum_hz"] * t[None] + ph)
        return to_adc(a, ctx["bias"], ctx["adc_max"])

    def material(self, params):
        return params["white_rms_counts"] >= self.min_white_counts or \
            params["hum_counts"] >= self.min_hum_counts
