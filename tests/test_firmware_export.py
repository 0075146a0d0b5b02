"""Model export: the generated C (node tables and m2cgen per tree, float32) gives scikit-learn's
predictions on every session-1 drop."""

import re
import shutil
import subprocess

import numpy as np
import pytest
from sklearn.ensemble import RandomForestClassifier, RandomForestRegressor

from impactsense import _core, _link
from impactsense.data import load_session
from impactsense.export import export_models, f32_floor, firmware_models, load_models

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def session_features():
    s = load_session()
    cfg = _core.CoreConfig()
    cfg.fs_hz = float(s.rig.fs_hz)
    X, status = _link.feature_vector_batch(np.ascontiguousarray(s.adc.astype(np.int16)), cfg)
    assert np.all(np.isfinite(X))
    return s, X


@pytest.fixture(scope="module")
def exported(tmp_path_factory, session_features):
    import joblib
    import json

    s, X = session_features
    d = tmp_path_factory.mktemp("model")
    e = s.rig.ball_mass_g * s.height_mm
    cls = (e >= np.percentile(e, 75)).astype(int)
    kw = dict(n_estimators=15, random_state=0, min_samples_leaf=2)
    joblib.dump(RandomForestRegressor(**kw).fit(X, s.x_mm), d / "rf_x.joblib")
    joblib.dump(RandomForestRegressor(**kw).fit(X, s.y_mm), d / "rf_y.joblib")
    joblib.dump(RandomForestClassifier(**kw).fit(X, cls), d / "rf_energy.joblib")
    (d / "model_card.json").write_text(json.dumps({"features": "test"}))  # roles found by type and name
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
    model_dir, out, summary = exported
    _, X = session_features
    m = load_models(model_dir)
    p = firmware_models(out).predict(X)
    np.testing.assert_allclose(p[:, 0], m.x.predict(X), atol=1e-3)
    np.testing.assert_allclose(p[:, 1], m.y.predict(X), atol=1e-3)
    np.testing.assert_array_equal(p[:, 2], m.energy.predict(X))
    assert summary["table_bytes_total"] == sum(7 * n for n in summary["nodes"].values()) + 4 * 45


@pytest.mark.skipif(shutil.which("cc") is None, reason="no host C compiler")
def test_generated_c_matches_sklearn_on_every_drop(exported, session_features, tmp_path):
    model_dir, out, _ = exported
    _, X = session_features
    m2c = (out / "impactsense_models_m2c.c").read_text()
    assert "double" not in m2c
    assert len(re.findall(r"^static float x_tree_\d+\(const float \* input\)", m2c, re.M)) == 15
    exe = tmp_path / "predict"
    subprocess.run(["cc", "-O2", "-std=c11", "-ffp-contract=off", f"-I{out}",
                    str(ROOT / "firmware/test/native/predict_main.c"), str(out / "impactsense_forest_tables.c"),
                    str(out / "impactsense_models_m2c.c"), "-o", str(exe)], check=True)
    res = subprocess.run([str(exe)], input=X.astype(np.float32).tobytes(), capture_output=True, check=True)
    got = np.loadtxt(res.stdout.decode().splitlines())
    assert got.shape == (len(X), 6)
    m = load_models(model_dir)
    want_x, want_y, want_p = m.x.predict(X), m.y.predict(X), m.energy.predict_proba(X)[:, 1]
    for cols in ((0, 1, 2), (3, 4, 5)):  # node tables, m2cgen
        np.testing.assert_allclose(got[:, cols[0]], want_x, atol=1e-3)
        np.testing.assert_allclose(got[:, cols[1]], want_y, atol=1e-3)
        np.testing.assert_allclose(got[:, cols[2]], want_p, atol=1e-5)
        np.testing.assert_array_equal((got[:, cols[2]] > 0.5).astype(int), m.energy.predict(X))


def test_cli_export(exported, tmp_path):
    from impactsense.cli import main

    model_dir = exported[0]
    assert main(["export", str(model_dir), "--out", str(tmp_path / "m"), "--no-m2cgen"]) == 0
    assert (tmp_path / "m" / "impactsense_forest_tables.c").is_file()
    assert not (tmp_path / "m" / "impactsense_models_m2c.c").exists()


def test_export_rejects_incomplete_model_dir(tmp_path):
    from impactsense.export import ExportError

    (tmp_path / "model_card.json").write_text("{}")
    with pytest.raises(ExportError, match="no joblib model"):
        export_models(tmp_path, tmp_path / "out")
