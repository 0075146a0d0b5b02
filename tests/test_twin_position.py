"""The reported impact position: the twin's matched position (twin.h TwinEstimate.x_mm, y_mm) when the model
has a site map, the forests' otherwise; and why: the twin finds the true position back from a wrong one."""

import numpy as np
import pytest

from impactsense.data import load_session
from impactsense.metrics import localisation_metrics
from impactsense.models import ForestSettings, ImpactModel
from impactsense.pipeline import SignalConfig, featurize, fit_localiser
from impactsense.sitemap import BUNDLED, SiteMap, twin_features
from impactsense.split import case_split
from impactsense.twin import estimate, fit_twin


@pytest.fixture(scope="module")
def split_features():
    s = load_session()
    train, test = case_split(s.case_id, 0.2, 0)
    cfg = fit_localiser(s, train, SignalConfig.for_rig(s.rig))
    return s, featurize(s.adc, cfg), cfg, train, test


@pytest.fixture(scope="module")
def models(split_features, tmp_path_factory):
    """Two models on the same training cases: with the bundled twin's site map and without."""
    s, f, cfg, train, _ = split_features
    fit = lambda site: ImpactModel.fit(f.take(train), s.xy_mm[train], s.height_mm[train], s.rig.ball_mass_g,  # noqa: E731
                                       cfg, ForestSettings(n_estimators=20), site_map=site)
    return {"twin": fit(SiteMap.load(BUNDLED)), "forest": fit(None)}


def test_reported_position_is_the_twins_with_a_site_map(models, split_features, tmp_path):
    s, f, _, _, test = split_features
    ft = f.take(test)
    twin_model, forest_model = models["twin"], models["forest"]
    p = twin_model.predict(ft)
    assert p["position_source"] == "twin"
    ran = np.isfinite(p["xy_mm"]).all(1)
    assert ran.sum() >= ft.usable.sum() - 2
    np.testing.assert_array_equal(ran, p["energy_class"] >= 0)   # a position exactly where a class is given
    feats, usable = twin_features(ft.take(np.flatnonzero(ran)))
    want = estimate(twin_model.site_map, twin_model.twin_fit, feats, usable, p["forest_xy_mm"][ran])["xy_mm"]
    np.testing.assert_allclose(p["xy_mm"][ran], want, atol=1e-4)
    assert np.abs(p["xy_mm"][ran] - p["forest_xy_mm"][ran]).max() > 1.0   # not the forests' position
    # Without a site map: the forests' position, as before.
    q = forest_model.predict(ft)
    assert q["position_source"] == "forest"
    np.testing.assert_array_equal(q["xy_mm"], q["forest_xy_mm"])
    assert "twin_xy_mm" not in q and "height_mm" not in q
    # The card says which, and a loaded model reports the same.
    twin_model.save(tmp_path / "m")
    assert twin_model.card["position_source"] == "twin"
    np.testing.assert_allclose(ImpactModel.load(tmp_path / "m").predict(ft)["xy_mm"][ran], p["xy_mm"][ran], atol=1e-6)


def test_twin_position_beats_the_forests_on_held_out_cases(models, split_features):
    """Measured drops of cases the models never saw (mean 1.2 mm off the map's 5 mm grid): the twin's
    position is closer to the truth than the forests' it started from (2.4 -> 1.3 mm MAE with 100 trees)."""
    s, f, _, _, test = split_features
    p = models["twin"].predict(f.take(test))
    ok = np.isfinite(p["xy_mm"]).all(1)
    twin = localisation_metrics(s.xy_mm[test][ok], p["xy_mm"][ok])
    forest = localisation_metrics(s.xy_mm[test][ok], p["forest_xy_mm"][ok])
    assert twin["mae_mm"] < 0.75 * forest["mae_mm"], (twin, forest)
    assert twin["rmse_mm"] < forest["rmse_mm"]


def test_twin_finds_a_map_made_event_from_an_offset_position(split_features):
    """Events made from the site map itself (the features the twin predicts at a grid point for a 150 mm
    drop, through the rig's offsets and slopes fitted on session-1) and a model position 6 mm off in a random
    direction: the twin's position comes back towards the true point (a plain weighted mean around the
    given position, with its 7 mm prior, would stay near it)."""
    s, f, _, _, _ = split_features
    site = SiteMap.load(BUNDLED)
    feats, usable = twin_features(f)
    fit = fit_twin(feats, usable, site, s.xy_mm, s.height_mm)
    rng = np.random.default_rng(1)
    idx = rng.choice(np.flatnonzero(site.present), 300, replace=False)
    truth = site.xy_mm[idx]
    lh = np.log10(150.0)
    ev = site.values()[idx] + np.asarray(fit.offset) + np.asarray(fit.slope) * (lh - fit.ref_log10_height_mm)
    ang = rng.uniform(0, 2 * np.pi, len(idx))
    start = truth + 6.0 * np.c_[np.cos(ang), np.sin(ang)]
    r = estimate(site, fit, ev.astype(np.float32), np.full(len(idx), 0xFFFF, np.uint16), start)
    assert np.all(r["status"] == 0)
    err = np.hypot(*(r["xy_mm"] - truth).T)
    assert np.median(err) < 2.0 and np.mean(err < 6.0) > 0.98, np.percentile(err, [50, 90, 100])
    np.testing.assert_allclose(r["log10_height_mm"], lh, atol=0.05)


def test_reported_uncertainty_is_the_calibrated_spread_which_ranks_the_errors(models, split_features):
    """uncertainty_mm (the report's field) is the twin's calibrated 1-sigma (twin.calibrated_uncertainty of
    its spread and misfit, with the model's fitted constants); the raw spread (twin_spread_mm) is kept and on
    held-out cases larger spreads go with larger errors (Spearman > 0.2; 0.38 with 100 trees). Coverage:
    tests/test_uncertainty.py."""
    from scipy.stats import spearmanr

    from impactsense.twin import calibrated_uncertainty

    s, f, _, _, test = split_features
    p = models["twin"].predict(f.take(test))
    ran = np.isfinite(p["xy_mm"]).all(1)
    np.testing.assert_array_equal(ran, np.isfinite(p["uncertainty_mm"]))
    np.testing.assert_allclose(p["uncertainty_mm"][ran], calibrated_uncertainty(
        models["twin"].twin_fit, p["twin_spread_mm"][ran], p["twin_misfit"][ran]), rtol=1e-12)
    err = np.linalg.norm(p["xy_mm"][ran] - s.xy_mm[test][ran], axis=1)
    assert spearmanr(p["twin_spread_mm"][ran], err).statistic > 0.2
    assert np.isnan(models["forest"].predict(f.take(test))["uncertainty_mm"]).all()
