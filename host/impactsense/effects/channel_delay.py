"""channel_delay: a per-channel timing offset (ADC scan order, bond line, cable). Unit: µs.

Physical meaning: channel i's samples are taken `delay_us` later than the model assumes, so every ToA
picked on channel i is late by that much (negative: early). Observable: the mean of channel i's centred
ToA residual. Feeds CoreConfig.rig_delay_us (the core subtracts it from every pick).
"""

import numpy as np

from ._base import Effect, channel_columns, fit_timing, shift_channels


class ChannelDelay(Effect):
    name = "channel_delay"
    units = {"delay_us": "µs"}
    meaning = "timing offset of one channel (scan order, bond line)"
    min_delay_us = 1.0   # a tenth of a sample: below the rig's timing resolution after averaging

    def fit(self, ref, F, sensor):
        (d,) = fit_timing(ref, F, [channel_columns(len(F), sensor)])
        return {"delay_us": float(d)}

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
