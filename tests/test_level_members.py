"""The position members at other onset thresholds (level_members.py): a level is the core's own localiser at another
threshold, the training drops' out-of-fold positions keep the members when their errors are partly independent of
the physics position's and not when they only add scatter, and a model with them reports the mean over its members
(its own featurize adds their positions), saves and loads them (docs/findings.md "Picks at other onset
thresholds")."""

import numpy as np
import pytest

from impactsense import correction_scale, level_members
from impactsense.correction_scale import choose_level_members
from impactsense.models import ForestSettings, ImpactModel
from impactsense.pipeline import featurize
from impactsense.signal import SignalConfig

SETTINGS = ForestSettings(n_estimators=20)


def test_a_level_is_the_core_localiser_at_that_threshold(session1, monkeypatch):
    rows = np.arange(0, len(session1), 40)
    cfg = SignalConfig.for_rig(session1.rig)
    trial = level_members.level_signal(cfg, 2.0)
    assert trial.onset_threshold_counts == 2.0 * cfg.onset_threshold_counts
    assert {k: v for k, v in trial.to_dict().items() if k != "onset_threshold_counts"} == \
        {k: v for k, v in cfg.to_dict().items() if k != "onset_threshold_counts"}
    # at the trained threshold a level is the core's physics position bit for bit
    monkeypatch.setattr(level_members, "LEVEL_FACTORS", (1.0, 2.0))
    xy = level_members.level_xy(session1.adc[rows], cfg)
    feats = featurize(session1.adc[rows], cfg)
    np.testing.assert_array_equal(xy[:, 0], feats.phys_xy_mm.astype(float))
    # a higher threshold picks other cycles: other positions, still localisations of the same drops
    err = np.abs(xy - session1.xy_mm[rows][:, None]).mean(axis=(0, 2))
    assert np.any(xy[:, 1] != xy[:, 0]) and err[1] < 3.0 * err[0] + 2.0, err


def _drops(level_noise, n_sites=40, reps=3, seed=0):
    rng = np.random.default_rng(seed)
    xy = np.repeat(rng.uniform(0, 400, (n_sites, 2)), reps, axis=0)
    X = rng.normal(size=(xy.shape[0], 6))
    phys = xy + rng.normal(0, 4.0, xy.shape)
    levels = {f"onset_x{k}": xy + level_noise(rng, phys, xy) for k in range(3)}
    return xy, X, phys, levels


def _choice(level_noise):
    xy, X, phys, levels = _drops(level_noise)
    X[:, :2] = phys     # the location features hold the physics position (members put theirs there)
    names = ["phys_x_mm", "phys_y_mm"] + [f"f{k}" for k in range(4)]
    return choose_level_members(X, phys, None, None, levels, xy, SETTINGS, names)


def test_levels_with_their_own_pick_noise_are_kept():
    # each level's error independent of the physics position's: the mean of four positions halves the scatter
    choice = _choice(lambda rng, phys, xy: rng.normal(0, 4.0, xy.shape))
    assert choice["keep"], choice
    assert choice["out_of_fold_mae_mm"][1] < 0.8 * choice["out_of_fold_mae_mm"][0]


def test_levels_that_only_add_scatter_are_not_kept():
    # the physics position's own error plus more scatter: the mean is worse than the physics position alone
    choice = _choice(lambda rng, phys, xy: (phys - xy) + rng.normal(0, 12.0, xy.shape))
    assert not choice["keep"], choice
    assert choice["out_of_fold_mae_mm"][1] > choice["out_of_fold_mae_mm"][0]


@pytest.fixture(scope="module")
def level_model(session1):
    rows = np.arange(0, len(session1), 6)
    cfg = SignalConfig.for_rig(session1.rig)
    feats = level_members.add_level_positions(featurize(session1.adc[rows], cfg), session1.adc[rows], cfg)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(correction_scale, "CORRECTION_GAIN_SIGMAS", -np.inf)    # keep them whatever the gain
        model = ImpactModel.fit(feats, session1.xy_mm[rows], session1.height_mm[rows], session1.rig.ball_mass_g,
                                cfg, SETTINGS, choose_edge=True)
    return model, rows


def test_a_model_with_level_members_reports_their_mean_and_reloads(level_model, session1, tmp_path):
    model, rows = level_model
    assert set(level_members.LEVEL_MEMBERS) <= set(model.members), model.members.keys()
    assert model.card["level_members"]["keep"]
    adc = session1.adc[rows[:20]]
    with_levels = model.predict(model.featurize(adc))["xy_mm"]
    # features without the levels' positions (pipeline.featurize alone): those members do not join the mean
    without = model.predict(featurize(adc, model.signal))["xy_mm"]
    assert np.isfinite(with_levels).all() and np.any(np.abs(with_levels - without) > 1e-6)
    model.save(tmp_path / "m")
    loaded = ImpactModel.load(tmp_path / "m")
    assert set(loaded.members) == set(model.members)
    np.testing.assert_allclose(loaded.predict(loaded.featurize(adc))["xy_mm"], with_levels, atol=1e-9)
