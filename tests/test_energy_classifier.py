"""The measured-trained energy classifier without a site map: what it reads, saved and loaded by its card."""

import json

import numpy as np
import pytest

from impactsense.errors import DataError
from impactsense.models import ENERGY_FEATURES, MEASURED_ENERGY_FEATURES, ForestSettings, ImpactModel
from impactsense.pipeline import featurize
from impactsense.signal import SignalConfig


@pytest.fixture(scope="module")
def no_twin_model(session1):
    rows = np.arange(0, len(session1), 5)
    cfg = SignalConfig.for_rig(session1.rig)
    feats = featurize(session1.adc[rows], cfg)
    model = ImpactModel.fit(feats, session1.xy_mm[rows], session1.height_mm[rows], session1.rig.ball_mass_g, cfg,
                            ForestSettings(n_estimators=15))
    return model, feats, session1.height_mm[rows]


def test_the_classifier_reads_each_channels_energies_and_first_peaks(no_twin_model):
    model, feats, height = no_twin_model
    assert model.energy_features == MEASURED_ENERGY_FEATURES
    assert set(ENERGY_FEATURES) < set(MEASURED_ENERGY_FEATURES)
    assert sum(n.startswith("log_first_peak_") for n in MEASURED_ENERGY_FEATURES) == 4
    assert model.forest_energy.n_features_in_ == len(MEASURED_ENERGY_FEATURES)
    # in-sample it separates the drops above the 75th-percentile energy from the rest
    label = (height >= np.percentile(height, 75)).astype(int)
    assert np.mean(model.predict(feats)["energy_class"] == label) > 0.9


def test_saved_card_lists_them_and_a_card_without_the_list_reads_the_legacy_set(no_twin_model, tmp_path):
    model, feats, _ = no_twin_model
    model.save(tmp_path / "m")
    card = json.loads((tmp_path / "m" / "model_card.json").read_text())
    assert card["energy_features"] == MEASURED_ENERGY_FEATURES
    again = ImpactModel.load(tmp_path / "m")
    assert np.array_equal(again.predict(feats)["energy_class"], model.predict(feats)["energy_class"])
    # a card from before the list: the classifier was trained on ENERGY_FEATURES, and a forest of another
    # width is refused with the card's field named
    del card["energy_features"]
    (tmp_path / "m" / "model_card.json").write_text(json.dumps(card))
    with pytest.raises(DataError, match="energy_features"):
        ImpactModel.load(tmp_path / "m")
