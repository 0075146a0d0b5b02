"""The band picks chosen by the forests' out-of-fold positions (band_forests.py) and the one-standard-error rule
they share with the correction's factor (correction_scale.choose_by_gain): the default (band picks off) unless the
alternative's per-site gain is clear."""

import numpy as np
import pytest

from impactsense.correction_scale import CORRECTION_GAIN_SIGMAS, choose_by_gain


def _errors(gain_mean, gain_spread, n_sites=40, reps=2, seed=0):
    """Per-drop errors of a default and an alternative at n_sites sites (reps drops each): the alternative's
    per-site gain is gain_mean +- gain_spread (alternating signs: its mean is gain_mean exactly)."""
    rng = np.random.default_rng(seed)
    sites = np.repeat(np.arange(n_sites), reps)
    default = rng.uniform(5.0, 9.0, n_sites)[sites]
    other = default - (gain_mean + gain_spread * (-1.0) ** np.arange(n_sites))[sites]
    return [default, other], sites


def test_a_clear_gain_takes_the_alternative():
    # 1 mm better on the mean, +-1 mm per site: about 6 standard errors
    err, sites = _errors(1.0, 1.0)
    chosen, mae, z = choose_by_gain(err, sites, 0)
    assert chosen == 1 and z > CORRECTION_GAIN_SIGMAS and mae[1] < mae[0]


def test_a_lower_but_noisy_mean_keeps_the_default():
    # 0.2 mm better on the mean with +-4 mm per site: well inside one standard error (0.64 mm)
    err, sites = _errors(0.2, 4.0)
    chosen, mae, z = choose_by_gain(err, sites, 0)
    assert mae[1] < mae[0] and chosen == 0 and z < CORRECTION_GAIN_SIGMAS


def test_the_default_index_is_kept_when_it_is_best():
    err, sites = _errors(-1.0, 1.0)
    assert choose_by_gain(err, sites, 0)[0] == 0
    # the factor rule's default is the last option (the whole correction)
    assert choose_by_gain(err[::-1], sites, 1)[0] == 1


@pytest.mark.slow
def test_training_without_a_site_map_records_the_band_choice(session1):
    """A measured session trained without a site map: the card says what the forests' folds chose, and the
    model's signal has the band picks exactly when the card says so (the rule: on only with a clear gain)."""
    from impactsense.models import ForestSettings
    from impactsense.workflow import train

    rows = np.arange(0, len(session1), 5)
    keep = np.setdiff1d(np.arange(len(session1)), rows)
    model, _ = train(session1, None, 0.0, 0, exclude_rows=keep, settings=ForestSettings(n_estimators=20),
                     choose_class=True)
    choice = model.card["band_choice"]
    assert choice["band_on"] == (float(model.signal.band_velocity_mm_per_us) > 0)
    assert choice["tried"]   # the drops are at enough sites for the folds
    off, on = choice["out_of_fold_mae_mm"]
    assert choice["band_on"] == (on < off and choice["gain_sigmas"] > CORRECTION_GAIN_SIGMAS)
    assert 0 < off < 20 and 0 < on < 20
