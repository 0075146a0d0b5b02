"""Model export: the generated C (node tables and m2cgen per tree, float32) gives scikit-learn's
predictions on every session-1 drop."""

import re
import shutil
import subprocess

import numpy as np
import pytest

from impactsense.data import load_session
from impactsense.export import export_models, f32_floor, firmware_models, load_models

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def session_features():
    """The core's feature vectors of every session-1 drop (the trainer's featurize at 100 kHz)."""
    from impactsense.pipeline import SignalConfig, featurize

    s = load_session()
    f = featurize(s.adc, SignalConfig.for_rig(s.rig))
    return s, f


@pytest.fixture(scope="module")
def exported(tmp_path_factory, session_features):
    """`impactsense train`'s model type (residual x/y forests on feature subsets), small, on all drops."""
    from impactsense.models import ForestSettings, ImpactModel
    from impactsense.pipeline import SignalConfig

    s, f = session_features
    model = ImpactModel.fit(f, s.xy_mm, s.height_mm, s.rig.ball_mass_g, SignalConfig.for_rig(s.rig),
                            ForestSettings(n_estimators=15, min_samples_leaf=2))
    d = model.save(tmp_path_factory.mktemp("model"))
    out = tmp_path_factory.mktemp("export")
    summary = export_models(d, out)
    return d, out, summary


def test_float32_floor_keeps_sklearn_decisions():
    rng = np.random.default_rng(0)
    t = rng.normal(0, 100, 100000)
    lo = f32_floor(t)
    assert np.all(lo.astype(np.float64) <= t)
    hi = np.nextafter(lo, np.float32(np.inf))
    assert np.all(hi.astype(np.float64) > t)  # so for float32 x: x <= lo  <=>  x <= t


def test_tables_walker_matches_sklearn_on_every_drop(exported, session_features):
    from impactsense.models import ImpactModel

    model_dir, out, summary = exported
    _, f = session_features
    use = f.usable
    assert use.sum() > 700
    want = ImpactModel.load(model_dir).predict(f)
    fm, signal = firmware_models(out)
    got = fm.predict(f.vector, f.phys_xy_mm)
    np.testing.assert_array_equal(got[:, 3], use)  # the firmware runs the models exactly where the host does
    np.testing.assert_allclose(got[use, :2], want["xy_mm"][use], atol=2e-3)
    np.testing.assert_array_equal(got[use, 2], want["energy_class"][use])
    assert summary["residual_xy"] and signal["fs_hz"] == 100000
    n_inputs = sum(len(v) for v in summary["inputs"].values())
    assert summary["table_bytes_total"] == sum(7 * n for n in summary["nodes"].values()) + 4 * 45 + n_inputs


@pytest.mark.skipif(shutil.which("cc") is None, reason="no host C compiler")
def test_generated_c_matches_sklearn_on_every_drop(exported, session_features, tmp_path):
    model_dir, out, _ = exported
    _, f = session_features
    use = f.usable
    X = np.ascontiguousarray(f.vector[use], dtype=np.float32)
    m2c = (out / "impactsense_models_m2c.c").read_text()
    assert "double" not in m2c
    assert len(re.findall(r"^static float x_tree_\d+\(const float \* input\)", m2c, re.M)) == 15
    exe = tmp_path / "predict"
    subprocess.run(["cc", "-O2", "-std=c11", "-ffp-contract=off", f"-I{out}",
                    str(ROOT / "firmware/test/native/predict_main.c"), str(out / "impactsense_forest_tables.c"),
                    str(out / "impactsense_models_m2c.c"), "-o", str(exe)], check=True)
    res = subprocess.run([str(exe)], input=X.tobytes(), capture_output=True, check=True)
    got = np.loadtxt(res.stdout.decode().splitlines())
    assert got.shape == (len(X), 6)
    m = load_models(model_dir)
    want_x = m.x.predict(X[:, m.inputs["x"]])
    want_y = m.y.predict(X[:, m.inputs["y"]])
    want_p = m.energy.predict_proba(X[:, m.inputs["energy"]])[:, 1]
    for cols in ((0, 1, 2), (3, 4, 5)):  # node tables, m2cgen
        np.testing.assert_allclose(got[:, cols[0]], want_x, atol=1e-3)
        np.testing.assert_allclose(got[:, cols[1]], want_y, atol=1e-3)
        np.testing.assert_allclose(got[:, cols[2]], want_p, atol=1e-5)
        np.testing.assert_array_equal((got[:, cols[2]] > 0.5).astype(int),
                                      m.energy.predict(X[:, m.inputs["energy"]]))


def test_cli_export(exported, tmp_path):
    from impactsense.cli import main

    model_dir = exported[0]
    assert main(["export", str(model_dir), "--out", str(tmp_path / "m"), "--no-m2cgen", "--rate", "native"]) == 0
    assert (tmp_path / "m" / "impactsense_forest_tables.c").is_file()
    assert not (tmp_path / "m" / "impactsense_models_m2c.c").exists()


def test_export_rejects_incomplete_model_dir(tmp_path):
    from impactsense.export import ExportError

    (tmp_path / "model_card.json").write_text("{}")
    with pytest.raises(ExportError, match="no joblib model"):
        export_models(tmp_path, tmp_path / "out")
