"""The edge correction of the arrival times (edge_travel.py): fitted from drops at known positions it recovers a
late arrival that follows the edge images' geometry, the localiser re-run on the corrected picks places drops near
the edges closer to the truth, zero coefficients give the core's positions bit for bit, and a model with the edge
members reports the mean over its members, saves and loads them and refuses a damaged card (docs/findings.md
"Edge images in the travel time")."""

import json

import numpy as np
import pytest

from impactsense import _core
from impactsense.edge_travel import N_BASES, corrected, fit_correction, travel_bases
from impactsense.errors import DataError
from impactsense.signal import SignalConfig

SX = [50.0, 400.0, 395.0, 60.0]
SY = [45.0, 55.0, 300.0, 290.0]
V = 1.2


def plate() -> SignalConfig:
    cfg = SignalConfig()
    cfg.sensor_x_mm, cfg.sensor_y_mm = list(SX), list(SY)
    cfg.plate_x_mm, cfg.plate_y_mm = 450.0, 350.0
    cfg.velocity_mm_per_us = V
    cfg.localiser_starts = 4
    cfg.sigma_us = 3.0
    return cfg


# late where the x-edges' images are close behind the direct path, earlier along the y-edges, and a curve in d
TRUE_COEF = np.array([-0.02, 0.004, 0.0, 0.0, 7.0, -3.0, 0.0, 0.0])


def drops(cfg, n, seed, coef=TRUE_COEF, noise_us=0.5):
    rng = np.random.default_rng(seed)
    xy = rng.uniform([5.0, 5.0], [445.0, 345.0], (n, 2))
    d = np.hypot(xy[:, None, 0] - np.array(SX)[None], xy[:, None, 1] - np.array(SY)[None])
    toa = 100.0 + rng.normal(0, 20, (n, 1)) + d / V + travel_bases(xy, cfg, "threshold") @ coef
    toa = toa + rng.normal(0, noise_us, toa.shape)
    raw = {"toa_us": toa.astype(np.float32), "flags": np.zeros((n, 4), np.uint8),
           "pick_period": np.full((n, 4), np.nan, np.float32)}
    return raw, xy


def plain(raw, cfg):
    return corrected(raw, cfg, "threshold", np.zeros((len(raw["toa_us"]), 2)) + 200.0, np.zeros(N_BASES))


def test_fit_recovers_the_correction_shared_by_the_channels():
    cfg = plate()
    raw, xy = drops(cfg, 300, 1)
    coef = fit_correction(raw, xy, cfg, "threshold")
    assert coef is not None and len(coef) == N_BASES
    test_xy = np.random.default_rng(2).uniform([5, 5], [445, 345], (200, 2))
    got = travel_bases(test_xy, cfg, "threshold") @ np.asarray(coef)
    want = travel_bases(test_xy, cfg, "threshold") @ TRUE_COEF
    # centred over the channels (a common offset is the drop's t0): within the picks' 0.5 us noise
    err = (got - got.mean(1, keepdims=True)) - (want - want.mean(1, keepdims=True))
    spread = want - want.mean(1, keepdims=True)
    assert np.sqrt(np.mean(err ** 2)) < 0.2 < 0.5 < np.sqrt(np.mean(spread ** 2))


def test_zero_coefficients_are_the_core_localiser_bit_for_bit():
    cfg = plate()
    raw, _ = drops(cfg, 40, 3)
    use = np.ones((40, 4), np.uint8)
    core = _core.localise_batch(raw["toa_us"], use, SX, SY, V, cfg.sigma_us, 450.0, 350.0, cfg.huber_us,
                                [1.0, 0.0, 1.0], [], 4, 0)
    np.testing.assert_array_equal(plain(raw, cfg), np.c_[core["x_mm"], core["y_mm"]].astype(float))


def test_corrected_positions_closer_near_the_edges():
    cfg = plate()
    raw, xy = drops(cfg, 300, 4)
    coef = fit_correction(raw, xy, cfg, "threshold")
    raw_t, xy_t = drops(cfg, 200, 5)
    before = plain(raw_t, cfg)
    after = corrected(raw_t, cfg, "threshold", before, coef)
    err_before = np.abs(before - xy_t).mean()
    err_after = np.abs(after - xy_t).mean()
    assert err_after < 0.6 * err_before
    # exact direct-path picks: nothing to correct, the fit stays near zero and the positions where they were
    raw0, xy0 = drops(cfg, 300, 6, coef=np.zeros(N_BASES))
    coef0 = np.asarray(fit_correction(raw0, xy0, cfg, "threshold"))
    c = travel_bases(xy0, cfg, "threshold") @ coef0
    assert np.abs(c - c.mean(1, keepdims=True)).max() < 0.5


