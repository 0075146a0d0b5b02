"""The position members' stack (member_stack.py): when one member is much closer to the truth than the others, the
training drops' out-of-fold positions keep a weighted sum that leans on it; members that are alike keep the mean; a
member that did not place a drop reads the mean there; the model reports the stack's weighted sum and refuses a
damaged one (docs/findings.md "Session 20: travelpick")."""

import json

import numpy as np
import pytest

from impactsense.errors import DataError
from impactsense.member_stack import MEAN, choose_stack, stack_ok, stacked_position
from impactsense.position_members import joined_position, mean_of_members


def _sites(n_sites=40, reps=2, seed=0):
    rng = np.random.default_rng(seed)
    return rng, np.repeat(rng.uniform(0, 400, (n_sites, 2)), reps, axis=0), np.repeat(np.arange(n_sites), reps)


def _member(rng, xy, sd, site_sd=0.0, sites=None):
    """(corrected, base) positions: the truth plus per-drop scatter sd and a per-site bias site_sd (mm)."""
    bias = 0.0 if not site_sd else rng.normal(0, site_sd, (sites.max() + 1, 2))[sites]
    corrected = xy + bias + rng.normal(0, sd, xy.shape)
    return corrected, corrected + rng.normal(0, sd, xy.shape)


def test_one_good_member_gets_the_weight():
    # a member (a travel field's, say) without the per-site bias the other three share in part: the mean dilutes it
    rng, xy, sites = _sites()
    each = {"main": _member(rng, xy, 2.0, 6.0, sites), "a": _member(rng, xy, 1.0),
            "b": _member(rng, xy, 2.0, 6.0, sites), "c": _member(rng, xy, 2.0, 6.0, sites)}
    stack = choose_stack(each, mean_of_members(each)[0], xy, sites)
    assert stack["keep"], stack
    assert sum(w for n, w in stack["weights"].items() if n.startswith("a")) > 0.7, stack
    assert stack["out_of_fold_mae_mm"][1] < 0.7 * stack["out_of_fold_mae_mm"][0]
    assert abs(sum(stack["weights"].values()) - 1.0) < 1e-3


def test_alike_members_keep_the_mean():
    # four members with independent scatter of the same size: their mean is the best weighting there is
    rng, xy, sites = _sites(seed=1)
    each = {name: _member(rng, xy, 4.0) for name in ("main", "a", "b", "c")}
    stack = choose_stack(each, mean_of_members(each)[0], xy, sites)
    assert not stack["keep"], stack


def test_too_few_sites_or_one_member_no_stack():
    rng, xy, sites = _sites(n_sites=4)
    each = {name: _member(rng, xy, 4.0) for name in ("main", "a")}
    assert choose_stack(each, mean_of_members(each)[0], xy, sites) is None
    rng, xy, sites = _sites()
    each = {"main": _member(rng, xy, 4.0)}
    assert choose_stack(each, mean_of_members(each)[0], xy, sites) is None


def test_a_member_that_did_not_place_a_drop_reads_the_mean():
    rng, xy, _ = _sites(n_sites=5)
    each = {"main": _member(rng, xy, 2.0), "a": _member(rng, xy, 2.0)}
    each["a"][0][:3] = np.nan
    mean = mean_of_members(each)[0]
    got = stacked_position(each, mean, {"a": 0.8, "main@base": 0.2})
    np.testing.assert_allclose(got[:3], 0.8 * mean[:3] + 0.2 * each["main"][1][:3])
    np.testing.assert_allclose(got[3:], 0.8 * each["a"][0][3:] + 0.2 * each["main"][1][3:])
    # a member the rows do not have at all: its weight goes to the mean
    np.testing.assert_allclose(stacked_position(each, mean, {"gone": 1.0}), mean)


class _Shift:
    def __init__(self, v):
        self.v = v

    def predict(self, X):
        return np.full(len(X), self.v)


def test_the_model_join_reports_the_stack():
    names = ["phys_x_mm", "phys_y_mm", "f0"]
    phys = np.array([[100.0, 100.0], [200.0, 50.0]])
    X = np.column_stack([phys, [0.0, 1.0]])
    base = phys + 3.0
    members = {"band_field": (_Shift(1.0), _Shift(-1.0))}
    mean, _ = joined_position(phys + 2.0, phys, members, X, None, {"band_field": base}, names)
    np.testing.assert_allclose(mean, ((phys + 2.0) + (base + [1.0, -1.0])) / 2)
    stack = {"keep": True, "weights": {"band_field@base": 0.75, MEAN: 0.25}}
    got, _ = joined_position(phys + 2.0, phys, members, X, None, {"band_field": base}, names, stack)
    np.testing.assert_allclose(got, 0.75 * base + 0.25 * mean)
    got, _ = joined_position(phys + 2.0, phys, members, X, None, {"band_field": base}, names, {**stack, "keep": False})
    np.testing.assert_allclose(got, mean)


def test_a_damaged_stack_is_refused(session1, tmp_path):
    good = {"keep": True, "weights": {"mean": 0.2, "main@base": 0.3, "band_field": 0.5}}
    assert stack_ok(good, ["band_field"])
    assert not stack_ok(good, [])                                        # a member the model does not have
    assert not stack_ok({**good, "weights": {"mean": -0.1, "main": 1.1}}, [])
    assert not stack_ok({**good, "weights": {"mean": float("nan")}}, [])
    assert not stack_ok({**good, "weights": {"mean": True}}, [])
    assert not stack_ok({"keep": "yes", "weights": {"mean": 1.0}}, [])
    assert not stack_ok({"keep": True, "weights": {}}, [])

    from impactsense.models import ForestSettings, ImpactModel
    from impactsense.pipeline import featurize
    from impactsense.signal import SignalConfig

    rows = np.arange(0, len(session1), 12)
    cfg = SignalConfig.for_rig(session1.rig)
    model = ImpactModel.fit(featurize(session1.adc[rows], cfg), session1.xy_mm[rows], session1.height_mm[rows],
                            session1.rig.ball_mass_g, cfg, ForestSettings(n_estimators=5), members=False)
    model.save(tmp_path / "m")
    card_path = tmp_path / "m" / "model_card.json"
    card = json.loads(card_path.read_text())
    card["member_stack"] = {"keep": True, "weights": {"threshold_field": 1.0}}   # not among its members
    card_path.write_text(json.dumps(card))
    with pytest.raises(DataError, match="member_stack"):
        ImpactModel.load(tmp_path / "m")
