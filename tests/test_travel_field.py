"""Each channel's travel residual as a smooth field (travel_field.py): fitted from drops at known positions it recovers
a per-channel late arrival that no shared basis holds, the localiser on the picks less the field places held-out
drops closer to the truth, fields fitted out of fold do not see their own drops, and a damaged card's field is
refused (docs/findings.md "Session 19: anyrig")."""

import numpy as np

from impactsense.edge_travel import _localise
from impactsense.travel_field import (MIN_SITES, field_at, field_positions, fields_ok, fit_fields,
                                      out_of_fold_positions)

from test_edge_travel import SX, SY, V, plate   # the same test plate (four sensors off the corners)


def late_us(xy):
    """A per-channel smooth lateness (us): channel 0 late toward the plate's right, channel 2 toward the bottom,
    channel 1 with a bump in the middle, channel 3 none (each disc's own: no basis shared by the four holds it)."""
    x, y = xy[:, 0], xy[:, 1]
    return np.stack([6.0 * x / 450.0, 5.0 * np.exp(-((x - 225) ** 2 + (y - 175) ** 2) / (2 * 90.0 ** 2)),
                     6.0 * (1 - y / 350.0), np.zeros(len(x))], 1)


def drops(n, seed, noise_us=0.5):
    rng = np.random.default_rng(seed)
    xy = np.round(rng.uniform([10.0, 10.0], [440.0, 340.0], (n, 2)), 1)
    d = np.hypot(xy[:, None, 0] - np.array(SX)[None], xy[:, None, 1] - np.array(SY)[None])
    toa = 100.0 + rng.normal(0, 20, (n, 1)) + d / V + late_us(xy) + rng.normal(0, noise_us, (n, 4))
    raw = {"toa_us": toa.astype(np.float32), "flags": np.zeros((n, 4), np.uint8),
           "pick_period": np.full((n, 4), np.nan, np.float32)}
    return raw, xy


def test_field_recovers_each_channels_lateness():
    cfg = plate()
    raw, xy = drops(120, 1)
    fields = fit_fields(raw, xy, cfg)
    assert set(fields) == {"threshold"}    # the band picks are off
    test_xy = np.random.default_rng(2).uniform([40, 40], [410, 310], (200, 2))
    got, want = field_at(fields["threshold"], test_xy), late_us(test_xy)
    err = (got - got.mean(1, keepdims=True)) - (want - want.mean(1, keepdims=True))
    spread = want - want.mean(1, keepdims=True)
    assert np.sqrt(np.mean(err ** 2)) < 0.25 * np.sqrt(np.mean(spread ** 2))


def test_positions_on_the_picks_less_the_field_are_closer():
    cfg = plate()
    raw, xy = drops(120, 3)
    fields = fit_fields(raw, xy, cfg)
    raw_t, xy_t = drops(100, 4)
    before = _localise(raw_t, cfg, "threshold", np.zeros((100, 4)))
    after = field_positions(raw_t, cfg, fields)["threshold_field"]
    e0, e1 = np.nanmean(np.abs(before - xy_t)), np.nanmean(np.abs(after - xy_t))
    assert e1 < 0.5 * e0 and e0 > 2.0


def test_out_of_fold_positions_do_not_see_their_own_drops():
    cfg = plate()
    raw, xy = drops(100, 5)
    sites = np.arange(100)
    oof = out_of_fold_positions(raw, xy, cfg, sites)["threshold_field"]
    inside = field_positions(raw, cfg, fit_fields(raw, xy, cfg))["threshold_field"]
    # fitted on the drops it places, the field also takes their noise: out of fold is the honest (larger) error
    assert np.isfinite(oof).all()
    assert np.mean(np.abs(oof - xy)) > np.mean(np.abs(inside - xy))


def test_too_few_sites_no_field_and_a_damaged_field_refused():
    cfg = plate()
    raw, xy = drops(MIN_SITES - 1, 6)
    assert fit_fields(raw, xy, cfg) == {}
    raw, xy = drops(60, 7)
    fields = fit_fields(raw, xy, cfg)
    assert fields_ok(fields)
    bad = {"threshold": {**fields["threshold"], "alpha": fields["threshold"]["alpha"][:2]}}
    assert not fields_ok(bad)
    assert not fields_ok({"threshold": {**fields["threshold"], "length_mm": [-1.0] * 4}})
    assert not fields_ok({"other": fields["threshold"]})
