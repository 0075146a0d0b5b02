"""A drop with one channel without an onset (dead, disconnected) on a model without a site map: its position
is the physics localiser's three-sensor one, and its energy class comes from the other three channels' energies
(height_class.fit_three_channel_classes: height_class's linear estimate of log m g h, one per channel left out)."""

import numpy as np
import pytest

from impactsense.data import load_session
from impactsense.faults import FaultSpec, inject_session
from impactsense.models import ForestSettings, ImpactModel
from impactsense.workflow import evaluate, train


@pytest.fixture(scope="module")
def measured_model():
    s1 = load_session()
    model, split = train(s1, None, 0.2, 0, settings=ForestSettings(n_estimators=20, seed=0), site_map=None)
    return s1.subset(np.asarray(split["test_recordings"], int)[::2]), model


@pytest.mark.parametrize("channel", [0, 2])
def test_a_dead_channel_still_gets_an_energy_class(measured_model, channel):
    """>= 90 % of the drops get a class (all of them when the other three channels have their onsets) and
    the class is as right as the four-channel one within 0.1 (the three channels carry ~3/4 of the energy)."""
    test, model = measured_model
    assert model.site_map is None and set(model.three_channel_class) == {0, 1, 2, 3}
    clean = evaluate(test, model, rows=np.arange(len(test)))
    dead = evaluate(inject_session(test, FaultSpec(dead_channel=channel, noise=1)), model, rows=np.arange(len(test)))
    assert dead["classified"] >= 0.9 * dead["n"]
    assert dead["energy_class_accuracy"] >= clean["energy_class_accuracy"] - 0.1


def test_the_three_channel_class_is_saved_with_its_checksum_and_loads_the_same(measured_model, tmp_path):
    test, model = measured_model
    model.save(tmp_path / "m")
    back = ImpactModel.load(tmp_path / "m")
    dead = inject_session(test, FaultSpec(dead_channel=3, noise=1))
    from impactsense.pipeline import featurize
    f = featurize(dead.adc, model.signal)
    assert np.array_equal(model.predict(f)["energy_class"], back.predict(f)["energy_class"])
    # a replaced file is refused, naming it
    from impactsense.errors import DataError
    (tmp_path / "m" / "linear_energy_without_3.npz").write_bytes(
        (tmp_path / "m" / "linear_energy_without_0.npz").read_bytes())
    with pytest.raises(DataError, match="linear_energy_without_3"):
        ImpactModel.load(tmp_path / "m")


def test_a_channel_left_out_by_the_core_is_localised_and_classified_as_a_dead_one(measured_model):
    """The core's channel_left_out (retrain's answer to a change the models cannot absorb): the channel gets no
    onset, the drop the physics three-sensor position a dead channel gets (the same three picks) and a class."""
    from dataclasses import replace

    from impactsense import _core
    from impactsense.commands.retrain import leave_out
    from impactsense.pipeline import featurize

    test, model = measured_model
    test = test.subset(np.arange(0, len(test), 3))
    left = replace(model, signal=leave_out(model.signal, [2]))
    f_left = featurize(test.adc, left.signal)
    f_dead = featurize(inject_session(test, FaultSpec(dead_channel=2)).adc, model.signal)
    assert np.all(f_left.flags[:, 2] & _core.FLAG_NO_ONSET)
    assert not np.any(f_left.flags[:, [0, 1, 3]] & _core.FLAG_NO_ONSET)
    np.testing.assert_allclose(f_left.phys_xy_mm, f_dead.phys_xy_mm, atol=0.05)
    pred = left.predict(f_left)
    assert pred["three_channel"].all() and np.all(pred["energy_class"] >= 0)
    # nothing left out: the features are the rig's own, bit for bit
    f_none = featurize(test.adc, leave_out(model.signal, []))
    np.testing.assert_array_equal(f_none.vector, featurize(test.adc, model.signal).vector)
