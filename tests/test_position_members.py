"""With the band picks on, the threshold picks' and the band picks' own positions each get a forest pair
(models.POSITION_MEMBERS) and the reported position is the mean of the three corrected positions (without the
members' stack, member_stack.py)."""

import json

import numpy as np
import pytest

from impactsense import correction_scale
from impactsense.export import ExportError, load_models
from impactsense.models import LOCATION_FEATURES, ForestSettings, ImpactModel
from impactsense.position_members import POSITION_MEMBERS, member_positions
from impactsense.pipeline import featurize
from impactsense.signal import SignalConfig


@pytest.fixture(scope="module")
def band_on(session1, band_on_subset):
    rows, cfg, feats = band_on_subset()
    args = (feats, session1.xy_mm[rows], session1.height_mm[rows], session1.rig.ball_mass_g, cfg,
            ForestSettings(n_estimators=10))
    stack, correction_scale.STACK = correction_scale.STACK, False   # the mean, not the members' stack
    try:
        return ImpactModel.fit(*args), ImpactModel.fit(*args, members=False), feats
    finally:
        correction_scale.STACK = stack


def test_the_members_are_the_two_positions_whose_mean_is_the_physics_position(band_on):
    _, _, feats = band_on
    pos = member_positions(feats)
    placed = np.isfinite(pos["band"]).all(1)
    assert placed.mean() > 0.8
    mean = 0.5 * (pos["threshold"][placed] + pos["band"][placed])
    assert np.abs(mean - feats.phys_xy_mm[placed]).max() < 1e-3
    # the two positions are not the same (else there is nothing to average)
    assert np.median(np.hypot(*(pos["threshold"][placed] - pos["band"][placed]).T)) > 0.5


def test_the_reported_position_is_the_mean_of_the_three_corrected_positions(band_on):
    model, one_pair, feats = band_on
    assert set(model.members) == set(POSITION_MEMBERS) and not one_pair.members
    got = model.predict(feats)["xy_mm"]
    main = one_pair.predict(feats)["xy_mm"]          # the same first pair (same settings and seed)
    pos = member_positions(feats)
    placed = feats.usable & np.isfinite(pos["band"]).all(1)
    X = feats.vector[:, [list(feats_names()).index(n) for n in LOCATION_FEATURES]].astype(float)
    total = main.copy()
    for name in POSITION_MEMBERS:
        Xb = X.copy()
        Xb[:, [LOCATION_FEATURES.index("phys_x_mm"), LOCATION_FEATURES.index("phys_y_mm")]] = pos[name]
        for k in range(2):
            total[placed, k] += pos[name][placed, k] + model.members[name][k].predict(Xb[placed])
    assert np.allclose(got[placed], total[placed] / 3, atol=1e-6)
    assert np.array_equal(got[~placed & feats.usable], main[~placed & feats.usable])


def feats_names():
    from impactsense.pipeline import FEATURE_NAMES

    return FEATURE_NAMES


def test_saved_and_loaded_alike_and_the_board_export_refuses_it(band_on, tmp_path):
    model, one_pair, feats = band_on
    model.save(tmp_path / "m")
    card = json.loads((tmp_path / "m" / "model_card.json").read_text())
    assert card["position_members"] == list(POSITION_MEMBERS)
    again = ImpactModel.load(tmp_path / "m")
    assert np.allclose(again.predict(feats)["xy_mm"], model.predict(feats)["xy_mm"], atol=1e-9)   # summation order
    with pytest.raises(ExportError, match="position_members"):
        load_models(tmp_path / "m")
    one_pair.save(tmp_path / "one")
    assert "position_members" not in json.loads((tmp_path / "one" / "model_card.json").read_text())
    load_models(tmp_path / "one")


def test_without_band_positions_there_are_no_members(session1):
    rows = np.arange(0, len(session1), 20)
    cfg = SignalConfig.for_rig(session1.rig)
    feats = featurize(session1.adc[rows], cfg)
    model = ImpactModel.fit(feats, session1.xy_mm[rows], session1.height_mm[rows], session1.rig.ball_mass_g, cfg,
                            ForestSettings(n_estimators=5))
    assert member_positions(feats) is None and not model.members



def test_a_member_that_places_no_drop_of_a_fold_reads_nan_not_a_crash():
    """A fold of few sites (20 cases x 3: the correction's choice from 10 sites) can hold no drop the band
    picks placed; the members' forests were asked to predict 0 rows and sklearn's ValueError ended `retrain`."""
    from sklearn.ensemble import RandomForestRegressor

    from impactsense.position_members import each_member_position

    rng = np.random.default_rng(0)
    n, names = 6, ["phys_x_mm", "phys_y_mm", "c"]
    X = rng.normal(size=(n, 3))
    phys = rng.uniform(0, 100, (n, 2))
    fit = RandomForestRegressor(n_estimators=2, random_state=0).fit(rng.normal(size=(10, 3)), rng.normal(size=10))
    members = {m: (fit, fit) for m in POSITION_MEMBERS}
    positions = {m: np.full((n, 2), np.nan) for m in [*POSITION_MEMBERS, "band"]}
    out = each_member_position(phys, phys, members, X, positions, None, names)
    assert all(np.isnan(out[m][0]).all() and np.isnan(out[m][1]).all() for m in POSITION_MEMBERS)
    positions = {m: phys + 1.0 for m in [*POSITION_MEMBERS, "band"]}      # placed: predicted as before
    out = each_member_position(phys, phys, members, X, positions, None, names)
    assert all(np.isfinite(out[m][0]).all() for m in POSITION_MEMBERS)