@pytest.fixture(scope="module")
def edge_model(session1, tmp_path_factory, band_on_subset):
    """A session-1 subset with the band picks on and the edge members forced on (the rule itself keeps them only
    when the training drops' physics positions gain: models.choose_edge_travel)."""
    import impactsense.models as models

    rows, cfg, feats = band_on_subset()
    forced = {"threshold": fit_correction(feats.raw, session1.xy_mm[rows], cfg, "threshold"),
              "band": fit_correction(feats.raw, session1.xy_mm[rows], cfg, "band")}
    import impactsense.correction_scale as correction_scale

    keep = models.choose_edge_travel, models.training_fields, correction_scale.STACK, models.location_names
    models.choose_edge_travel = lambda *a: forced
    models.training_fields = lambda *a: ({}, None)    # the edge members alone (no travel-field members)
    correction_scale.STACK = False                    # their mean (not the members' stack, member_stack.py)
    models.location_names = lambda left, host: keep[3](left, False)   # the core's inputs, as `without` (host_columns.py)
    try:
        args = (feats, session1.xy_mm[rows], session1.height_mm[rows], session1.rig.ball_mass_g, cfg,
                models.ForestSettings(n_estimators=10))
        model = models.ImpactModel.fit(*args, choose_edge=True)
        without = models.ImpactModel.fit(*args)
    finally:
        models.choose_edge_travel, models.training_fields, correction_scale.STACK, models.location_names = keep
    out = tmp_path_factory.mktemp("edge") / "model"
    model.save(out)
    return model, without, feats, out


def test_the_edge_members_join_the_mean(edge_model):
    from impactsense.position_members import EDGE_MEMBERS, POSITION_MEMBERS, edge_positions

    model, without, feats, _ = edge_model
    assert set(model.members) == set(POSITION_MEMBERS + EDGE_MEMBERS)
    got = model.predict(feats)["xy_mm"]
    base = without.predict(feats)["xy_mm"]        # the same main pair and band members (same seed)
    use = feats.usable
    edge = edge_positions(feats.take(np.flatnonzero(use)), model.signal, model.edge_travel)
    placed = np.isfinite(edge["band_edge"]).all(1)
    assert placed.mean() > 0.8
    # where the band picks placed the drop: six members, the three of `without` among them
    total = base[use] * 3
    from impactsense.models import LOCATION_FEATURES, columns
    from impactsense.position_members import member_inputs
    X = feats.vector[use][:, columns(LOCATION_FEATURES)]
    for name in EDGE_MEMBERS:
        ok = np.isfinite(edge[name]).all(1)
        pred = np.stack([f.predict(member_inputs(X[ok], edge[name][ok], LOCATION_FEATURES)) for f in model.members[name]], 1)
        total[ok] += edge[name][ok] + pred
    assert np.allclose(got[use][placed], total[placed] / 6, atol=1e-4)
    assert np.abs(got[use] - base[use]).max() > 0.01


def test_a_saved_edge_model_loads_and_predicts_the_same(edge_model):
    from impactsense.models import ImpactModel

    model, _, feats, out = edge_model
    loaded = ImpactModel.load(out)
    assert loaded.edge_travel == model.edge_travel
    # the forests' file keeps their nodes exactly; only the order of the sums may move the last bit
    np.testing.assert_allclose(loaded.predict(feats)["xy_mm"], model.predict(feats)["xy_mm"], rtol=0, atol=1e-9)
    card = json.loads((out / "model_card.json").read_text())
    assert card["edge_travel"]["threshold"] == model.edge_travel["threshold"]


def test_a_damaged_edge_card_is_refused(edge_model, tmp_path):
    import shutil

    from impactsense.models import ImpactModel

    _, _, _, out = edge_model
    bad = tmp_path / "bad"
    shutil.copytree(out, bad)
    card_path = bad / "model_card.json"
    card = json.loads(card_path.read_text())
    card["edge_travel"]["threshold"] = card["edge_travel"]["threshold"][:-1]
    card_path.write_text(json.dumps(card))
    with pytest.raises(DataError, match="edge_travel"):
        ImpactModel.load(bad)


