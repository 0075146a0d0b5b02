"""noise: the noise floor rises (white, counts rms) and/or mains hum appears (amplitude, counts, 50/60 Hz).

Physical meaning: a ground loop, a longer cable, a noisy supply. Observables: the core's pre-trigger noise
RMS (white part) and a least-squares lock-in at 50 and 60 Hz over the quiet tail (the pre-trigger is
1.3 ms, too short to see 50 Hz; the baseline removal hides it there). sensor None: every channel.

A raised noise floor also moves the core's picks (a weak, far arrival is picked later) and energies: that
forward model is measured, not assumed: white noise of a grid of levels is added to a few reference
recordings and the core's ToA and energy changes are fitted per channel as a + b x distance
(`noise_table`), so a noisy session's slower-looking picks are explained by the noise, not named a slower
plate; the decay rate's change (fewer blocks above a higher noise) is measured the same way.
"""

from dataclasses import replace as dc_replace

import numpy as np

from ..residuals import HUM_HZ, hum_white_gain
from ._base import Effect, to_adc, to_float

WHITE_GRID_COUNTS = np.array([0.0, 1.0, 2.0, 4.0, 8.0, 16.0])
# draws per level: with 2 the table's ToA slope per mm scattered by ~0.03 us/mm at 10 counts, and a noisy
# session was also named a slower plate (docs/findings.md, issue 16)
NOISE_DRAWS = 6
_TABLES: dict = {}


def noise_table(probe, chans: tuple) -> dict:
    """Per white level of WHITE_GRID_COUNTS added on `chans`, each channel's (ToA shift at zero distance µs,
    ToA shift per mm, log-energy shift per mm, decay-rate shift 1/s): robust fits (the decay: the median)
    over the probe's drops and NOISE_DRAWS draws."""
    import hashlib

    from ..residuals import _robust_lstsq, extract
    sess = probe["session"]
    key = (hashlib.sha1(np.ascontiguousarray(sess.adc).tobytes()).hexdigest(), chans,
           repr(sorted((probe.get("picker") or {}).items())))
    if key in _TABLES:
        return _TABLES[key]
    base = extract(sess, probe.get("picker"))
    sxy = sess.rig.sensor_xy_mm.astype(float)
    d = np.hypot(base.x_mm[:, None] - sxy[None, :, 0], base.y_mm[:, None] - sxy[None, :, 1])
    bias = float(sess.rig.bias_counts)
    rng = np.random.default_rng(0)
    tab = np.zeros((len(WHITE_GRID_COUNTS), 4, 4))
    for k, w in enumerate(WHITE_GRID_COUNTS[1:], start=1):
        dt, de, dd, ok_e, dk = [], [], [], [], []
        for _ in range(NOISE_DRAWS):
            a = to_float(sess.adc, bias)
            a[:, list(chans)] += rng.normal(0.0, w, a[:, list(chans)].shape)
            F = extract(dc_replace(sess, adc=to_adc(a, bias, sess.rig.adc_max)), probe.get("picker"))
            dt.append(F.toa_us - base.toa_us)
            de.append(F.log_energy - base.log_energy)
            dk.append(F.decay_per_s - base.decay_per_s)
            ok_e.append(~(F.clipped | base.clipped))
            dd.append(d)
        dt, de, dd, ok_e, dk = (np.concatenate(v) for v in (dt, de, dd, ok_e, dk))
        for c in chans:
            ok = np.isfinite(dt[:, c])
            X = np.stack([np.ones(ok.sum()), dd[ok, c]], axis=1)
            (a0, a1), _ = _robust_lstsq(X, dt[ok, c])
            ok = ok_e[:, c] & np.isfinite(de[:, c])
            X = np.stack([np.ones(ok.sum()), dd[ok, c]], axis=1)
            (_, b1), _ = _robust_lstsq(X, de[ok, c])
            decay = dk[:, c][np.isfinite(dk[:, c])]
            tab[k, c] = (a0, a1, b1, float(np.median(decay)) if decay.size else 0.0)
    _TABLES[key] = {"white_counts": WHITE_GRID_COUNTS, "shift": tab}
    return _TABLES[key]


def _white_gain(ref) -> np.ndarray:
    """The hum lock-in's reading per unit white-noise power (0 without the reference's recordings)."""
    if ref.probe is None:
        return np.zeros(len(HUM_HZ))
    rig = ref.probe["session"].rig
    return hum_white_gain(rig.fs_hz, rig.samples)


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
        a2 = (F.hum_counts[:, ch, :] ** 2).mean(axis=(0, 1)) - ref.hum2[ch].mean(axis=0) \
            - white ** 2 * _white_gain(ref)
        k = int(np.argmax(a2))
        return {"white_rms_counts": white, "hum_counts": float(np.sqrt(max(a2[k], 0.0))),
                "hum_hz": float(HUM_HZ[k])}

    def add(self, ref, sensor, params):
        out = ref.copy()
        ch = self._chans(sensor)
        out.log_noise[ch] = 0.5 * np.log(np.exp(2 * out.log_noise[ch]) + params["white_rms_counts"] ** 2)
        k = HUM_HZ.index(params["hum_hz"])
        out.hum2[ch, k] += params["hum_counts"] ** 2
        out.hum2[ch] += params["white_rms_counts"] ** 2 * _white_gain(ref)   # the lock-in reads white noise too
        if ref.probe is not None and params["white_rms_counts"] > 0:
            tab = noise_table(ref.probe, tuple(ch))
            w = np.clip(params["white_rms_counts"], 0.0, tab["white_counts"][-1])
            for c in ch:
                a0, a1, b1, k1 = (float(np.interp(w, tab["white_counts"], tab["shift"][:, c, j])) for j in range(4))
                out.noise_toa_us[c] += a0
                out.noise_toa_us_per_mm[c] += a1
                out.noise_log_energy_per_mm[c] += b1
                out.decay_off[c] += k1
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

    def bounds(self, params):
        """Both amplitudes are rms / peak counts: never below zero (fit clamps them there)."""
        return {"white_rms_counts": (0.0, np.inf), "hum_counts": (0.0, np.inf)}

    def material(self, params):
        return params["white_rms_counts"] >= self.min_white_counts or \
            params["hum_counts"] >= self.min_hum_counts
