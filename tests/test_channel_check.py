"""One channel against the other three without a site map (channel_check.py): a debonded disc's channel is found on
a model of any rig, no channel of an unchanged session is, and a flagged drop takes the three-sensor path."""

from dataclasses import replace

import numpy as np
import pytest

from impactsense import _core
from impactsense.channel_check import (EVENT_SCORE, RUN_EVENTS, RUN_SCORE, channel_scores, fit_channel_check,
                                       flagged_channel)
from impactsense.data import load_session
from impactsense.edge_travel import three_sensor_positions
from impactsense.faults import FaultSpec, inject_session
from impactsense.pipeline import featurize
from impactsense.signal import SignalConfig


@pytest.fixture(scope="module")
def fitted(session1):
    """(signal, check) fitted on every 4th session-1 drop, and the held-out drops between them."""
    cfg = SignalConfig.for_rig(session1.rig)
    train_rows = np.arange(0, len(session1), 4)
    train = featurize(session1.adc[train_rows], cfg)
    check = fit_channel_check(train.raw, cfg, train.phys_xy_mm, session1.xy_mm[train_rows])
    return cfg, check, session1.subset(np.arange(2, len(session1), 8))


def flags(session, cfg, check):
    f = featurize(session.adc, cfg)
    scores = channel_scores(f.raw, cfg, check, f.phys_xy_mm)
    return flagged_channel(scores, check), scores, f.phys_xy_mm


def test_the_check_is_fitted_and_clean_drops_score_low(fitted):
    """Training drops' scores (robust sd of their own residuals) stay well under the event threshold; held-out
    drops of the same session and of another session (session-2, with its channel-3 delay) flag nothing."""
    cfg, check, test = fitted
    assert check is not None and len(check["level"]) == len(check["tilt"]) == 4
    assert max(check["training_score_max"]) < EVENT_SCORE / 1.5
    bad, scores, _ = flags(test, cfg, check)
    assert np.all(bad == -1) and np.nanmax(scores) < EVENT_SCORE / 1.5
    s2 = load_session("bundled:session-2")
    bad2, _, _ = flags(s2.subset(np.arange(0, len(s2), 6)), cfg, check)
    assert np.all(bad2 == -1)


@pytest.mark.parametrize("channel", [0, 3])
def test_a_debonded_channel_is_flagged_on_every_drop(fitted, channel):
    cfg, check, test = fitted
    bad, scores, _ = flags(inject_session(test, FaultSpec(debond=channel, debond_hz=4000, seed=channel)), cfg, check)
    assert np.mean(bad == channel) >= 0.95
    others = np.delete(scores, channel, axis=1)
    assert np.nanmax(others) < RUN_SCORE   # the other three look stronger, not weaker (the mean they meet falls)


def with_gain_and_delay(test, gain: float, channel: int = 1, delayed: int = 2):
    """The session with one channel's signal about its baseline times `gain` and another's 20 us late."""
    adc = test.adc.astype(float)
    base = np.median(adc[:, channel, :64], axis=-1, keepdims=True)
    adc[:, channel] = base + gain * (adc[:, channel] - base)
    adc[:, delayed] = np.roll(adc[:, delayed], 2, axis=-1)   # 20 us late at 100 kHz
    return replace(test, adc=np.clip(np.rint(adc), 0, test.rig.adc_max).astype(test.adc.dtype))


def test_a_moderate_gain_change_or_a_delay_is_not_a_debond(fitted):
    """A gain moves the level only (the tilt is a ratio within the channel), a delay neither: x0.8 is not flagged."""
    cfg, check, test = fitted
    bad, _, _ = flags(with_gain_and_delay(test, 0.8), cfg, check)
    assert np.all(bad == -1)


def test_a_channel_far_weaker_than_the_rest_is_flagged_whatever_its_spectrum(fitted):
    """x0.3 without a low-pass (the level ~ -1 in log10 energy, tens of robust sd): flagged on the level alone."""
    cfg, check, test = fitted
    bad, _, _ = flags(with_gain_and_delay(test, 0.3), cfg, check)
    assert np.mean(bad == 1) >= 0.95


