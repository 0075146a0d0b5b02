"""The reported position's uncertainty (uncertainty_mm, host and board) is a calibrated 1-sigma radial error:
u = sqrt(E r^2), r the distance of the reported position from the truth (twin.py). For a 2-D Gaussian error
P(r <= u) = 1 - exp(-1) = 0.63 and P(r <= 2u) = 1 - exp(-4) = 0.98; so on drops the model never saw about
63 % of the errors must lie within 1x and nearly all within 2x. The twin match's raw spread does not: it
covers ~97 % at 1x (it reads about twice too wide)."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from impactsense.data import load_session
from impactsense.errors import DataError
from impactsense.models import ForestSettings, ImpactModel
from impactsense.pipeline import SignalConfig, featurize, fit_localiser
from impactsense.sitemap import BUNDLED, SiteMap
from impactsense.split import case_split
from impactsense.twin import TwinFit, calibrated_uncertainty, fit_uncertainty

TARGET = 1.0 - np.exp(-1.0)   # P(r <= u) for a 2-D Gaussian, u = sqrt(E r^2)
TOL = 0.1                     # ~2 binomial sd at 155 drops of 31 cases (repetitions are correlated)


def coverage(err, u, k=1.0):
    ok = np.isfinite(err) & np.isfinite(u)
    return float(np.mean(err[ok] <= k * u[ok]))


def test_fit_uncertainty_recovers_a_known_calibration():
    """Radial errors drawn with E r^2 = ((1 + 0.3 s) * sqrt(max(1, m / mean m)))^2: the maximum-likelihood fit
    finds a, b and the misfit reference, and its u covers 63 % of fresh draws."""
    rng = np.random.default_rng(0)
    n = 4000
    s = rng.uniform(2.0, 8.0, n)
    m = rng.gamma(4.0, 0.1, n)
    true_u = (1.0 + 0.3 * s) * np.sqrt(np.maximum(1.0, m / m.mean()))
    draw = lambda: true_u * np.sqrt(rng.chisquare(2, n) / 2.0)   # noqa: E731  Rayleigh, E r^2 = u^2
    r = draw()
    r[:10] = np.nan                                               # events without an estimate are ignored
    got = fit_uncertainty(s, m, r)
    assert got["uncertainty_misfit_ref"] == pytest.approx(m[10:].mean())   # of the events with an error
    assert got["uncertainty_offset_mm"] == pytest.approx(1.0, abs=0.25)
    assert got["uncertainty_scale"] == pytest.approx(0.3, abs=0.06)
    fit = TwinFit(offset=[0.0] * 16, slope=[0.0] * 16, weight=[1.0] * 16, ref_log10_height_mm=2.0, **got)
    u = calibrated_uncertainty(fit, s, m)
    assert coverage(draw(), u) == pytest.approx(TARGET, abs=0.03)
    # an event whose energies fit 4x worse than the training events' mean gets twice the uncertainty
    np.testing.assert_allclose(calibrated_uncertainty(fit, [5.0], [4 * got["uncertainty_misfit_ref"]]),
                               2 * calibrated_uncertainty(fit, [5.0], [0.0]))
    with pytest.raises(DataError, match="out-of-fold"):
        fit_uncertainty(s[:10], m[:10], r[10:20])


def test_a_card_without_the_calibration_reports_the_raw_spread():
    fit = TwinFit.from_dict({"offset": [0.0] * 16, "slope": [0.0] * 16, "weight": [1.0] * 16,
                             "ref_log10_height_mm": 2.0})
    np.testing.assert_allclose(calibrated_uncertainty(fit, [3.0, 7.0], [0.4, 9.0]), [3.0, 7.0])


@pytest.fixture(scope="module")
def demo_model():
    """The demo's split (session-1, seed 0) and a twin model on its training cases; session-2's features."""
    s = load_session()
    train, test = case_split(s.case_id, 0.2, 0)
    cfg = fit_localiser(s, train, SignalConfig.for_rig(s.rig))
    f = featurize(s.adc, cfg)
    model = ImpactModel.fit(f.take(train), s.xy_mm[train], s.height_mm[train], s.rig.ball_mass_g, cfg,
                            ForestSettings(n_estimators=50), site_map=SiteMap.load(BUNDLED))
    s2 = load_session("bundled:session-2")
    return model, {"demo": (f.take(test), s.xy_mm[test]), "session-2": (featurize(s2.adc, cfg), s2.xy_mm)}


def predicted(model, feats, xy):
    p = model.predict(feats)
    return p, np.linalg.norm(p["xy_mm"] - xy, axis=1)


def test_uncertainty_is_a_calibrated_1_sigma_on_held_out_cases(demo_model, tmp_path):
    """Held-out cases of session-1: 0.63 +- 0.1 of the errors within 1x (0.63 with 100 trees; 0.56-0.77 over
    10 case splits), >= 90 % within 2x, mean (r / u)^2 near 1; the raw spread covers >= 90 % at 1x."""
    model, sets = demo_model
    p, err = predicted(model, *sets["demo"])
    u = p["uncertainty_mm"]
    assert np.isfinite(u).sum() >= 150
    assert coverage(err, u) == pytest.approx(TARGET, abs=TOL)
    assert coverage(err, u, 2.0) >= 0.9
    ok = np.isfinite(err) & np.isfinite(u)
    assert 0.6 <= np.mean((err[ok] / u[ok]) ** 2) <= 1.5
    assert coverage(err, p["twin_spread_mm"]) >= 0.9      # the uncalibrated spread is no 1-sigma
    # the constants live in the model card and a loaded model reports the same
    model.save(tmp_path / "m")
    assert model.card["twin"]["uncertainty_scale"] == model.twin_fit.uncertainty_scale
    np.testing.assert_allclose(ImpactModel.load(tmp_path / "m").predict(sets["demo"][0])["uncertainty_mm"], u,
                               rtol=1e-9)


def test_uncertainty_grows_where_the_rig_changed(demo_model):
    """Session-2 (a later day; channel 3 reads a further 7.4 us early, unknown to the session-1 model) errs
    twice as far (rms 4.8 against 2.4 mm). The calibration cannot know that; the misfit's Birge ratio (the
    events' energies fit the twin about twice worse) widens u: 1x coverage 0.33 -> 0.46, 2x 0.70 -> 0.88 with
    50 trees. The 0.63 target is missed here at 100 kHz (met on the board, test below)."""
    model, sets = demo_model
    p, err = predicted(model, *sets["session-2"])
    plain = calibrated_uncertainty(replace(model.twin_fit, uncertainty_misfit_ref=0.0), p["twin_spread_mm"], 0.0)
    assert coverage(err, p["uncertainty_mm"]) >= coverage(err, plain) + 0.08
    assert coverage(err, p["uncertainty_mm"]) >= 0.4
    assert coverage(err, p["uncertainty_mm"], 2.0) >= 0.8


def test_shipped_board_model_reports_a_1_sigma_on_session_2():
    """The firmware app with the shipped tables (models/, all of session-1 at the board's rate) on session-2's
    160 drops, as the emulated board reports them: 0.63 +- 0.1 of the errors within the reported uncertainty
    (0.64), >= 90 % within 2x (0.96)."""
    from impactsense.export import firmware_models
    from impactsense.board.scores import board_reports
    models, signal = firmware_models(Path(__file__).resolve().parents[1] / "models")
    s2 = load_session("bundled:session-2")
    got = board_reports(s2, models, signal)
    rows = np.asarray(sorted(got))
    assert rows.size >= 155
    err = np.hypot(*(np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in rows]) - s2.xy_mm[rows]).T)
    u = np.array([got[i]["uncertainty_mm"] for i in rows])
    assert coverage(err, u) == pytest.approx(TARGET, abs=TOL)
    assert coverage(err, u, 2.0) >= 0.9
