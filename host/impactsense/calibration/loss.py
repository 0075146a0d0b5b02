"""The twin's loss factor: how the rig's decay rate rises with frequency, read from the calibration drops.

The damping stage fits one mass-proportional D_s: every frequency of the twin's records decays alike. A plate whose
material loses a fixed fraction of its energy per cycle (a laminate's resin, a polymer) rings out faster at high
frequency. Per octave band (BANDS_FROM_HZ up to BAND_TOP_FS x the logging rate) the calibration drops' records are
band-passed and each channel's energy decay rate (1/s) is the least-squares slope of its log block energies from
START_MS after the channel's onset (its first
sample above ONSET_OF_PEAK x its peak), blocks BLOCK_MS long, while a block stays SNR x above the
channel's noise before the onsets; the band's rate is the median over the drops' channels, and so is the broadband rate
(the unfiltered record, the same rule). A line r(f) = c + eta 2 pi f through the bands' rates (least squares) gives
the modal solver's loss factor eta (SimParams.loss_factor: mode k decays at D_s / 2 + eta omega_k / 2, the direct
solver's records the same, `sim.loss`). It is kept only when the rise is significant and physical: eta at least Z_MIN x its
standard error, which comes from the decay fits' own scatter (each band's median carries its channels' spread,
`median_se`, through the line's weights; the bands' scatter about the line when larger), and the line a loss on top
of a damping (a positive intercept c, and D_s' below positive). A flat decay, or a record with no ringing field to
read (a passing dispersive wave: its high bands leave first, the line's intercept negative), keeps the twin exactly
as it was (eta 0, D_s unchanged). When kept, D_s is lowered by what the line puts above its intercept at the
broadband rate, D_s' = D_s - (r_broadband - c): the twin keeps the broadband decay the damping stage matched and
decays per band as the rig does
(docs/method.md, "The twin's loss factor").
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfiltfilt

BANDS_FROM_HZ = 1000.0
BAND_TOP_FS = 0.4          # the highest band's upper edge at most this x the logging rate
BLOCK_MS = 0.5
START_MS = 1.0             # after the onset: the direct wave has passed
SNR = 20.0                 # a block's energy at least this x the noise's over the same length
MIN_BLOCKS = 4
MIN_CHANNELS = 4           # a band's rate needs this many (drop, channel) decays
Z_MIN = 3.0                # the loss factor's significance: eta at least this x its standard error (one-sided 0.13 %)
ONSET_OF_PEAK = 0.1     # a channel's onset: its first sample above this x its peak


def octave_bands(fs_hz: float) -> list[tuple[float, float]]:
    out, lo = [], BANDS_FROM_HZ
    while 2 * lo <= BAND_TOP_FS * fs_hz:
        out.append((lo, 2 * lo))
        lo *= 2
    return out


def _rates(x: np.ndarray, start: np.ndarray, noise_power: np.ndarray, fs_hz: float) -> np.ndarray:
    """Energy decay rate [1/s] of each row of x [K, n] from sample start[k] (NaN: too few blocks above SNR)."""
    blk = max(2, int(round(BLOCK_MS * 1e-3 * fs_hz)))
    out = np.full(len(x), np.nan)
    for k, row in enumerate(x):
        s0 = int(start[k])
        nb = (row.size - s0) // blk
        if s0 < 0 or nb < MIN_BLOCKS:
            continue
        e = (row[s0:s0 + nb * blk] ** 2).reshape(nb, blk).sum(1)
        above = e > SNR * noise_power[k] * blk
        m = int(np.argmin(above)) if not above.all() else nb      # the leading blocks above the noise
        if m < MIN_BLOCKS:
            continue
        t = (np.arange(m) + 0.5) * blk / fs_hz
        out[k] = -np.polyfit(t, np.log(e[:m]), 1)[0]
    return out


def onsets(x: np.ndarray) -> np.ndarray:
    """Per row of x [K, n] (bias removed) the first sample above ONSET_OF_PEAK x its largest magnitude."""
    a = np.abs(x)
    return np.argmax(a >= ONSET_OF_PEAK * a.max(axis=1, keepdims=True), axis=1)


def median_se(r: np.ndarray) -> float:
    """Standard error of the median of r from its own scatter: 1.2533 x the MAD-based sigma / sqrt(n) (the
    median's large-sample error for a normal spread, robust to a few channels' stray fits)."""
    r = np.asarray(r, float)
    return float(1.2533 * 1.4826 * np.median(np.abs(r - np.median(r))) / np.sqrt(r.size))


def decay_by_band(adc: np.ndarray, bias: float, fs_hz: float) -> dict:
    """adc [R, 4, n] counts. Per band (and broadband) the median energy decay rate over the channels and how many
    channels gave one; the noise is each channel's record before its onset (less one block)."""
    x = np.asarray(adc, float) - float(bias)
    x = x.reshape(-1, x.shape[-1])
    on = onsets(x - np.median(x, axis=1, keepdims=True))
    blk = max(2, int(round(BLOCK_MS * 1e-3 * fs_hz)))
    pre = int(max(8, on.min() - blk))
    x = x - np.mean(x[:, :pre], axis=1, keepdims=True)
    start = on + int(round(START_MS * 1e-3 * fs_hz))
    bands = octave_bands(fs_hz)
    out = {"bands_hz": bands, "rate_per_s": [], "channels": [], "rate_se_per_s": []}
    for lo, hi in [*bands, (None, None)]:
        y = x if lo is None else sosfiltfilt(butter(4, [lo, hi], btype="band", fs=fs_hz, output="sos"), x, axis=-1)
        noise = np.mean(y[:, :pre] ** 2, axis=1)
        r = _rates(y, start, noise, fs_hz)
        r = r[np.isfinite(r)]
        rate, n = (float(np.median(r)) if r.size >= MIN_CHANNELS else float("nan")), int(r.size)
        if lo is None:
            out["broadband_rate_per_s"], out["broadband_channels"] = rate, n
        else:
            out["rate_per_s"].append(rate)
            out["channels"].append(n)
            out["rate_se_per_s"].append(median_se(r) if r.size >= MIN_CHANNELS else float("nan"))
    return out


