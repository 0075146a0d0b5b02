"""The band picks' floor under a diagnosed raised white-noise floor (docs/findings.md "Session 23: noisezc"):
retrain's training drops carry the diagnosed noise, and a floor at 3 x their noise rms leaves the band picks
out; the floor is the lab's noise without the diagnosed white part, and the core's envelope term follows the
noise in the band."""

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from impactsense import _core
from impactsense.loop import pick_settings
from impactsense.pipeline import as_int16, band_floor_preset, band_off, training_noise_floor
from impactsense.signal import SignalConfig

WHITE = 9.77


@pytest.fixture(scope="module")
def drops():
    from impactsense.data import bundled_session_path, load_session

    s = load_session(bundled_session_path("session-1")).subset(np.arange(0, 771, 6))
    clean = np.asarray(s.adc)
    rng = np.random.default_rng(11)
    noisy = np.clip(np.rint(clean + rng.normal(0.0, WHITE, clean.shape)), 0, s.rig.adc_max).astype(clean.dtype)
    return SimpleNamespace(rig=s.rig, clean=clean, session=s, noisy=dataclasses.replace(s, adc=noisy))


def noise_effect(white):
    return SimpleNamespace(effect="noise", sensor=None, params={"white_rms_counts": white, "hum_counts": 0.0,
                                                                  "hum_hz": 50.0})


def test_under_a_diagnosed_noise_the_pick_settings_carry_the_reference_drops_floor(drops):
    """loop.pick_settings on the noisy drops with the clean ones as the reference: band_noise_counts is the
    clean drops' median noise rms (what band_config would take training on them), not the noisy drops' ~4 x
    larger one; without a reference, nothing preset (the floor as before)."""
    clean = drops.session
    cfg = pick_settings(drops.noisy, [noise_effect(WHITE)], reference=clean)
    floor = training_noise_floor(clean, np.arange(len(drops.clean)), cfg)
    noisy = training_noise_floor(drops.noisy, np.arange(len(drops.clean)), cfg)
    assert noisy > 4.0 * floor > 0.0
    assert cfg.band_noise_counts == floor and band_floor_preset(cfg) == floor
    assert pick_settings(drops.noisy, [noise_effect(WHITE)]).band_noise_counts == 0.0


def test_the_preset_floor_is_carried_only_while_the_band_picks_are_off():
    cfg = SignalConfig()
    assert band_floor_preset(cfg) == 0.0          # nothing preset: the training drops' own noise (as before)
    cfg.band_noise_counts = 1.5
    assert band_floor_preset(cfg) == 1.5
    cfg.band_pick_hz = 17000.0                    # a chosen band pick's floor is its own, not a preset
    assert band_floor_preset(cfg) == 0.0
    assert band_off(cfg).band_noise_counts == 0.0


def test_at_the_reference_floor_the_band_picks_survive_the_diagnosed_noise(drops):
    """Band picks at 5 % of the envelope's peak (17 kHz) on the drops with 9.77 counts of white noise: with the
    floor at the noisy drops' noise (3 x ~9.8 counts, band_config's floor on them) no drop keeps a band pick
    (measured: none of 516 channels); at the clean drops' floor the envelope's own noise sets it (4 x its rms,
    ~1.5 counts) and 81 % keep one, two thirds within 20 us of the clean pick (a 17 kHz envelope rises over
    ~60 us)."""
    cfg = SignalConfig.for_rig(drops.rig)
    cfg.band_pick_hz, cfg.band_window_us, cfg.band_pick_fraction = 17000.0, 1000.0, 0.05
    rows = np.arange(len(drops.clean))
    lab = training_noise_floor(drops.session, rows, cfg)
    noisy_floor = training_noise_floor(drops.noisy, rows, cfg)

    def picks(adc, floor):
        c = SignalConfig.from_dict({**cfg.to_dict(), "band_noise_counts": floor})
        return _core.extract_batch(as_int16(adc, c), c.core())["toa_band_us"].astype(float)

    clean = picks(drops.clean, lab)
    ok = np.isfinite(clean)
    assert ok.mean() > 0.8
    at_lab = (picks(drops.noisy.adc, lab) - clean)[ok]
    at_noisy = (picks(drops.noisy.adc, noisy_floor) - clean)[ok]
    assert np.isnan(at_noisy).mean() > 0.8
    assert np.isnan(at_lab).mean() < 0.3
    assert np.mean(np.abs(at_lab) < 20.0) > 0.5 and abs(np.nanmedian(at_lab)) < 15.0
