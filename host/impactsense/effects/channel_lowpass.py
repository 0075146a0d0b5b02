"""channel_lowpass: one channel loses its high frequencies (a partial debond, a cracked disc). Unit: Hz.

Physical meaning: a compliant bond line acts as a low-pass between plate and disc; modelled as a
second-order Butterworth low-pass with cut-off `fc_hz` on channel i (params may give `order` 1: an RC-like
first-order bond; the diagnosis's forward table is the second order's; and `noise_filtered` true when the
channel's noise is behind the low-pass too, not given back). It lowers the spectral centroid,
delays the onset (group delay) and lowers the energy. The forward model is measured, not assumed: the
effect filters a few reference recordings at a grid of cut-offs and reads the core's features, so the
fit explains the centroid, timing (its median change and its growth with distance), energy and decay
residuals of channel i jointly.
"""

from dataclasses import replace as dc_replace

import numpy as np
from scipy import signal

from ._base import Effect, to_adc, to_float

FC_GRID_HZ = np.geomspace(1000.0, 40000.0, 23)
REFINE_STEPS = np.geomspace(0.8, 1.25, 11)   # the fit's finer log grid around the best node of FC_GRID_HZ
PRETRIGGER_NOISE_SAMPLES = 64   # the record's first samples: before any impact (the noise level)


def _nanmedian_or_nan(v) -> float:
    """The median of v's finite values; NaN without a warning when there is none (a record too short for the
    decay's blocks reads no decay)."""
    v = np.asarray(v, float)
    return float(np.median(v[np.isfinite(v)])) if np.isfinite(v).any() else float("nan")


def lowpass(a: np.ndarray, fc_hz: float, fs_hz: float, order: int = 2) -> np.ndarray:
    b, a_ = signal.butter(int(order), min(fc_hz, 0.45 * fs_hz), fs=fs_hz)
    return signal.lfilter(b, a_, a, axis=-1)


def lowpass_gain_at(f_hz: float, fc_hz: float, fs_hz: float, order: int = 2) -> float:
    """|H(f)| of `lowpass` (the effect's filter) at f_hz."""
    b, a_ = signal.butter(int(order), min(fc_hz, 0.45 * fs_hz), fs=fs_hz)
    return float(np.abs(signal.freqz(b, a_, worN=[float(f_hz)], fs=fs_hz)[1][0]))


def lowpass_signal(a: np.ndarray, fc_hz: float, fs_hz: float, rng=None, order: int = 2,
                   give_back: bool = True) -> np.ndarray:
    """The bond's low-pass on recordings a [..., samples] (bias removed): it filters the disc's signal, not the
    amplifier's noise, so the noise it takes from the recording is given back (fresh noise of the first
    samples' level, through the complement of the filter)."""
    if not give_back:
        return lowpass(a, fc_hz, fs_hz, order)
    sigma = a[..., :PRETRIGGER_NOISE_SAMPLES].std(axis=-1, keepdims=True)
    fresh = np.random.default_rng(rng).standard_normal(a.shape)
    return lowpass(a, fc_hz, fs_hz, order) + sigma * (fresh - lowpass(fresh, fc_hz, fs_hz, order))


_TABLES: dict = {}


