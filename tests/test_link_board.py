"""The board's view of the drops (4 x 50 kHz, SAADC scan order) and the models trained on it: the scan delays
are removed with the right sign, the board-rate fit finds the rig's own channel delays, and
`impactsense export` ships models trained at the board rate that localise and classify the held-out drops on
the emulated board."""

import json

import numpy as np
import pytest

from impactsense import _core
from impactsense.data import load_session
from impactsense.pipeline import SignalConfig, as_int16, fit_localiser


@pytest.fixture(scope="module")
def s1():
    return load_session()


@pytest.fixture(scope="module")
def rig_fit(s1):
    """The physics localiser fitted at 100 kHz on all drops: velocity and the rig's channel delays."""
    return fit_localiser(s1, np.arange(len(s1)), SignalConfig.for_rig(s1.rig))


def test_scan_delays_are_removed(s1, rig_fit):
    """On the board, channel c is read c x 5 us after channel 0, so its onsets come c x 5 us early in the
    capture; with the board's config the core's DToA equal the 100 kHz DToA (no per-channel bias: a sign
    error would leave 10, 20, 30 us)."""
    from impactsense.board.capture import board_captures
    from impactsense.board.capture import signal_for_board

    rows = np.arange(0, len(s1), 4)
    caps, got, _ = board_captures(s1.subset(rows), 50000)
    assert got.size > 0.95 * rows.size
    toa_b = _core.extract_batch(as_int16(caps), signal_for_board(s1.rig, rig_fit.to_dict()).core())["toa_us"]
    toa_h = _core.extract_batch(as_int16(s1.adc[rows[got]]), rig_fit.core())["toa_us"]
    d_b = toa_b[:, 1:] - toa_b[:, :1]
    d_h = toa_h[:, 1:] - toa_h[:, :1]
    bias = np.nanmedian(d_b - d_h, axis=0)
    assert np.all(np.abs(bias) < 2.0), bias  # 2 us: a tenth of a board sample period


def apparent_speed(cfg: SignalConfig, adc: np.ndarray, xy_mm: np.ndarray) -> float:
    """The speed (mm/us) at which cfg's localiser model has its travel times grow with distance over these drops:
    the least-squares slope of travel distance on the model's travel time (both centred over a drop's four
    channels), each pick's slowness scaled by the dispersion at the frequency of the cycle cfg's core picks."""
    from impactsense.travel import picks, slowness_scales, travel_distances

    _, period = picks(adc, cfg, with_period=True)
    metric = (cfg.travel_metric_xx, cfg.travel_metric_xy, cfg.travel_metric_yy)
    d = travel_distances(xy_mm, cfg.sensor_xy_mm, metric)
    t = d * slowness_scales(period, cfg.fs_hz, cfg.dispersion_exponent, cfg.dispersion_ref_hz) / cfg.velocity_mm_per_us
    dc, tc = d - d.mean(1, keepdims=True), t - t.mean(1, keepdims=True)
    return float((dc * dc).sum() / (dc * tc).sum())


def test_board_models_fit_the_rig_delays(s1, rig_fit, tmp_path):
    """The localiser fitted on the board's picks finds the same rig delays as at 100 kHz (channels 2 and 3
    about 6-7 us early); the card keeps only the rig's part (the firmware adds the scan delays).

    Speed: with the dispersion term a fit's velocity_mm_per_us is the speed at its own reference frequency (the
    median of its picks': ~17 kHz at 100 kHz, ~15 kHz on the board, with the board's own exponent), so the two
    are compared as each model times the same drops (apparent_speed). Session-1: 0.921 vs 0.944 mm/us (2.5 %;
    without a dispersion term the board's picks are 2.0 % slower than the 100 kHz ones too: their threshold
    crossings at 20 us sampling come later on the weaker, farther arrivals); the board's velocity 3 % low or its
    dispersion dropped fails (5.4, 7.3 %). And the fitted speed is the board's: on the held-out drops the
    physics localiser with it is closer to the truth than with it 3 % off either way (4.91 vs 5.18 / 5.39 mm;
    the 100 kHz speed and dispersion moved to the board: 5.49 mm). A scan-delay error moves the delays by
    5-15 us."""
    from impactsense.board.capture import board_captures
    from impactsense.board.models import train_board_models
    from impactsense.pipeline import featurize

    d = train_board_models(s1, tmp_path / "m", n_trees=5)
    card = json.loads((d / "model_card.json").read_text())
    sig = card["signal"]
    assert card["board_fs_hz"] == 50000 and sig["fs_hz"] == 50000
    np.testing.assert_allclose(sig["rig_delay_us"], rig_fit.rig_delay_us, atol=2.0)
    caps, got, board = board_captures(s1, 50000, sig)
    board_speed = apparent_speed(board, caps, s1.xy_mm[got])
    assert board_speed == pytest.approx(apparent_speed(rig_fit, s1.adc[got], s1.xy_mm[got]), rel=0.03)
    held_out = np.isin(s1.recording_id[got], card["split"]["test_recordings"])

    def physics_mae(velocity_factor):
        cfg = SignalConfig.from_dict({**board.to_dict(),
                                      "velocity_mm_per_us": board.velocity_mm_per_us * velocity_factor})
        xy = featurize(caps[held_out], cfg).phys_xy_mm.astype(float)
        return float(np.nanmean(np.abs(xy - s1.xy_mm[got][held_out])))
    assert physics_mae(1.0) < min(physics_mae(0.97), physics_mae(1.03))


