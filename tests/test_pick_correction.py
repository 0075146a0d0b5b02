"""The three-sensor path's pick corrections (pick_correction.py) and its stack of plain and corrected positions
(three_channel_position.stack_weights / stacked_positions)."""

import json
from dataclasses import replace

import numpy as np
import pytest

from impactsense.correction_scale import drop_sites
from impactsense.data import load_session
from impactsense.edge_travel import _localise
from impactsense.errors import DataError
from impactsense.faults import FaultSpec, inject_session
from impactsense.modelfolder import CARD_FILE
from impactsense.models import ForestSettings, ImpactModel
from impactsense.pick_correction import fit_pick_corrections, pick_corrections, pick_errors
from impactsense.pipeline import featurize, fit_localiser
from impactsense.signal import SignalConfig
from impactsense.split import case_split
from impactsense.three_channel_position import stack_weights
from impactsense.three_level_positions import add_level_picks


LATE_US = 15.0


@pytest.fixture(scope="module")
def drops():
    s1 = load_session().subset(np.arange(0, 771, 3))
    train, test = case_split(s1.case_id, 0.25, 0, None)
    cfg = fit_localiser(s1, train, SignalConfig.for_rig(s1.rig))
    feats = {name: add_level_picks(featurize(s1.adc[rows], cfg), s1.adc[rows], cfg)
             for name, rows in (("train", train), ("test", test))}
    return s1, train, test, cfg, feats


def _late_cycle(raw: dict) -> dict:
    """The threshold picks LATE_US late (about a cycle of the plate's first arrival) on every channel whose first
    peak is below that channel's median: a repeatable error the channel's own signal tells."""
    raw = dict(raw)
    fp = np.asarray(raw["first_peak"], float)
    late = fp < np.median(fp, 0, keepdims=True)
    raw["toa_us"] = np.asarray(raw["toa_us"], float) + np.where(late, LATE_US, 0.0)
    return raw


def test_a_pick_error_the_channels_own_signal_tells_is_learnt_and_the_three_sensor_position_recovers(drops):
    """With the threshold picks LATE_US late on the weaker half of each channel's drops, the correction learnt on
    the training drops takes more than a third of the added scatter off the held-out drops' pick errors (about
    half measured: what the first peak tells), and their three-sensor position with any channel out, 1.5 x or
    more off the unchanged picks' without it, comes back to within 1.1 x of it."""
    s1, train, test, cfg, feats = drops
    raw_tr, raw_te = _late_cycle(feats["train"].raw), _late_cycle(feats["test"].raw)
    xy_tr, xy_te = s1.xy_mm[train], s1.xy_mm[test]
    forests, oof = fit_pick_corrections(raw_tr, xy_tr, cfg, feats["train"].phys_xy_mm, drop_sites(xy_tr))
    assert "threshold" in forests and oof["threshold"].shape == (len(train), 4)
    corr = pick_corrections(forests, raw_te, cfg, feats["test"].phys_xy_mm)
    spread = lambda e: np.nanmean(np.abs(e - np.nanmedian(e)))  # noqa: E731
    clean = spread(pick_errors(feats["test"].raw, cfg, xy_te, "threshold"))
    late = pick_errors(raw_te, cfg, xy_te, "threshold")
    assert spread(late - corr["threshold"]) < spread(late) - (spread(late) - clean) / 3
    err = lambda p: np.nanmean(np.abs(p - xy_te))  # noqa: E731
    for c in range(4):
        unchanged = err(_localise(feats["test"].raw, cfg, "threshold", 0.0, without=c))
        assert err(_localise(raw_te, cfg, "threshold", 0.0, without=c)) > 1.5 * unchanged
        assert err(_localise(raw_te, cfg, "threshold", corr["threshold"], without=c)) < 1.1 * unchanged


def test_the_stack_weights_recover_a_known_combination():
    """Positions whose truth is base + 0.6 (b - a): the weights (-0.6, 0.6, 1) within 0.05, summing to 1."""
    rng = np.random.default_rng(0)
    base = rng.uniform(0, 300, (200, 2))
    a, b = base + rng.normal(0, 5, (200, 2)), base + rng.normal(0, 5, (200, 2))
    truth = base + 0.6 * (b - a)
    w = stack_weights(np.stack([a, b, base], 1), truth)
    np.testing.assert_allclose(w, [-0.6, 0.6, 1.0], atol=0.05)
    assert abs(w.sum() - 1) < 1e-9


def test_a_models_stack_moves_only_its_channels_three_sensor_rows_and_saves_with_checksums(drops, tmp_path):
    """A model with a stack for channel 1: a drop with channel 1 dead moves from the position before the stack;
    one with channel 2 dead (no stack) and the clean drops are placed as before, bit for bit; the model saves
    and loads the same; a card whose weights do not fit the pick sets is refused naming the field."""
    s1, train, test, cfg, feats = drops
    model = ImpactModel.fit(featurize(s1.adc[train], cfg), s1.xy_mm[train], s1.height_mm[train],
                            s1.rig.ball_mass_g, cfg, ForestSettings(n_estimators=10))
    forests, _ = fit_pick_corrections(feats["train"].raw, s1.xy_mm[train], cfg, feats["train"].phys_xy_mm,
                                      drop_sites(s1.xy_mm[train]))
    k = 2 * len(forests) + 1
    w = np.r_[np.full(k - 1, 0.1), 1.0 - 0.1 * (k - 1)]
    with_stack = replace(model, three_channel_stack={"forests": forests, "weights": {1: w}})
    test_s = s1.subset(test)
    for c, moves in ((1, True), (2, False)):
        adc = inject_session(test_s, FaultSpec(dead_channel=c, noise=1, seed=c)).adc
        new, old = with_stack.predict(with_stack.featurize(adc)), model.predict(model.featurize(adc))
        rows = new["three_channel"]
        assert rows.mean() > 0.9
        moved = np.abs(new["xy_mm"][rows] - old["xy_mm"][rows]).max()
        assert (moved > 0.1) if moves else (moved == 0.0)
    clean = with_stack.featurize(test_s.adc)
    np.testing.assert_array_equal(with_stack.predict(clean)["xy_mm"], model.predict(clean)["xy_mm"])
    with_stack.save(tmp_path / "m")
    back = ImpactModel.load(tmp_path / "m")
    assert sorted(back.three_channel_stack["forests"]) == sorted(forests)
    dead = with_stack.featurize(inject_session(test_s.subset(np.arange(12)), FaultSpec(dead_channel=1)).adc)
    np.testing.assert_array_equal(with_stack.predict(dead)["xy_mm"], back.predict(dead)["xy_mm"])
    card_path = tmp_path / "m" / CARD_FILE
    card = json.loads(card_path.read_text())
    card["three_channel_position_stack"]["weights"]["1"] = [0.5, 0.5]
    card_path.write_text(json.dumps(card))
    with pytest.raises(DataError, match="three_channel_position_stack.weights"):
        ImpactModel.load(tmp_path / "m")
