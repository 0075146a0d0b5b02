"""channel_delay: a per-channel timing offset (ADC scan order, bond line, cable). Unit: µs.

Physical meaning: channel i's samples are taken `delay_us` later than the model assumes, so every ToA
picked on channel i is late by that much (negative: early). Observable: the mean of channel i's centred
ToA residual. Feeds CoreConfig.rig_delay_us (the core subtracts it from every pick).

The size is fitted on both pick sets where the reference has band picks (`band_timing`), as the move's fit
is (`effects.sensor_position`): a delay shifts the channel's whole recording, so its threshold and band picks
alike. The threshold picks alone under-read a delay that is not a whole number of samples on a plate whose
onset is sampled near the Nyquist rate (docs/findings.md, "Session 18: delaysize"); the band picks follow it.
"""

import numpy as np

from scipy import optimize

from ..band_timing import band_resid
from ..residuals import huber_ll
from ._base import Effect, channel_columns, fit_timing, shift_channels
from .sensor_position import band_ll


BOTH_PICK_SETS = True   # switch: False fits the threshold picks alone (the size before delaysize)


class ChannelDelay(Effect):
    name = "channel_delay"
    units = {"delay_us": "µs"}
    meaning = "timing offset of one channel (scan order, bond line)"
    min_delay_us = 1.0   # a tenth of a sample: below the rig's timing resolution after averaging

    def fit(self, ref, F, sensor):
        (d0,) = fit_timing(ref, F, [channel_columns(len(F), sensor)])
        if not BOTH_PICK_SETS or band_resid(ref, F) is None:
            return {"delay_us": float(d0)}
        def nll(d):
            m = self.add(ref, sensor, {"delay_us": d})
            timing = huber_ll(m.toa_resid(F) / m.sigma["timing"])
            return -float(np.nansum(timing)) - float(band_ll(m, F).sum())

        span = 3.0 * float(ref.band["sigma_us"])   # the band picks' reference scale bounds the search
        res = optimize.minimize_scalar(nll, bounds=(d0 - span, d0 + span), method="bounded",
                                       options={"xatol": 0.01})
        return {"delay_us": float(res.x) if res.fun <= nll(d0) else float(d0)}

    def add(self, ref, sensor, params):
        out = ref.copy()
        out.delay_us[sensor] += params["delay_us"]
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        s = np.zeros((adc.shape[0], 4))
        s[:, sensor] = params["delay_us"]
        return shift_channels(adc, s, ctx)

    def core_overrides(self, values, sensor, params):
        d = list(values["rig_delay_us"])
        d[sensor] += params["delay_us"]
        return {**values, "rig_delay_us": d}

    def material(self, params):
        return abs(params["delay_us"]) >= self.min_delay_us