def slope_test(omega: np.ndarray, rate: np.ndarray, se: np.ndarray) -> dict:
    """The least-squares line rate = c + eta omega through the bands and eta's standard error: the bands' own
    errors (their channels' scatter, `median_se`) carried through the line's weights, or the bands' scatter about
    the line when that is larger (a decay the line does not describe). z = eta / its error."""
    eta, c = np.polyfit(omega, rate, 1)
    a = (omega - omega.mean()) / np.sum((omega - omega.mean()) ** 2)        # eta = sum a_b rate_b
    var_bands = float(np.sum(a ** 2 * se ** 2))
    dof = omega.size - 2
    res = rate - (c + eta * omega)
    var_line = float(np.sum(res ** 2) / dof / np.sum((omega - omega.mean()) ** 2)) if dof > 0 else 0.0
    err = float(np.sqrt(max(var_bands, var_line)))
    return {"eta": float(eta), "c": float(c), "eta_se": err, "z": float(eta / err) if err > 0 else float("inf")}


def fit_loss(decay: dict, d_s: float) -> dict:
    """The rule (module docstring) on decay_by_band's rates: {"loss_factor", "damping_per_s", "intercept_per_s",
    "z", "rise", "kept", "why", ...}; loss_factor 0 and D_s unchanged when not kept."""
    f = np.array([np.sqrt(lo * hi) for lo, hi in decay["bands_hz"]])
    r = np.asarray(decay["rate_per_s"], float)
    se = np.asarray(decay.get("rate_se_per_s", [np.nan] * r.size), float)
    ok = np.isfinite(r) & np.isfinite(se)
    broad = decay.get("broadband_rate_per_s", float("nan"))

    def js(v):                                                                  # JSON: an unreadable value is None
        return [float(x) if np.isfinite(x) else None for x in np.asarray(v, float)]

    res = {**decay, "bands_hz": [list(b) for b in decay["bands_hz"]], "rate_per_s": js(r), "rate_se_per_s": js(se),
           "broadband_rate_per_s": float(broad) if np.isfinite(broad) else None,
           "damping_stage_per_s": float(d_s), "loss_factor": 0.0, "damping_per_s": float(d_s), "kept": False}
    if ok.sum() < 3 or not np.isfinite(broad):
        return {**res, "why": "fewer than three bands (or no broadband rate) with a readable decay"}
    t = slope_test(2 * np.pi * f[ok], r[ok], se[ok])
    slope, c = t["eta"], t["c"]
    lo_fit, hi_fit = c + slope * 2 * np.pi * f[ok].min(), c + slope * 2 * np.pi * f[ok].max()
    rise = float(hi_fit / lo_fit) if lo_fit > 0 else float("inf")
    ds = float(d_s) - (broad - c)
    res.update(intercept_per_s=c, slope_loss_factor=slope, loss_factor_se=t["eta_se"], z=t["z"], rise=rise)
    if not t["z"] >= Z_MIN:
        return {**res, "why": f"the decay rate's rise with frequency is not significant (z {t['z']:.1f} < {Z_MIN:g}; "
                              f"{rise:.2f} x over the bands): no loss factor"}
    if not (c > 0 and ds > 0):
        return {**res, "why": f"the decay rises with frequency (z {t['z']:.1f}) but not as a loss on top of a "
                              f"damping (the line's intercept {c:.0f} 1/s, the damping it leaves {ds:.0f} 1/s): "
                              "a passing wave, not a ringing plate's decay; no loss factor"}
    return {**res, "loss_factor": slope, "damping_per_s": ds, "kept": True,
            "why": f"the decay rate rises {rise:.2f} x over the bands (z {t['z']:.1f})"}


def twin_loss(session, rows, d_s: float) -> dict:
    """The rule on `rows` (recording ids) of the session: fit_loss of their band decays."""
    rows = np.asarray(list(rows), int)
    decay = decay_by_band(session.adc[rows], float(session.rig.bias_counts), float(session.rig.fs_hz))
    return fit_loss(decay, d_s)
