"""The band picks chosen by what the forests make of them (workflow.train without a site map).

`pipeline.choose_band` turns the band picks on when they bring the training drops' physics positions clearly
closer; on some plates the forests' held-out positions then get worse (docs/findings.md "The band picks chosen
by the forests"). Without a site map the reported position is the forests', so here the band picks are chosen
by the training drops' out-of-fold positions of the forests the band picks feed (correction_scale's folds: 5
site-grouped folds, 50-tree forests, the band picks' position members refitted per fold, the correction's
factor chosen as the model chooses it): off (the cheaper, the default) unless the physics-chosen band pair gains
more than one standard error per site (correction_scale.choose_by_gain, the rule written once).
"""

from __future__ import annotations

import time

import numpy as np

from .correction_scale import CORRECTION_MIN_SITES, choose_by_gain, drop_sites, scale_choice
from .pipeline import band_finished, band_off, choose_band, columns_reading, featurize
from .position_members import member_positions
from .signal import SignalConfig


def position_oof_error(features, xy: np.ndarray, signal: SignalConfig, settings) -> np.ndarray | None:
    """Each training drop's out-of-fold position error (mean per axis, mm; NaN where none is placed) of the
    forests the band picks feed: the physics position's pair and, with the band picks on, their position members
    (POSITION_MEMBERS), at the correction factor correction_scale chooses. The edge and level members are chosen
    afterwards on the chosen picks and partly stand in for the band members (scored with them, the band picks'
    gain shrank below one standard error on splits whose held-out drops kept it: docs/findings.md). None with too
    few sites (correction_scale.CORRECTION_MIN_SITES)."""
    from .models import LOCATION_FEATURES, columns

    xy = np.asarray(xy, float)
    use = np.flatnonzero(features.usable)
    train = features.take(use)
    names = columns_reading(signal.channel_left_out, LOCATION_FEATURES)
    positions = member_positions(train) if float(signal.band_velocity_mm_per_us) > 0 else None
    out = scale_choice(train.vector[:, columns(names)], np.asarray(train.phys_xy_mm, float), positions, None,
                       xy[use], settings, names)
    if out is None:
        return None
    err = np.full(len(xy), np.nan)
    err[use] = out[1]
    return err


class ForestBandChoice:
    """fit_localiser's band_choice: the band picks off or the physics-chosen pair on, as the forests' out-of-fold
    positions of the training drops (`rows` of `session`) say; `record` (after the call) is the model card's
    "band_choice": {"band_on", "tried": True, "out_of_fold_mae_mm": [off, on], "gain_sigmas", "seconds" (the
    choice's wall time)}, or
    {"band_on", "tried": False} when no band pair could be tried (off) or the drops are at too few sites for the
    folds (pipeline.choose_band's physics rule)."""

    def __init__(self, session, rows: np.ndarray, settings, fits=None):
        self.session, self.rows, self.settings, self.fits = session, np.asarray(rows), settings, fits
        self.record: dict = {}

    def _error(self, cfg: SignalConfig) -> np.ndarray | None:
        return position_oof_error(featurize(self.session.adc[self.rows], cfg), self.session.xy_mm[self.rows], cfg,
                                  self.settings)

    def _physics(self, cfg: SignalConfig) -> SignalConfig:
        """fit_localiser's own choice (pipeline.choose_band's physics rule), recorded."""
        out = band_finished(self.session, self.rows, choose_band(self.session, self.rows, cfg, self.fits), self.fits)
        self.record["band_on"] = bool(float(out.band_velocity_mm_per_us) > 0)
        return out

    def __call__(self, cfg: SignalConfig) -> SignalConfig:
        session, rows, fits = self.session, self.rows, self.fits
        start = time.perf_counter()
        sites = drop_sites(np.asarray(session.xy_mm, float)[rows])
        if np.unique(sites).size < CORRECTION_MIN_SITES:   # too few sites for folds: the physics rule
            self.record = {"band_on": False, "tried": False}
            return self._physics(cfg)
        on = choose_band(session, rows, cfg, fits, gain=np.inf)
        off = band_finished(session, rows, band_off(cfg), fits)
        if float(on.band_velocity_mm_per_us) <= 0:
            self.record = {"band_on": False, "tried": False}
            return off
        on = band_finished(session, rows, on, fits)
        err = [self._error(off), self._error(on)]
        if any(e is None for e in err):
            self.record = {"band_on": False, "tried": False}
            return self._physics(cfg)
        ok = np.isfinite(err[0]) & np.isfinite(err[1])
        chosen, mae, z = choose_by_gain([e[ok] for e in err], sites[ok], 0)
        self.record = {"band_on": bool(chosen == 1), "tried": True, "out_of_fold_mae_mm": [round(m, 3) for m in mae],
                       "gain_sigmas": round(z, 2), "seconds": round(time.perf_counter() - start, 1)}
        return on if chosen == 1 else off
