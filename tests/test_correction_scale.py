"""The forests' correction of the physics position, scaled by the training drops' out-of-fold figures
(correction_scale.choose_correction_scale): none when the residual carries nothing the features explain, whole when it
is a function of them; the scaled forests predict (and save) the scaled correction."""

import numpy as np

from impactsense.forestfile import load_forest, save_forest
from impactsense.correction_scale import (CORRECTION_MIN_SITES, choose_correction_scale, position_forests,
                                         scale_forests)
from impactsense.models import ForestSettings

SETTINGS = ForestSettings(n_estimators=30)


def _sites(n_sites=40, reps=2, seed=0):
    rng = np.random.default_rng(seed)
    site_xy = rng.uniform(0, 400, (n_sites, 2))
    xy = np.repeat(site_xy, reps, axis=0)
    X = rng.normal(size=(xy.shape[0], 6))
    return rng, xy, X


def test_pure_scatter_is_not_corrected():
    # the physics position's error is independent of every feature: a correction only adds the forests' scatter
    rng, xy, X = _sites()
    phys = xy + rng.normal(0, 5.0, xy.shape)
    choice = choose_correction_scale(X, phys, None, None, xy, SETTINGS)
    assert choice["scale"] <= 0.25, choice
    assert choice["out_of_fold_mae_mm"][0] < choice["out_of_fold_mae_mm"][-1]


def test_a_learnable_bias_is_corrected_whole():
    # the physics position is off by a smooth function of two features (a few mm of scatter on top)
    rng, xy, X = _sites()
    bias = np.stack([12.0 * X[:, 0], -9.0 * X[:, 1]], 1)
    phys = xy - bias + rng.normal(0, 1.0, xy.shape)
    choice = choose_correction_scale(X, phys, None, None, xy, SETTINGS)
    assert choice["scale"] == 1.0, choice
    assert choice["out_of_fold_mae_mm"][-1] < 0.6 * choice["out_of_fold_mae_mm"][0]


def test_few_sites_keep_the_whole_correction():
    rng, xy, X = _sites(n_sites=CORRECTION_MIN_SITES - 1)
    assert choose_correction_scale(X, xy + rng.normal(0, 5.0, xy.shape), None, None, xy, SETTINGS) is None


def test_a_new_users_few_sites_still_get_the_choice():
    """20 cases x 3 drops, 80 % of the cases trained: 16 sites. Under 20 sites the whole correction was kept
    with no choice (a thick steel plate, sensors in one corner: the held-out MAE 24.9 mm mean over 4 splits
    against 21.4 with the choice, docs/findings.md Session 22: newuser2); the one-standard-error rule still
    guards the whole correction."""
    assert CORRECTION_MIN_SITES <= 16
    rng, xy, X = _sites(n_sites=16, reps=3, seed=2)
    phys = xy + rng.normal(0, 5.0, xy.shape)
    choice = choose_correction_scale(X, phys, None, None, xy, SETTINGS)
    assert choice is not None and choice["scale"] <= 0.5, choice


def test_scaled_forests_predict_and_save_the_scaled_correction(tmp_path):
    rng, xy, X = _sites(n_sites=25)
    phys = xy - 10.0 * X[:, :2]
    fx, fy, _ = position_forests(X, phys, None, None, xy, SETTINGS)
    before = fx.predict(X[:5])
    scale_forests([fx], 0.25)
    np.testing.assert_allclose(fx.predict(X[:5]), 0.25 * before, rtol=1e-12)
    save_forest(tmp_path / "f.npz", fx)
    np.testing.assert_allclose(load_forest(tmp_path / "f.npz").predict(X[:5]), 0.25 * before, rtol=1e-12)


def test_a_model_without_a_site_map_carries_its_choice_and_predicts_the_scaled_correction(session1):
    from impactsense.models import LOCATION_FEATURES, ImpactModel, columns
    from impactsense.pipeline import featurize
    from impactsense.signal import SignalConfig

    rows = np.arange(0, len(session1), 6)
    cfg = SignalConfig.for_rig(session1.rig)
    feats = featurize(session1.adc[rows], cfg)
    model = ImpactModel.fit(feats, session1.xy_mm[rows], session1.height_mm[rows], session1.rig.ball_mass_g, cfg,
                            SETTINGS, members=False)
    choice = model.card["correction_scale"]
    assert choice["scale"] in choice["scales"] and len(choice["out_of_fold_mae_mm"]) == len(choice["scales"])
    # the same forests fitted whole (same settings and seed), times the chosen scale, plus the physics position
    use = feats.usable
    X = feats.vector[use][:, columns(LOCATION_FEATURES)]
    phys = feats.phys_xy_mm[use].astype(float)
    fx, fy, _ = position_forests(X, phys, None, None, session1.xy_mm[rows][use], SETTINGS)
    want = phys + choice["scale"] * np.stack([fx.predict(X), fy.predict(X)], 1)
    np.testing.assert_allclose(model.predict(feats)["xy_mm"][use], want, atol=1e-6)
