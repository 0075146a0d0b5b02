"""The site-factor study's measures (benchmarks/bench_class_sitefactor.py): a drop's energies minus the twin's
site map at its position give its height, the channels' median survives one wrong channel, and the reliability
weights follow the map's local spread."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_class_sitefactor as study  # noqa: E402

from impactsense.sitemap import N_FEATURES, SiteMap, quantise  # noqa: E402


def edge_map(nx=41, ny=31, step=5.0):
    """A site map whose 16 features carry a sharp edge pattern (a 12 mm-scale ripple near x = 0) and a smooth
    distance law per channel."""
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    x, y = 10.0 + step * i.ravel(), 10.0 + step * j.ravel()
    sensors = np.array([[40.0, 40.0], [160.0, 40.0], [40.0, 130.0], [160.0, 130.0]])
    cols = []
    for c in range(4):
        d = np.hypot(x - sensors[c, 0], y - sensors[c, 1])
        for k in range(4):
            cols.append(3.0 - 0.004 * d - 0.2 * k + 0.2 * np.exp(-x / 40.0) * np.cos(x / 6.0))
    base, scale, q = quantise(np.stack(cols, 1))
    return SiteMap(10.0, 10.0, step, nx, ny, base, scale, q, 175.0)


def test_site_corrected_median_recovers_the_height_at_the_position_and_survives_one_wrong_channel():
    site = edge_map()
    rng = np.random.default_rng(3)
    xy = rng.uniform(12.0, 200.0, (60, 2)) * [1.0, 0.7]
    log_h = rng.uniform(1.7, 2.5, 60)
    grid, _ = study.dense_grid(site)
    truth_map = study.grid_at(site, grid, xy)
    feats = truth_map + (log_h - np.log10(175.0))[:, None]           # the rig's energy = the map's x h / h_ref
    usable = np.full(60, (1 << N_FEATURES) - 1, np.uint16)
    med = study.robust_height(study.site_corrected(feats, usable, truth_map))
    assert np.allclose(med - (log_h - np.log10(175.0))[:, None], 0.0, atol=1e-9)
    # one channel 0.5 (a factor 3) off, another not usable: the median moves by at most half the middle gap
    bad = feats.copy()
    bad[:, 4:8] += 0.5
    usable_3 = np.full(60, (1 << N_FEATURES) - 1 - (0xF << 12), np.uint16)      # channel 3 left out
    med_bad = study.robust_height(study.site_corrected(bad, usable_3, truth_map))
    mean_bad = np.nanmean(study.site_corrected(bad, usable_3, truth_map), 1)
    err_med = np.abs(med_bad - (log_h - np.log10(175.0))[:, None])
    err_mean = np.abs(mean_bad - (log_h - np.log10(175.0))[:, None])
    assert err_med.max() < 1e-9           # three channels: the median is a right one
    assert err_mean.min() > 0.16          # the mean carries a third of the wrong channel's 0.5


def test_local_spread_is_large_where_the_map_changes_fast_and_weights_follow_it():
    site = edge_map()
    mean_g, sd_g = study.dense_grid(site, smooth_mm=5.0)
    near, far = np.array([[15.0, 80.0]]), np.array([[150.0, 80.0]])
    sd_near, sd_far = study.grid_at(site, sd_g, near), study.grid_at(site, sd_g, far)
    # far from the edge only the distance law's gradient (0.004 / mm) spreads it: 0.004 x 5 mm per axis
    assert sd_far.mean() == pytest.approx(0.004 * 5.0, rel=0.15)
    assert sd_near.mean() > 1.5 * sd_far.mean()       # the edge ripple on top of it
    # two channels: one whose site factor is uncertain (sd 0.2) reads +0.3, one sure (sd 0) reads 0
    corrected = np.full((1, 4, 4), np.nan)
    corrected[0, 0, :], corrected[0, 1, :] = 0.3, 0.0
    sd = np.zeros((1, 16))
    sd[0, 0:4] = 0.2
    w = study.weighted_height(corrected, sd, tau=0.05)
    assert w == pytest.approx(np.full((1, 4), 0.3 * 0.05 ** 2 / (0.05 ** 2 + 0.2 ** 2 + 0.05 ** 2)), rel=1e-6)


def test_ridge_scores_classify_drops_whose_energy_is_the_site_corrected_height():
    site = edge_map()
    rng = np.random.default_rng(5)
    cases = rng.uniform(15.0, 195.0, (60, 2)) * [1.0, 0.7]
    heights = rng.choice([100.0, 150.0, 200.0, 250.0], 60)
    rep = np.repeat(np.arange(60), 3)
    xy, h = cases[rep], heights[rep]
    grid, _ = study.dense_grid(site)
    feats = study.grid_at(site, grid, xy) + np.log10(h / 175.0)[:, None] + rng.normal(0, 0.01, (len(xy), 16))
    usable = np.full(len(xy), (1 << N_FEATURES) - 1, np.uint16)
    med = study.robust_height(study.site_corrected(feats, usable, study.grid_at(site, grid, xy)))
    energy = 0.0044 * 9.80665 * h * 1e-3
    train, test = np.arange(0, 150), np.arange(150, len(xy))
    corrected = study.ridge_scores(np.c_[med, xy], energy, xy, train, test)
    raw = study.ridge_scores(np.c_[feats.reshape(-1, 4, 4).mean(1), xy], energy, xy, train, test)
    assert corrected["oof_class"] == 1.0 and corrected["class"] == 1.0
    assert corrected["rms_log"] < 0.05
    assert raw["rms_log"] > 2 * corrected["rms_log"]      # the edge ripple a cubic cannot follow
