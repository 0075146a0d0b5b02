"""The host's location inputs beside the core's feature vector (host_columns.py): ratios of the core's own per-channel
numbers, so a channel's gain cancels in them; a model reads them only where the board never has to (with its
members, without a site map), saves and loads them, and the board's export sends such a model to its own forests
(docs/findings.md "Session 22: rigcpos")."""

import numpy as np

from impactsense.export import beyond_the_board
from impactsense.host_columns import HOST_LOCATION_FEATURES, host_columns, location_matrix, location_names
from impactsense.models import LOCATION_FEATURES, ForestSettings, ImpactModel
from impactsense.pipeline import FEATURE_NAMES, featurize
from impactsense.signal import SignalConfig


def _tilts(names):
    return [k for k, n in enumerate(HOST_LOCATION_FEATURES) if n.startswith(names)]


def test_a_channel_gain_cancels_in_the_tilts(session1):
    rows = np.arange(0, len(session1), 12)
    cfg = SignalConfig.for_rig(session1.rig)
    adc = session1.adc[rows]
    bias = float(session1.rig.bias_counts)
    quiet = adc.astype(float)
    quiet[:, 1] = bias + 0.7 * (quiet[:, 1] - bias)     # channel 1 at 0.7 x its gain
    before = featurize(adc, cfg)
    after = featurize(np.round(quiet).astype(adc.dtype), cfg)
    ok = before.usable & after.usable
    a, b = host_columns(before.raw)[ok], host_columns(after.raw)[ok]
    energy_shift = np.median(np.log10(after.raw["energy"][ok, 1] / before.raw["energy"][ok, 1]))
    assert abs(energy_shift - 2 * np.log10(0.7)) < 0.02          # the gain did reach the channel's energy
    for k in _tilts(("early_tilt_21_1", "early_tilt_32_1", "early_share_1")):
        # the channel's tilts move far less than its energy (the pick may move by a sample at the lower gain)
        assert np.median(np.abs(b[:, k] - a[:, k])) < 0.1 * abs(energy_shift), HOST_LOCATION_FEATURES[k]
    other = _tilts(("early_tilt_21_0", "early_tilt_32_0", "early_share_0"))
    np.testing.assert_allclose(b[:, other], a[:, other], atol=1e-6)   # the other channels untouched


def test_core_names_read_the_vector_bit_for_bit(session1):
    rows = np.arange(0, len(session1), 40)
    feats = featurize(session1.adc[rows], SignalConfig.for_rig(session1.rig))
    core = location_names((0, 0, 0, 0), False)
    assert core == LOCATION_FEATURES
    np.testing.assert_array_equal(location_matrix(feats, core),
                                  feats.vector[:, [FEATURE_NAMES.index(n) for n in core]])
    both = location_names((0, 0, 0, 0), True)
    assert both[:len(core)] == core and set(both[len(core):]) == set(HOST_LOCATION_FEATURES)
    X = location_matrix(feats, both)
    assert X.shape == (len(rows), len(both)) and np.isfinite(X[feats.usable]).all()
    # a channel left out: none of its host columns either
    assert not any(n.endswith("_2") for n in location_names((0, 0, 1, 0), True)[len(core) - 3:])


def test_a_model_with_host_columns_saves_loads_and_stays_off_the_board(session1, tmp_path, monkeypatch):
    from impactsense import host_columns as hc

    monkeypatch.setattr(hc, "HOST_CHOICE", "always")         # whatever the rule says on these drops
    rows = np.arange(0, len(session1), 3)
    cfg = SignalConfig.for_rig(session1.rig)
    feats = featurize(session1.adc[rows], cfg)
    fit = dict(members=True, choose_edge=True)
    model = ImpactModel.fit(feats, session1.xy_mm[rows], session1.height_mm[rows], session1.rig.ball_mass_g, cfg,
                            ForestSettings(n_estimators=10), **fit)
    assert set(HOST_LOCATION_FEATURES) <= set(model.location_features)
    board = ImpactModel.fit(feats, session1.xy_mm[rows], session1.height_mm[rows], session1.rig.ball_mass_g, cfg,
                            ForestSettings(n_estimators=10), members=False)
    assert not set(HOST_LOCATION_FEATURES) & set(board.location_features)    # the board's pair: the core's only
    back = ImpactModel.load(model.save(tmp_path / "m"))
    np.testing.assert_array_equal(back.predict(feats)["xy_mm"], model.predict(feats)["xy_mm"])
    card = {"location_features": model.location_features, "signal": {}}
    assert beyond_the_board(card)[0] == "location_features"
    assert beyond_the_board({"location_features": LOCATION_FEATURES, "signal": {}}) is None


def _sites_with_a_hidden_bias(seed=0, n_sites=40, reps=3):
    """Drops at n_sites sites, reps each: a physics position off the truth by a smooth function of a column the
    core's inputs do not carry (h), and a pure-noise column."""
    rng = np.random.default_rng(seed)
    site_xy = rng.uniform(0, 400, (n_sites, 2))
    xy = np.repeat(site_xy, reps, 0)                         # the declared position: a site's drops share it
    h = np.repeat(rng.uniform(-1, 1, n_sites), reps) + rng.normal(0, 0.05, n_sites * reps)
    phys = xy + np.stack([6 * h, -4 * h], 1) + rng.normal(0, 1.0, xy.shape)
    core = np.column_stack([phys, rng.normal(0, 1, (len(xy), 3))])
    return xy, phys, core, h[:, None], rng.normal(0, 1, (len(xy), 1))


def test_extra_inputs_kept_when_they_carry_the_sites_bias_dropped_when_noise():
    from impactsense.correction_scale import choose_extra_inputs

    xy, phys, core, h, noise = _sites_with_a_hidden_bias()
    names = ["phys_x_mm", "phys_y_mm", "a", "b", "c"]
    settings = ForestSettings(n_estimators=20)
    useful = choose_extra_inputs(core, np.hstack([core, h]), phys, None, None, xy, settings, names, names + ["h"])
    assert useful["keep"] and useful["out_of_fold_mae_mm"][1] < useful["out_of_fold_mae_mm"][0] - 1.0
    assert useful["gain_sigmas"] > 1.0
    useless = choose_extra_inputs(core, np.hstack([core, noise]), phys, None, None, xy, settings, names,
                                  names + ["n"])
    assert not useless["keep"]                               # the simpler model is the default
    assert useless["gain_sigmas"] < 1.0
    # too few sites for five site-grouped folds of two: no choice
    few = slice(0, 9 * 3)
    assert choose_extra_inputs(core[few], np.hstack([core, h])[few], phys[few], None, None, xy[few], settings,
                               names, names + ["h"]) is None


def test_train_records_the_choice_and_the_model_reads_what_it_chose(session1):
    rows = np.arange(0, len(session1), 3)
    cfg = SignalConfig.for_rig(session1.rig)
    feats = featurize(session1.adc[rows], cfg)
    model = ImpactModel.fit(feats, session1.xy_mm[rows], session1.height_mm[rows], session1.rig.ball_mass_g, cfg,
                            ForestSettings(n_estimators=10), members=True, choose_edge=True)
    choice = model.card["host_location_inputs"]
    assert set(choice) >= {"keep", "out_of_fold_mae_mm", "gain_sigmas", "board"}
    host = set(HOST_LOCATION_FEATURES) & set(model.location_features)
    assert host == (set(HOST_LOCATION_FEATURES) if choice["keep"] else set())
    assert "core's feature vector only" in choice["board"]