def forward_table(probe) -> dict:
    """Median change of (toa_us, log_energy, log_centroid, decay_per_s) of a channel low-passed at each fc."""
    if "lowpass_table" in probe:
        return probe["lowpass_table"]
    import hashlib
    key = (hashlib.sha1(np.ascontiguousarray(probe["session"].adc).tobytes()).hexdigest(),
           repr(sorted((probe.get("picker") or {}).items())))
    if key in _TABLES:
        probe["lowpass_table"] = _TABLES[key]
        return _TABLES[key]
    from ..residuals import extract
    sess = probe["session"]
    from ..residuals import _robust_lstsq
    base = extract(sess, probe.get("picker"))
    bias = float(sess.rig.bias_counts)
    sxy = sess.rig.sensor_xy_mm.astype(float)
    d = np.hypot(base.x_mm[:, None] - sxy[None, :, 0], base.y_mm[:, None] - sxy[None, :, 1])
    rows, slopes = [], []
    raw = to_float(sess.adc, bias)
    for fc in FC_GRID_HZ:
        a = lowpass_signal(raw, fc, sess.rig.fs_hz, rng=0)
        F = extract(dc_replace(sess, adc=to_adc(a, bias, sess.rig.adc_max)), probe.get("picker"))
        rows.append([np.nanmedian(F.toa_us - base.toa_us), np.nanmedian(F.log_energy - base.log_energy),
                     np.nanmedian(F.log_centroid - base.log_centroid),
                     _nanmedian_or_nan(F.decay_per_s - base.decay_per_s)])
        # the pick change's growth with distance (a weaker, farther arrival is picked later still)
        dt, dd = (F.toa_us - base.toa_us).ravel(), d.ravel()
        ok = np.isfinite(dt)
        (a0, a1), _ = _robust_lstsq(np.stack([np.ones(ok.sum()), dd[ok] - np.median(dd[ok])], axis=1), dt[ok])
        slopes.append(a1)
    probe["lowpass_table"] = _TABLES[key] = {"fc_hz": FC_GRID_HZ, "shift": np.array(rows),
                                             "toa_us_per_mm": np.array(slopes),
                                             "median_distance_mm": float(np.median(d))}
    return probe["lowpass_table"]


class ChannelLowpass(Effect):
    name = "channel_lowpass"
    units = {"fc_hz": "Hz"}
    meaning = "low-pass on one channel (partial debond)"
    max_fc_hz = 15000.0   # above this the first-arrival band (≈2.6 kHz centroid) is not affected

    def _shifts(self, ref, fc):
        tab = forward_table(ref.probe)
        lf = np.log(tab["fc_hz"])
        return [float(np.interp(np.log(fc), lf, tab["shift"][:, k])) for k in range(4)]

    def fit(self, ref, F, sensor):
        best = (-np.inf, None)
        base = ref.ll(F).sum()
        for fc in forward_table(ref.probe)["fc_hz"]:
            gain = self.add(ref, sensor, {"fc_hz": fc}).ll(F).sum() - base
            if gain > best[0]:
                best = (gain, fc)
        # refine on a finer log grid around the best cut-off
        fcs = best[1] * REFINE_STEPS
        gains = [self.add(ref, sensor, {"fc_hz": fc}).ll(F).sum() for fc in fcs]
        return {"fc_hz": float(fcs[int(np.argmax(gains))])}

    def resolution(self, params):
        """The refine grid's step at fc (a grid argmax: the folds often land on one node)."""
        return {"fc_hz": float(params["fc_hz"]) * float(REFINE_STEPS[1] / REFINE_STEPS[0] - 1.0)}

    def add(self, ref, sensor, params):
        dt, de, dc, dd = self._shifts(ref, params["fc_hz"])
        tab = forward_table(ref.probe)
        slope = float(np.interp(np.log(params["fc_hz"]), np.log(tab["fc_hz"]), tab["toa_us_per_mm"]))
        out = ref.copy()
        out.delay_us[sensor] += dt - slope * tab["median_distance_mm"]
        out.pick_toa_us_per_mm[sensor] += slope
        out.gain_log[sensor] += de
        out.cent_off[sensor] += dc
        out.decay_off[sensor] += dd
        return out

    def apply_signal(self, adc, sensor, params, ctx, rng=None):
        a = to_float(adc, ctx["bias"])
        a[:, sensor] = lowpass_signal(a[:, sensor], params["fc_hz"], ctx["fs_hz"], rng, params.get("order", 2),
                                      not params.get("noise_filtered", False))
        return to_adc(a, ctx["bias"], ctx["adc_max"])

    def material(self, params):
        return params["fc_hz"] <= self.max_fc_hz
