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


def test_a_model_with_host_columns_saves_loads_and_stays_off_the_board(session1, tmp_path):
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
