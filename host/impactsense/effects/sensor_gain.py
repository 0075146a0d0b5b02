"""sensor_gain: a channel's sensitivity differs (coupling, preamp, disc capacitance). Unitless ratio.

Physical meaning: every sample of channel i is multiplied by `gain`; energies by gain^2. Observable: the
centred log-energy residual of unclipped channels. Its timing consequence is measured, not assumed (the AIC
onset barely moves; a threshold crossing comes later on a weaker channel): the reference's probe recordings
are scaled by a grid of gains and each channel's pick change is fitted as a + b x distance (`gain_table`);
`add` puts the interpolated change into the reference's timing, so a gain is not also named a delay.
`noise_kept` (apply_signal): a disc's or bond's gain loss lies before the amplifier, whose noise keeps its level;
the noise the scaling takes from a recording is given back (white, the first samples' level).
"""

from dataclasses import replace as dc_replace

import numpy as np

from ..residuals import centre, _robust_lstsq
from ._base import Effect, channel_columns, to_adc, to_float

PRETRIGGER_NOISE_SAMPLES = 64   # the record's first samples: before any impact (the noise level)
NOISE_STREAM = 0x6A1                  # the given-back noise's stream beside a seed (not the low-pass's draws)
GAIN_GRID = np.array([0.4, 0.55, 0.7, 0.85, 1.0, 1.2, 1.5, 2.0])
_TABLES: dict = {}


def gain_table(probe) -> dict:
    """Per gain of GAIN_GRID (every channel scaled), each channel's ToA change (µs at zero distance, µs per mm):
    robust fits over the probe's drops."""
    import hashlib

    from ..residuals import extract
    sess, picker = probe["session"], probe.get("picker")
    key = (hashlib.sha1(np.ascontiguousarray(sess.adc).tobytes()).hexdigest(), repr(sorted((picker or {}).items())))
    if key in _TABLES:
        return _TABLES[key]
    base = extract(sess, picker)
    sxy = sess.rig.sensor_xy_mm.astype(float)
    d = np.hypot(base.x_mm[:, None] - sxy[None, :, 0], base.y_mm[:, None] - sxy[None, :, 1])
    bias = float(sess.rig.bias_counts)
    tab = np.zeros((len(GAIN_GRID), 4, 2))
    for k, g in enumerate(GAIN_GRID):
        if g == 1.0:
            continue
        F = extract(dc_replace(sess, adc=to_adc(to_float(sess.adc, bias) * g, bias, sess.rig.adc_max)), picker)
        dt = F.toa_us - base.toa_us
        for c in range(4):
            ok = np.isfinite(dt[:, c])
            if ok.sum() >= 4:
                tab[k, c], _ = _robust_lstsq(np.stack([np.ones(ok.sum()), d[ok, c]], axis=1), dt[ok, c])
    _TABLES[key] = {"gain": GAIN_GRID, "shift": tab}
    return _TABLES[key]


def gain_toa_shift(probe, sensor: int, gain: float) -> tuple[float, float]:
    """The table's (µs, µs/mm) ToA change of channel `sensor` at `gain` (log-gain interpolation)."""
    tab = gain_table(probe)
    lg = np.log(tab["gain"])
    x = float(np.clip(np.log(gain), lg[0], lg[-1]))
    return tuple(float(np.interp(x, lg, tab["shift"][:, sensor, j])) for j in range(2))


def gain_keeping_noise(a: np.ndarray, gain: float, rng=None) -> np.ndarray:
    """Recordings a [..., samples] (bias removed) scaled by gain < 1 with the noise they lose given back: fresh
    white noise of sqrt(1 - gain^2) x the first samples' level (the amplifier's noise, after the disc)."""
    sigma = a[..., :PRETRIGGER_NOISE_SAMPLES].std(axis=-1, keepdims=True)
    # a seed gets its own stream: apply_effects hands every effect the same seed (the low-pass's noise)
    gen = rng if isinstance(rng, np.random.Generator) else \
        np.random.default_rng(None if rng is None else [*np.atleast_1d(rng).tolist(), NOISE_STREAM])
    fresh = gen.standard_normal(a.shape)
    return gain * a + sigma * np.sqrt(1.0 - gain ** 2) * fresh


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
        if ref.probe is not None:   # the pick change of this gain (the table is relative to the probe's own)
            a, b = gain_toa_shift(ref.probe, sensor, params["gain"])
            out.pick_toa_us[sensor] += a
            out.pick_toa_us_per_mm[sensor] += b
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        a = to_float(adc, ctx["bias"])
        g = float(params["gain"])
        if params.get("noise_kept", False) and g < 1.0:
            # the gain is the disc's (a bond's), not the amplifier's: the amplifier's noise keeps its level
            a[:, sensor] = gain_keeping_noise(a[:, sensor], g, rng)
        else:
            a[:, sensor] *= g
        return to_adc(a, ctx["bias"], ctx["adc_max"])

    def material(self, params):
        return abs(params["gain"] - 1.0) >= self.min_change
