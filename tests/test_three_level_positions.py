"""The three-sensor position as the mean over the onset levels (three_level_positions.py) and the training-time
choice between it and the single-threshold position (three_channel_position._better)."""

import numpy as np
import pytest

from impactsense.data import load_session
from impactsense.edge_travel import three_sensor_positions
from impactsense.faults import FaultSpec, inject_session
from impactsense.level_members import level_signal
from impactsense.pipeline import featurize, fit_localiser
from impactsense.signal import SignalConfig
from impactsense.three_channel_position import _better
from impactsense.three_level_positions import (THREE_LEVEL_FACTORS, add_level_picks, has_level_picks,
                                                 level_three_positions)


@pytest.fixture(scope="module")
def dead_channel_drops():
    s1 = load_session().subset(np.arange(0, 771, 16))
    cfg = fit_localiser(s1, np.arange(len(s1)), SignalConfig.for_rig(s1.rig))
    dead = inject_session(s1, FaultSpec(dead_channel=2, noise=1, seed=2))
    return add_level_picks(featurize(dead.adc, cfg), dead.adc, cfg), dead, cfg


def test_the_level_mean_is_the_mean_of_the_positions_the_core_gives_at_each_level(dead_channel_drops):
    """With channel 2 dead the core's position at each onset level is its three-sensor one: the host's mean over
    the levels equals the mean of the core's positions (process_event at each threshold) within float32
    rounding, and a row the trained threshold does not place stays unplaced."""
    f, dead, cfg = dead_channel_drops
    assert has_level_picks(f.raw) and f.raw["three_level_toa_us"].shape == (len(f), len(THREE_LEVEL_FACTORS), 4)
    base = three_sensor_positions(f.raw, cfg, 2)
    mean = level_three_positions(f.raw, cfg, 2, base)
    core = np.stack([f.phys_xy_mm] + [featurize(dead.adc, level_signal(cfg, k)).phys_xy_mm
                                      for k in THREE_LEVEL_FACTORS], 1).astype(float)
    rows = np.isfinite(core).all((1, 2))
    assert rows.mean() > 0.8
    np.testing.assert_allclose(mean[rows], core[rows].mean(1), atol=0.1)
    base[0] = np.nan
    assert np.isnan(level_three_positions(f.raw, cfg, 2, base)[0]).all()


def test_the_levels_are_kept_only_for_a_gain_beyond_one_standard_error():
    """_better: kept when the level mean's out-of-fold errors are lower by far more than the per-site
    scatter of the gains, not for a gain within it, nor when the two were scored on different drops."""
    rng = np.random.default_rng(0)
    xy = np.repeat(rng.uniform(0, 400, (40, 2)), 3, axis=0)   # 40 sites x 3 drops
    rows = np.ones(len(xy), bool)
    plain = {"rows": rows, "err": rng.gamma(2.0, 2.0, len(xy))}
    better = {"rows": rows, "err": plain["err"] * 0.7}
    noise = {"rows": rows, "err": plain["err"] + rng.normal(0.0, 1.0, len(xy))}
    assert _better(plain, better, xy)
    assert not _better(better, plain, xy)
    assert not _better(plain, {"rows": rows, "err": noise["err"] - 0.05 * noise["err"].std()}, xy)
    assert not _better(plain, {"rows": ~rows, "err": better["err"]}, xy)
    assert not _better({"rows": rows, "err": None}, better, xy)


def test_a_model_whose_three_sensor_path_reads_the_levels_saves_loads_and_leaves_clean_drops_alone(tmp_path):
    """A model whose card lists channel 1 for the level mean: its featurize adds the level picks, the drops with
    channel 1 dead move to the corrected level mean (not the single-threshold position), the drops with every
    channel are placed as without it bit for bit, and a saved copy predicts the same; a card listing a channel
    without a pair is refused."""
    from dataclasses import replace

    from impactsense.errors import DataError
    from impactsense.models import ForestSettings, ImpactModel

    s1 = load_session().subset(np.arange(0, 771, 4))
    train, test = np.arange(0, len(s1) - 40), np.arange(len(s1) - 40, len(s1))
    cfg = fit_localiser(s1, train, SignalConfig.for_rig(s1.rig))
    f = featurize(s1.adc[train], cfg)
    model = ImpactModel.fit(f, s1.xy_mm[train], s1.height_mm[train], s1.rig.ball_mass_g, cfg,
                            ForestSettings(n_estimators=10))
    assert model.card["three_channel_position_levels"] == []   # no level picks in its features: never tried
    levels = replace(model, card={**model.card, "three_channel_position_levels": [1]})
    dead = inject_session(s1.subset(test), FaultSpec(dead_channel=1, noise=1, seed=1))
    fd = levels.featurize(dead.adc)
    assert has_level_picks(fd.raw) and not has_level_picks(model.featurize(dead.adc).raw)
    new, old = levels.predict(fd), model.predict(fd)
    rows = new["three_channel"]
    assert rows.mean() > 0.9 and np.abs(new["xy_mm"][rows] - old["xy_mm"][rows]).max() > 0.5
    clean = levels.featurize(s1.adc[test])
    np.testing.assert_array_equal(levels.predict(clean)["xy_mm"], model.predict(clean)["xy_mm"])
    levels.save(tmp_path / "m")
    back = ImpactModel.load(tmp_path / "m")
    np.testing.assert_array_equal(back.predict(back.featurize(dead.adc))["xy_mm"], new["xy_mm"])
    import json
    card = json.loads((tmp_path / "m" / "model_card.json").read_text())
    card["three_channel_position_levels"] = [7]
    (tmp_path / "m" / "model_card.json").write_text(json.dumps(card))
    with pytest.raises(DataError, match="three_channel_position_levels"):
        ImpactModel.load(tmp_path / "m")
    # the edge-corrected three-sensor position needs the model's edge correction (this one has none)
    assert model.card["three_channel_position_edge"] == [] and not model.edge_travel
    card["three_channel_position_levels"], card["three_channel_position_edge"] = [1], [1]
    (tmp_path / "m" / "model_card.json").write_text(json.dumps(card))
    with pytest.raises(DataError, match="three_channel_position_edge"):
        ImpactModel.load(tmp_path / "m")
