"""The energy class from a linear estimate of log m g h (height_class.py): the out-of-fold rule picks it where
the drops' log energy is linear in the energy features and a cubic in position and keeps the classifier forest
where it is not; the model folder stays data-only; the board's form (the node-table arrays, linear_terms in the
emulator, the generated C) classifies every drop as the host does."""

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from impactsense.errors import DataError
from impactsense.height_class import (LINEAR_CLASS_FEATURES, LinearHeightClass, energy_class_choice,
                                      fit_linear_height_class, linear_tables, linear_tables_score,
                                      out_of_fold_classes)
from impactsense.models import ForestSettings

ROOT = Path(__file__).resolve().parents[1]
HEIGHTS_MM = np.arange(50.0, 301.0, 10.0)


def synthetic_drops(linear: bool, seed: int = 0):
    """120 positions x 3 repetitions on a 400 x 300 mm plate, heights from 26 levels. Five "energy" columns
    and the position. linear: each energy = log h + a smooth cubic site factor + 2 % noise (the linear model's
    own form). Not linear: the energies carry log h only through a fold the linear model cannot follow
    (|log h - mean|, with the sign in a sixth-order interaction of the position), which a forest can split."""
    rng = np.random.default_rng(seed)
    n_pos, reps = 120, 3
    pos = np.c_[rng.uniform(20, 380, n_pos), rng.uniform(20, 280, n_pos)]
    h = rng.choice(HEIGHTS_MM, n_pos)
    xy = np.repeat(pos, reps, axis=0)
    log_h = np.log(np.repeat(h, reps))
    u, v = (xy[:, 0] - 200) / 200, (xy[:, 1] - 150) / 150
    site = 0.3 * u - 0.2 * v + 0.25 * u * v - 0.3 * u ** 3 + 0.1 * v ** 2
    if linear:
        base = log_h + site
    else:
        centred = log_h - np.log(HEIGHTS_MM).mean()
        base = np.abs(centred) + 0.4 * (centred > 0.3)     # a fold and a step: not linear in log h
    E = np.stack([base + a * site + rng.normal(0, 0.02, len(xy)) for a in (0.0, 0.2, -0.1, 0.3, 0.1)], axis=1)
    X = np.c_[E, xy]                                         # LINEAR_CLASS_FEATURES' order
    energy_j = 0.0082 * 9.81 * np.exp(log_h) * 1e-3
    return X, energy_j, xy


@pytest.mark.parametrize("linear", [True, False])
def test_rule_picks_the_linear_estimate_only_where_log_energy_is_linear(linear):
    X, energy_j, xy = synthetic_drops(linear)
    oof = out_of_fold_classes(X, X, energy_j, xy, ForestSettings(n_estimators=40, seed=0))
    choice = energy_class_choice(oof)
    assert choice["n_drops"] == len(X)
    assert choice["use_linear"] == linear
    if linear:   # 2 % noise against a 10 mm (>= 3.3 % in log) height step: the linear model is nearly exact
        assert choice["linear_class_accuracy"] >= 0.97
    else:        # the fold: the linear estimate cannot tell the low and the high drops apart
        assert choice["forest_class_accuracy"] >= choice["linear_class_accuracy"] + 0.1