def test_the_board_refits_a_model_with_edge_members(edge_model):
    from impactsense.export import beyond_the_board

    _, _, _, out = edge_model
    card = json.loads((out / "model_card.json").read_text())
    assert beyond_the_board(card)[0] == "position_members"


def test_too_few_positions_are_not_tried(session1, monkeypatch):
    """Eight shared coefficients fitted on drops at a few positions pass the rule on those same drops (they fit
    them): under EDGE_MIN_SITES distinct positions the correction is not tried."""
    from impactsense import position_members
    from impactsense.pipeline import featurize

    rows = np.flatnonzero(session1.case_id < 12)
    assert len(np.unique(np.round(session1.xy_mm[rows], 1), axis=0)) < position_members.EDGE_MIN_SITES
    cfg = SignalConfig.for_rig(session1.rig)
    feats = featurize(session1.adc[rows], cfg)
    assert position_members.choose_edge_travel(feats, session1.xy_mm[rows], cfg) is None
    monkeypatch.setattr(position_members, "EDGE_MIN_SITES", 0)
    assert position_members.choose_edge_travel(feats, session1.xy_mm[rows], cfg) is not None


def test_three_sensor_positions_with_the_edge_correction():
    """With one channel's pick not read, the three picks fix x, y and t0 exactly: an edge-image bias of a few us
    moves the plain three-sensor position by centimetres near the edges, and nothing absorbs it. The same
    correction (its coefficients fitted on four-channel drops) brings the three-sensor positions back: without
    coefficients bit for bit the plain one, with them closer to the truth near the edges (issues 14/15,
    docs/findings.md "Unseen fault draws")."""
    from impactsense.edge_travel import three_sensor_positions

    cfg = plate()
    raw, xy = drops(cfg, 300, 6)
    coefs = {"threshold": fit_correction(raw, xy, cfg, "threshold"), "band": None}
    raw_t, xy_t = drops(cfg, 200, 7)
    edge = np.min(np.c_[xy_t, [450.0, 350.0] - xy_t], 1) < 60.0
    for c in range(4):
        before = three_sensor_positions(raw_t, cfg, c)
        np.testing.assert_array_equal(three_sensor_positions(raw_t, cfg, c, {"threshold": None, "band": None}), before)
        after = three_sensor_positions(raw_t, cfg, c, coefs)
        err_before = np.hypot(*(before - xy_t)[edge].T)
        err_after = np.hypot(*(after - xy_t)[edge].T)
        ok = np.isfinite(err_before) & np.isfinite(err_after)
        assert ok.sum() > 0.9 * edge.sum()
        assert np.median(err_after[ok]) < 0.6 * np.median(err_before[ok]), c


def near_field(xy, cfg, pick_set):
    """Another travel law's basis (what fit_correction and corrected take as `bases`): a pick late near its sensor."""
    d = np.hypot(np.asarray(xy)[:, None, 0] - np.array(SX)[None], np.asarray(xy)[:, None, 1] - np.array(SY)[None])
    return np.exp(-d / 40.0)[:, :, None]


def test_another_law_s_bases_are_fitted_and_corrected():
    cfg = plate()
    rng = np.random.default_rng(7)

    def near_drops(n):
        xy = rng.uniform([5.0, 5.0], [445.0, 345.0], (n, 2))
        d = np.hypot(xy[:, None, 0] - np.array(SX)[None], xy[:, None, 1] - np.array(SY)[None])
        toa = 100.0 + d / V + 12.0 * near_field(xy, cfg, "threshold")[:, :, 0] + rng.normal(0, 0.5, d.shape)
        return {"toa_us": toa.astype(np.float32), "flags": np.zeros((n, 4), np.uint8),
                "pick_period": np.full((n, 4), np.nan, np.float32)}, xy

    raw, xy = near_drops(300)
    coef = fit_correction(raw, xy, cfg, "threshold", bases=near_field)
    assert len(coef) == 1 and abs(coef[0] - 12.0) < 1.0
    raw_t, xy_t = near_drops(200)
    before = plain(raw_t, cfg)
    after = corrected(raw_t, cfg, "threshold", before, coef, bases=near_field)
    near = np.hypot(xy_t[:, None, 0] - np.array(SX)[None], xy_t[:, None, 1] - np.array(SY)[None]).min(1) < 60.0
    assert near.sum() >= 10
    assert np.abs(after - xy_t)[near].mean() < 0.6 * np.abs(before - xy_t)[near].mean()
