"""The core's bond inverse for a retrained model (impactcore.h bond_corner_hz, bond_gain, bond_limit_hz; docs/method.md
"Bond inverse"): a partly debonded disc's first-order low-pass, as `loop.fit_bond` sized it, undone before picking."""

from __future__ import annotations

import numpy as np

BOND_LIMIT_OF_PICK = 0.5   # the inverse's lift limited at this x the other channels' pick frequency


def others_pick_hz(session, channel: int) -> float:
    """The other channels' median pick frequency on `session` (fs / pick_period, the rig's picks)."""
    from .pipeline import featurize
    from .signal import SignalConfig

    period = np.asarray(featurize(session.adc, SignalConfig.for_rig(session.rig)).raw["pick_period"], float)
    others = [k for k in range(4) if k != channel]
    return float(session.rig.fs_hz) / float(np.nanmedian(period[:, others]))


def bond_inverse_fields(session, accepted) -> dict:
    """The core's bond inverse (impactcore.h bond_corner_hz, bond_gain, bond_limit_hz) for each channel with a
    first-order bond low-pass in `accepted` (fit_bond's): its corner fc and the channel's gain g, the lift limited
    at f2 = BOND_LIMIT_OF_PICK x the other channels' pick frequency on `session` (the noise the inverse amplifies
    above it costs more than the shape it gives back). {} when there is none, or when f2 would not be above fc
    (nothing to give back); one channel at most (the core's kMaxBondChannels): else {}."""
    lows = [c for c in accepted if c.effect == "channel_lowpass" and int(c.params.get("order", 2)) == 1]
    if len(lows) != 1:
        return {}
    low = lows[0]
    ch, fc = low.sensor, float(low.params["fc_hz"])
    f2 = BOND_LIMIT_OF_PICK * others_pick_hz(session, ch)
    if not f2 > fc:
        return {}
    g = 1.0
    for c in accepted:
        if c.effect == "sensor_gain" and c.sensor == ch:
            g *= float(c.params["gain"])
    fields = {"bond_corner_hz": [0.0] * 4, "bond_gain": [1.0] * 4, "bond_limit_hz": [0.0] * 4}
    fields["bond_corner_hz"][ch], fields["bond_gain"][ch], fields["bond_limit_hz"][ch] = fc, g, f2
    return fields
