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


SPECTRAL_BAND_HZ = (500.0, 30000.0)   # the one-pole's magnitude fitted in this band (below 0.4 fs)
SPECTRAL_MIN_SNR = 2.0                 # ... on bins where the bonded channel's power is this x its noise's
PRETRIGGER = 64                        # a record's first samples: its noise


def _spectra(session) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(f, P): each channel's power spectrum averaged over drops, its noise's (the first PRETRIGGER samples'
    variance, white) taken out: P (n_freq, 4), and that noise per channel."""
    x = np.asarray(session.adc, float)
    x = x - x[:, :, :PRETRIGGER].mean(axis=2, keepdims=True)
    n = x.shape[2]
    p = (np.abs(np.fft.rfft(x, axis=2)) ** 2).mean(axis=0).T
    noise = n * x[:, :, :PRETRIGGER].var(axis=2).mean(axis=0)
    return np.fft.rfftfreq(n, 1.0 / float(session.rig.fs_hz)), p - noise[None, :], noise


def spectral_one_pole(reference, data, channel: int) -> tuple[float, float]:
    """(fc, g): the first-order low-pass g / (1 + j f / fc) whose magnitude best gives `data`'s power spectrum of
    `channel` from `reference`'s (each averaged over its drops, noise taken out), the other channels' median ratio
    taken out (what the two sessions' drops differ in for every channel): |H|^2 = (P_new / P_ref)_channel /
    median over the others of the same, fitted in log over SPECTRAL_BAND_HZ on bins the channel's power stands
    SPECTRAL_MIN_SNR above its noise in both sessions (docs/method.md "Bond inverse")."""
    from scipy.optimize import least_squares

    f, p_ref, n_ref = _spectra(reference)
    _, p_new, n_new = _spectra(data)
    others = [k for k in range(p_ref.shape[1]) if k != channel]
    fs = float(reference.rig.fs_hz)
    band = (f >= SPECTRAL_BAND_HZ[0]) & (f <= min(SPECTRAL_BAND_HZ[1], 0.4 * fs))
    band &= (p_ref[:, channel] > SPECTRAL_MIN_SNR * n_ref[channel]) & (p_new[:, channel] > SPECTRAL_MIN_SNR * n_new[channel])
    band &= (p_ref[:, others] > 0).all(axis=1) & (p_new[:, others] > 0).all(axis=1)
    if band.sum() < 5:
        raise ValueError(f"channel {channel}: too few bins above the noise for a bond's spectrum ({int(band.sum())})")
    common = np.median(p_new[band][:, others] / p_ref[band][:, others], axis=1)
    h2 = p_new[band, channel] / p_ref[band, channel] / common
    fb = f[band]

    def resid(q):
        fc, g = np.exp(q)
        return np.log(h2) - np.log(g * g / (1.0 + (fb / fc) ** 2))

    fit = least_squares(resid, [np.log(3000.0), np.log(0.7)], loss="soft_l1", f_scale=0.3)
    fc, g = np.exp(fit.x)
    return float(fc), float(g)