def test_export_trains_the_shipped_models_at_the_board_rate(s1, tmp_path, capsys):
    """`impactsense export` on a 100 kHz model: the same training drops and forest settings at the board rate,
    and the exported tables on the emulated board score the held-out drops (Eq. 36 MAE; at 4 x 50 kHz the
    onset picks scatter ~2.5x more than at 100 kHz, so the bound is looser than the host's ~2.4 mm)."""
    from impactsense.cli import main
    from impactsense.models import ForestSettings
    from impactsense.workflow import train

    _, split = train(s1, tmp_path / "m100", 0.2, 0, None, ForestSettings(n_estimators=15, seed=0))
    assert main(["export", str(tmp_path / "m100"), "--out", str(tmp_path / "out"), "--no-m2cgen"]) == 0
    card = json.loads((tmp_path / "out" / "board-model" / "model_card.json").read_text())
    assert card["board_fs_hz"] == 50000 and card["forest"]["n_estimators"] == 15
    assert card["split"]["train_recordings"] == split["train_recordings"]
    assert card["split"]["test_recordings"] == split["test_recordings"]
    acc = json.loads((tmp_path / "out" / "export.json").read_text())["board_held_out"]
    assert acc["n"] == len(split["test_recordings"]) and acc["reported"] >= 0.95 * acc["n"]
    assert acc["all"]["mae_mm"] < 9.0
    assert acc["energy_class_accuracy"] > 0.8
    assert "held-out drops on the emulated board" in capsys.readouterr().out


def test_coarse_to_fine_search_finds_an_impact_beyond_the_one_match_reach():
    """twin.h coarse_cutoff_mm: an event whose energies are exactly the site map's at point P, matched from a
    start 14 mm away (the board's 50 kHz forests are often that far off). One match within 10 mm of the start
    cannot reach P; the coarse pass (every other grid point within 20 mm) finds it and the fine pass lands on it,
    visiting no more points than one match of the default 15 mm reach; coarse_cutoff_mm 0 is the one match."""
    from impactsense.sitemap import BUNDLED, SiteMap
    from impactsense.twin import TwinFit, estimate

    site = SiteMap.load(BUNDLED)
    values = site.values()
    i, j = site.nx // 2 - site.nx // 2 % 2, site.ny // 2 - site.ny // 2 % 2   # a point of the coarse grid
    p = i * site.ny + j
    assert np.isfinite(values[p]).all()
    truth = site.xy_mm[p]
    fit = TwinFit(offset=[0.0] * 16, slope=[1.0] * 16, weight=[1e4] * 16,  # a sharp match: misfit over prior
                  ref_log10_height_mm=float(np.log10(site.ref_height_mm)))
    start = truth + np.array([14.0, 0.0])
    run = lambda **cfg: estimate(site, TwinFit(**{**fit.to_dict(), **cfg}), values[[p]], np.array([0xFFFF]),  # noqa: E731
                                 start[None])
    one = run(cutoff_mm=10.0)
    c2f = run(cutoff_mm=10.0, coarse_cutoff_mm=20.0)
    wide = run(cutoff_mm=15.0)
    assert one["status"][0] == 0 and c2f["status"][0] == 0
    assert np.hypot(*(np.asarray(one["xy_mm"][0]) - truth)) >= site.step_mm - 1e-3   # stuck at its window's edge
    assert np.hypot(*(np.asarray(c2f["xy_mm"][0]) - truth)) < 0.5 * site.step_mm
    assert c2f["n_points"][0] <= wide["n_points"][0]
    zero = run(cutoff_mm=10.0, coarse_cutoff_mm=0.0)
    np.testing.assert_array_equal(zero["xy_mm"], one["xy_mm"])