def test_linear_model_file_round_trip_and_refuses_a_damaged_file(tmp_path):
    X, energy_j, _ = synthetic_drops(True)
    thr = float(np.percentile(energy_j, 75))
    model = fit_linear_height_class(X, energy_j, thr)
    assert model.n_features_in_ == len(LINEAR_CLASS_FEATURES) and len(model.terms) == 5 + 9
    # the estimate is log(m g h), its rms error at the 2 % noise level; the class is the estimate against the cut
    assert np.sqrt(np.mean((model.log_energy(X) - np.log(energy_j)) ** 2)) < 0.03
    np.testing.assert_array_equal(model.predict(X), (model.log_energy(X) > model.cut_log_energy_j).astype(int))
    model.save(tmp_path / "m.npz")
    back = LinearHeightClass.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(back.predict(X), model.predict(X))
    z = dict(np.load(tmp_path / "m.npz"))
    z["terms"] = np.full_like(z["terms"], 9)          # a factor beyond the inputs
    np.savez(tmp_path / "bad.npz", **z)
    with pytest.raises(DataError, match="beyond n_inputs"):
        LinearHeightClass.load(tmp_path / "bad.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(DataError, match="not a linear class file"):
        LinearHeightClass.load(tmp_path / "junk.npz")
    # the board's float32 arithmetic over the node-table arrays decides as the host's float64
    s32 = linear_tables_score(linear_tables(model), X)
    clear = np.abs(model.score(X)) > 1e-4
    np.testing.assert_array_equal((s32[clear] > 0).astype(int), model.predict(X)[clear])


@pytest.fixture(scope="module")
def linear_model_export(tmp_path_factory):
    """A small `impactsense train`-type model of session-1's first 240 drops whose energy class is the linear
    estimate, saved and exported."""
    from impactsense.data import load_session
    from impactsense.export import export_models
    from impactsense.models import ImpactModel, columns, impact_energy_j
    from impactsense.pipeline import SignalConfig, featurize

    s = load_session()
    rows = np.arange(240)
    cfg = SignalConfig.for_rig(s.rig)
    f = featurize(s.adc[rows], cfg)
    model = ImpactModel.fit(f, s.xy_mm[rows], s.height_mm[rows], s.rig.ball_mass_g, cfg,
                            ForestSettings(n_estimators=5, min_samples_leaf=3), members=False)
    use = f.usable
    X = f.vector[use][:, columns(LINEAR_CLASS_FEATURES)]
    model.forest_energy = fit_linear_height_class(X, impact_energy_j(s.height_mm[rows][use], s.rig.ball_mass_g),
                                                  model.energy_threshold_j)
    model.energy_class_features = list(LINEAR_CLASS_FEATURES)
    d = model.save(tmp_path_factory.mktemp("model"))
    out = tmp_path_factory.mktemp("export")
    summary = export_models(d, out)
    return d, out, summary, f


def test_linear_model_folder_loads_and_the_emulator_classifies_as_the_host(linear_model_export):
    from impactsense.export import firmware_models
    from impactsense.modelfolder import read_card
    from impactsense.models import ImpactModel

    d, out, summary, f = linear_model_export
    card, _ = read_card(d)
    assert card["energy_model"] == "linear" and card["files"]["energy"] == "linear_energy.npz"
    assert not any(p.suffix in (".pkl", ".joblib") for p in Path(d).iterdir())
    model = ImpactModel.load(d)
    assert isinstance(model.forest_energy, LinearHeightClass)
    want = model.predict(f)
    assert summary["energy_model"] == "linear" and summary["trees"]["energy"] == 14
    assert "#define IMPACTSENSE_ENERGY_LINEAR 1" in (out / "impactsense_models.h").read_text()
    fm, _ = firmware_models(out)
    got = fm.predict(f.vector, f.phys_xy_mm, np.ascontiguousarray(f.raw["window_energy"], np.float32),
                     np.ascontiguousarray(f.raw["diff_energy"], np.float32), np.ascontiguousarray(f.flags, np.uint8),
                     np.ascontiguousarray(f.raw["energy"], np.float32))
    ran = f.usable
    assert ran.sum() > 200
    np.testing.assert_array_equal(got[:, 3], ran)
    np.testing.assert_array_equal(got[ran, 2], want["energy_class"][ran])
    assert 0 < want["energy_class"][ran].mean() < 1           # both classes occur


@pytest.mark.skipif(shutil.which("cc") is None, reason="no host C compiler")
def test_generated_c_of_a_linear_model_classifies_as_the_host(linear_model_export, tmp_path):
    """The generated C of the linear estimate, both forms: its node-table arrays (impactsense_forest_tables.c,
    read as impactapp::linear_terms reads them) and its function (impactsense_models_m2c.c)."""
    from impactsense.export import load_models

    d, out, _, f = linear_model_export
    m2c = (out / "impactsense_models_m2c.c").read_text()
    assert "double" not in m2c and re.search(r"^float impactsense_m2c_energy\(const float\* input\)", m2c, re.M)
    use = f.usable
    X = np.ascontiguousarray(np.c_[f.vector[use], np.full(use.sum(), np.nan)], dtype=np.float32)
    exe = tmp_path / "predict"
    subprocess.run(["cc", "-O2", "-std=c11", "-ffp-contract=off", f"-I{out}",
                    str(ROOT / "firmware/test/native/predict_main.c"), str(out / "impactsense_forest_tables.c"),
                    str(out / "impactsense_models_m2c.c"), "-o", str(exe)], check=True)
    got = np.loadtxt(subprocess.run([str(exe)], input=X.tobytes(), capture_output=True,
                                    check=True).stdout.decode().splitlines())
    m = load_models(d)
    Xe = X[:, m.inputs["energy"]]
    score = m.energy.score(Xe)
    clear = np.abs(score) > 1e-4
    for col in (2, 5):   # the node tables (the driver's copy of linear_terms), the generated function
        np.testing.assert_allclose(got[:, col] - 0.5, score, atol=1e-4)
        np.testing.assert_array_equal((got[clear, col] > 0.5).astype(int), m.energy.predict(Xe)[clear])
