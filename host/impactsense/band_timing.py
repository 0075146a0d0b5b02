"""A second timing observable for the diagnosis: the core's band pick (`band_onset`, the onset of a channel's
envelope at one frequency) beside the threshold pick the reference models.

Why: a constant channel delay shifts the whole recording of its channel, so every pick on it moves by the
same delay. A moved disc changes the path each wave travels, and each pick moves by ITS OWN slowness times
the path change: on a dispersive plate a low band's envelope travels slower than the threshold pick's first
cycles, so the band pick moves by more (the reference measures both slownesses). Along a disc's look
direction the timing change of a move is nearly constant over the impacts and the threshold picks alone
cannot tell it from a delay (`effects.sensor_position.direction_test`); the band pick's shift against the
threshold pick's can (`effects.sensor_position.band_test`).

The band's frequency is BAND_FREQUENCY_FACTOR x the reference's median picked frequency (fs / pick period),
its envelope fraction BAND_FRACTION (both from the core's band-pick choices, `pipeline.choose_band`), its
window BAND_WINDOW_TRAVELS travel times over the longest sensor spacing. Nothing here is signal logic: the
core picks, the host fits a travel law to the picks.
"""

from __future__ import annotations

import numpy as np

BAND_FREQUENCY_FACTOR = 0.7
BAND_FRACTION = 0.05
BAND_WINDOW_TRAVELS = 4.0


def band_setting(F, slowness_us_per_mm: float) -> dict | None:
    """The band pick's core settings for the reference features F (its picks' periods), None when F's picks
    carry no period."""
    period = np.asarray(F.pick_period if F.pick_period is not None else [], float)
    period = period[np.isfinite(period) & (period > 0)]
    if period.size == 0 or not slowness_us_per_mm > 0:
        return None
    s = np.asarray(F.sensor_xy_mm, float)
    longest = float(np.hypot(*(s[:, None, :] - s[None, :, :]).transpose(2, 0, 1)).max())
    return {"band_pick_hz": float(BAND_FREQUENCY_FACTOR * np.median(F.fs_hz / period)),
            "band_pick_fraction": BAND_FRACTION,
            "band_window_us": float(BAND_WINDOW_TRAVELS * longest * slowness_us_per_mm)}


def band_picks(session, picker: dict | None, band: dict) -> np.ndarray:
    """The core's band picks (µs, [R, 4], NaN where none) of a session, with the timing picker's settings."""
    from . import _core
    from .residuals import timing_picker
    from .signal import core_config, core_samples

    cfg = core_config(session.rig, **timing_picker(picker))
    for k, v in band.items():
        setattr(cfg, k, v)
    return np.asarray(_core.extract_batch(core_samples(session.adc, cfg), cfg)["toa_band_us"], float)


def fit_band(ref, F) -> dict | None:
    """The band picks' travel law on the reference features F (F.toa_band_us): their slowness and each
    channel's offset from the threshold picks' delay (robust least squares on drop-centred picks, the
    reference's own fit), None without band picks on most drops."""
    from .residuals import _robust_lstsq, centre, robust_sigma

    tb = getattr(F, "toa_band_us", None)
    if tb is None:
        return None
    ok = np.all(np.isfinite(tb), axis=1)
    if ok.sum() < max(10, 0.5 * len(ok)):
        return None
    d, *_ = ref.geometry(F)
    cols = [centre(d[ok]).ravel()] + [centre(np.eye(4)[[i]].repeat(ok.sum(), 0)).ravel() for i in (1, 2, 3)]
    sol, res = _robust_lstsq(np.stack(cols, 1), centre(tb[ok]).ravel())
    delay = np.r_[0.0, sol[1:4]]
    return {"slowness_us_per_mm": float(sol[0]), "offset_us": (delay - ref.delay_us).tolist(),
            "sigma_us": robust_sigma(res)}


def band_resid(model, F) -> np.ndarray | None:
    """Drop-centred residual of the band picks under `model` (its discs, its delays plus the band's offsets
    learned on the reference: `Reference.band`), None when either is missing."""
    from .residuals import centre

    band = getattr(model, "band", None)
    tb = getattr(F, "toa_band_us", None)
    if band is None or tb is None:
        return None
    d, *_ = model.geometry(F)
    return centre(tb - (band["slowness_us_per_mm"] * d + model.delay_us + np.asarray(band["offset_us"])),
                  model.timing_kept(len(F)))