def test_the_three_sensor_positions_are_the_cores_with_the_channel_left_out(session1):
    cfg = SignalConfig.for_rig(session1.rig)
    cfg.band_pick_hz, cfg.band_window_us, cfg.band_velocity_mm_per_us = 17000.0, 1000.0, cfg.velocity_mm_per_us
    adc = session1.adc[::40]
    raw = featurize(adc, cfg).raw
    for c in (1, 2):
        left = SignalConfig.from_dict(cfg.to_dict())
        left.channel_left_out = [int(k == c) for k in range(4)]
        core = featurize(adc, left).phys_xy_mm
        ours = three_sensor_positions(raw, cfg, c)
        close = np.abs(core - ours).max(1) < 0.01
        assert close.mean() >= 0.95


def test_a_run_flags_a_channel_whose_scores_stay_between_the_thresholds():
    """Scores between RUN_SCORE and EVENT_SCORE flag once half a window of events shows them; a lone one does not."""
    check = {"event_score": EVENT_SCORE, "run_score": RUN_SCORE, "run_events": RUN_EVENTS}
    mid = 0.5 * (RUN_SCORE + EVENT_SCORE)
    scores = np.zeros((3 * RUN_EVENTS, 4))
    scores[:, 2] = mid
    bad = flagged_channel(scores, check)
    first = (RUN_EVENTS + 1) // 2 - 1
    assert np.all(bad[:first] == -1) and np.all(bad[first:] == 2)
    lone = np.zeros((3 * RUN_EVENTS, 4))
    lone[RUN_EVENTS, 1] = mid
    lone[2 * RUN_EVENTS, 3] = 2 * EVENT_SCORE
    bad = flagged_channel(lone, check)
    assert np.flatnonzero(bad >= 0).tolist() == [2 * RUN_EVENTS] and bad[2 * RUN_EVENTS] == 3
    unchecked = np.full((4, 4), np.nan)
    assert np.all(flagged_channel(unchecked, check) == -1)


def test_the_model_flags_the_channel_and_reports_the_three_sensor_answer(session1, tmp_path):
    """ImpactModel without a site map: the check in its card (saved and loaded), a debonded drop's position the
    three-sensor one and its class from the other three channels; the report flags the channel."""
    from impactsense.models import ForestSettings, ImpactModel
    from impactsense.workflow import channel_flags

    cfg = SignalConfig.for_rig(session1.rig)
    rows = np.arange(0, len(session1), 3)
    f = featurize(session1.adc[rows], cfg)
    model = ImpactModel.fit(f, session1.xy_mm[rows], session1.height_mm[rows], session1.rig.ball_mass_g, cfg,
                            ForestSettings(n_estimators=5), members=False)
    assert "channel_check" in model.card
    model.save(tmp_path / "m")
    back = ImpactModel.load(tmp_path / "m")
    test = session1.subset(np.arange(1, len(session1), 12))
    fd = featurize(inject_session(test, FaultSpec(debond=1, debond_hz=4000, seed=2)).adc, cfg)
    pred = back.predict(fd)
    assert np.mean(pred["bad_channel"] == 1) >= 0.95
    on = pred["bad_channel"] == 1
    np.testing.assert_allclose(pred["xy_mm"][on], three_sensor_positions(fd.raw, cfg, 1)[on])
    assert pred["three_channel"][on].all() and np.all(pred["energy_class"][on] >= 0)
    assert np.all(channel_flags(fd.flags, pred)[on, 1] & _core.FLAG_INCONSISTENT)
    clean = back.predict(featurize(test.adc, cfg))
    assert np.all(clean["bad_channel"] == -1) and not clean["three_channel"].any()
    # `impactsense evaluate`'s report counts them per channel
    from impactsense.workflow import evaluate
    debonded = inject_session(test, FaultSpec(debond=1, debond_hz=4000, seed=2))
    counts = evaluate(debonded, back, rows=np.arange(len(test)))["channels_left_out_inconsistent"]
    assert counts[1] >= 0.95 * len(test) and counts[0] == counts[2] == counts[3] == 0
    assert evaluate(test, back, rows=np.arange(len(test)))["channels_left_out_inconsistent"] == [0, 0, 0, 0]


def surface_drops(rng, n_sites: int, reps: int, plate=(1200.0, 800.0)):
    """A level ratio on sites of a plate: a surface a cubic does not describe (a sharp rise toward one corner, as
    beyond a sensor), a per-site misfit (sd 0.06) and a per-drop scatter (sd 0.02). (xy [R, 2], value [R], site [R])."""
    xy = np.repeat(rng.uniform((0, 0), plate, (n_sites, 2)), reps, 0)
    corner = np.exp(-np.hypot(plate[0] - xy[:, 0], xy[:, 1]) / 150.0)
    site_misfit = np.repeat(rng.normal(0, 0.06, n_sites), reps)
    return xy, 0.3 * corner + site_misfit + rng.normal(0, 0.02, len(xy)), np.repeat(np.arange(n_sites), reps)


def test_the_scale_on_few_sites_is_a_new_sites_spread():
    """With 24 sites of 4 drops (fewer than SITES_PER_TERM per term of the cubic) the cubic's own residuals
    understate the residuals at new sites (0.4-0.7 x on these draws); the check's scale (out of fold by site) is
    a new site's spread in the median over 12 draws (0.8-1.25 x; one draw's ranges 0.6-1.6 x). With 200 sites
    the scale is the in-sample one."""
    from types import SimpleNamespace

    from impactsense.channel_check import SITES_PER_TERM, _basis, check_scale, robust_sd

    plate = SimpleNamespace(plate_x_mm=1200.0, plate_y_mm=800.0)
    ours, own = [], []
    for seed in range(12):
        rng = np.random.default_rng(seed)
        xy, value, sites = surface_drops(rng, 24, 4)
        basis = _basis(xy, plate)
        assert 24 < SITES_PER_TERM * basis.shape[1]
        coef = np.linalg.lstsq(basis, value, rcond=None)[0]
        resid = value - basis @ coef
        scale, oof = check_scale(basis, value, resid, sites)
        assert oof
        new_xy, new_value, _ = surface_drops(rng, 2000, 1)
        new_sd = robust_sd(new_value - _basis(new_xy, plate) @ coef)
        ours.append(scale / new_sd)
        own.append(robust_sd(resid) / new_sd)
    assert 0.8 <= np.median(ours) <= 1.25 and np.median(own) < 0.65
    rng = np.random.default_rng(12)
    xy, value, sites = surface_drops(rng, 200, 4)
    basis = _basis(xy, plate)
    resid = value - basis @ np.linalg.lstsq(basis, value, rcond=None)[0]
    assert check_scale(basis, value, resid, sites) == (robust_sd(resid), False)


def test_a_check_fitted_on_few_sites_still_finds_a_debond_and_flags_no_clean_drop(session1):
    """Trained on the drops of 24 sites (all their repetitions, fewer than SITES_PER_TERM per term): the scales
    are out of fold by site, no clean drop of the other sites is flagged (by an event or the run rule over them
    in the recorded order) and a debonded channel still is on at least 0.95 of them."""
    from impactsense.channel_check import SITES_PER_TERM

    cfg = SignalConfig.for_rig(session1.rig)
    cases = np.unique(session1.case_id)
    picked = np.isin(session1.case_id, cases[::len(cases) // 24][:24])
    train = featurize(session1.adc[picked], cfg)
    check = fit_channel_check(train.raw, cfg, train.phys_xy_mm, session1.xy_mm[picked])
    assert max(check["n_sites"]) < SITES_PER_TERM * len(check["level"][0]["coef"])
    assert all(f["scale_out_of_fold"] for f in check["level"] + check["tilt"])
    test = session1.subset(np.flatnonzero(~picked)[::5])
    assert np.all(flags(test, cfg, check)[0] == -1)
    bad, _, _ = flags(inject_session(test, FaultSpec(debond=2, seed=5)), cfg, check)
    assert np.mean(bad == 2) >= 0.95
