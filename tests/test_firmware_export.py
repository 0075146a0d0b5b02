"""Model export: the generated C (node tables and m2cgen per tree, float32) gives scikit-learn's
predictions on every session-1 drop, for the energy classifier on summed energies and for the one on the
twin's height estimate (site map and twin configuration exported with the forests)."""

import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from impactsense.data import load_session
from impactsense.export import export_models, f32_floor, firmware_models, load_models, load_tables
from impactsense.export_c import _leaf_values

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def session_features():
    """The core's feature vectors of every session-1 drop (the trainer's featurize at 100 kHz)."""
    from impactsense.pipeline import SignalConfig, featurize

    s = load_session()
    f = featurize(s.adc, SignalConfig.for_rig(s.rig))
    return s, f


@pytest.fixture(scope="module", params=["summed", "twin"])
def exported(request, tmp_path_factory, session_features):
    """`impactsense train`'s model type (residual x/y forests on feature subsets), small, on all drops; the
    energy class on the summed energies or on the bundled twin's site map."""
    from impactsense.models import ForestSettings, ImpactModel
    from impactsense.pipeline import SignalConfig
    from impactsense.sitemap import BUNDLED, SiteMap

    s, f = session_features
    site = SiteMap.load(BUNDLED) if request.param == "twin" else None
    model = ImpactModel.fit(f, s.xy_mm, s.height_mm, s.rig.ball_mass_g, SignalConfig.for_rig(s.rig),
                            ForestSettings(n_estimators=15, min_samples_leaf=2), site_map=site, twin_edge=True)
    d = model.save(tmp_path_factory.mktemp("model"))
    out = tmp_path_factory.mktemp("export")
    summary = export_models(d, out)
    return d, out, summary


def energies(f):
    """What the twin and the three-channel classes read of each event (EventFeatures): window energies,
    difference energies, flags, channel energies."""
    return (np.ascontiguousarray(f.raw["window_energy"], np.float32),
            np.ascontiguousarray(f.raw["diff_energy"], np.float32), np.ascontiguousarray(f.flags, np.uint8),
            np.ascontiguousarray(f.raw["energy"], np.float32))


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
    model = ImpactModel.load(model_dir)
    want = model.predict(f)
    fm, signal = firmware_models(out)
    assert fm.has_twin == (model.site_map is not None)
    got = fm.predict(f.vector, f.phys_xy_mm, *energies(f))
    ran = use & (want["energy_class"] >= 0)
    assert ran.sum() >= use.sum() - 2
    np.testing.assert_array_equal(got[:, 3], ran)  # the firmware runs the models exactly where the host does
    np.testing.assert_allclose(got[ran, :2], want["xy_mm"][ran], atol=2e-3)
    # A twin model's position on the board is the twin's matched one, as on the host, not the forests'.
    moved = np.abs(got[ran, :2] - want["forest_xy_mm"][ran]).max()
    assert (moved > 1.0) if model.site_map is not None else (moved < 2e-3)
    np.testing.assert_array_equal(got[ran, 2], want["energy_class"][ran])
    assert summary["residual_xy"] and signal["fs_hz"] == 100000
    n_inputs = sum(len(v) for v in summary["inputs"].values())
    n_trees = sum(summary["trees"].values())
    twin_bytes = 0
    if model.site_map is not None:
        # the twin's height estimate carries its edge term (twin_edge.py, twin_edge=True), so the board's class above
        # applied it too
        assert model.twin_fit.edge_ramp_mm > 0 and model.twin_fit.edge_log10_bias != 0
        assert summary["inputs"]["energy"] == [len(f.vector[0])]  # the twin's estimate: one past the vector
        site = model.site_map
        twin_bytes = site.nx * site.ny * 16 + 4 * (5 * 16 + 5 + 6 + 3 + 4)  # q; base, scale, offset, slope, weight;
        # grid; config (ref height, prior, cutoff, temperature, coarse cutoff, weak channel); uncertainty (offset,
        # scale, misfit_ref); edge term (bias, ramp, plate x, y)
        assert summary["trees"]["energy"] == 25 and summary["nodes"]["energy"] <= 3 * 25  # stumps
    # without a twin the three-channel classes (height_class.linear_tables per channel: T = 14 terms, 7 inputs;
    # roots, factors, coef + bias + offset and scale per input, no child or leaf arrays)
    three_bytes = 0 if model.site_map is not None else 4 * (4 * 14 + 3 * 14 + 4 * (14 + 1 + 2 * 7))
    assert summary["table_bytes"].get("three_channel", 0) == three_bytes
    # without a twin the channel check: per channel two cubics (10 coefficients, median, scale) and 5 values
    check_bytes = 0 if model.site_map is not None else 2 * 4 * 12 * 4 + 6 * 4
    assert summary["table_bytes"].get("channel_check", 0) == check_bytes
    # forest.h's layout: 7 B a split node, 2 B a leaf (one more leaf than split nodes a tree), 4 B a distinct leaf
    # value (with min_samples_leaf=1 a regression leaf is one training drop's target: far fewer values than leaves)
    t = load_tables(out / "forest_tables.npz")
    splits = {r: t[r]["feature"].size for r in ("x", "y", "energy")}
    distinct = {r: t[r]["leaf_value"].size for r in ("x", "y", "energy")}
    assert all(t[r]["leaf"].size == splits[r] + summary["trees"][r] for r in splits)
    assert summary["nodes"] == {r: 2 * splits[r] + summary["trees"][r] for r in splits}
    assert all(0 < distinct[r] <= t[r]["leaf"].size for r in splits)
    assert summary["table_bytes_total"] == (sum(7 * splits[r] + 2 * (splits[r] + summary["trees"][r]) + 4 * distinct[r]
                                                for r in splits) + 4 * (n_trees + len(splits))   # roots: one past the last tree
                                            + n_inputs + twin_bytes + three_bytes + check_bytes)


@pytest.mark.parametrize("exported", ["summed"], indirect=True)
def test_single_leaf_trees_and_damaged_tables(exported, session_features):
    """forest.h's layout for a tree that is one leaf (a constant target): one split node whose two children are
    that leaf, walked by the firmware app like any tree; tables whose walk could leave a tree are refused."""
    from sklearn.ensemble import RandomForestRegressor

    from impactsense import _link
    from impactsense.export import forest_tables

    _, f = session_features
    t = load_tables(exported[1] / "forest_tables.npz")
    spec = {r: {k: v.tolist() for k, v in t[r].items()} for r in ("x", "y", "energy")}
    const = forest_tables(RandomForestRegressor(n_estimators=3, random_state=0).fit(f.vector[:50, :2], np.full(50, 1.5)))
    assert const["feature"].size == 3 and const["leaf"].size == 6 and const["leaf_value"].tolist() == [1.5]
    x = {**{k: v.tolist() for k, v in const.items()}, "inputs": [0, 1]}
    got = _link.ForestModels(x, spec["y"], spec["energy"], True).predict(f.vector, f.phys_xy_mm, *energies(f))
    ran = got[:, 3] > 0
    assert ran.sum() > 700
    np.testing.assert_allclose(got[ran, 0] - f.phys_xy_mm[ran, 0], 1.5, atol=1e-4)
    damaged = [("skip", 0, 0), ("skip", 0, len(spec["y"]["feature"])), ("feature", 0, len(spec["y"]["inputs"])),
               ("leaf", 0, len(spec["y"]["leaf_value"])), ("roots", -1, len(spec["y"]["feature"]) - 1),
               ("roots", 1, 0)]
    for key, i, v in damaged:
        bad = {k: list(a) for k, a in spec["y"].items()}
        bad[key][i] = v
        with pytest.raises(ValueError, match="forest"):
            _link.ForestModels(spec["x"], bad, spec["energy"], True)


@pytest.mark.parametrize("exported", ["twin"], indirect=True)
def test_firmware_walker_needs_the_twin_for_a_twin_model(exported):
    """A forest that reads the twin's estimate without a site map is refused (and so is one for x or y)."""
    from impactsense import _link

    t = load_tables(exported[1] / "forest_tables.npz")
    spec = {r: {k: v.tolist() for k, v in t[r].items()} for r in ("x", "y", "energy")}
    assert t["twin"] is not None
    with pytest.raises(ValueError, match="twin"):
        _link.ForestModels(spec["x"], spec["y"], spec["energy"], True)
    with pytest.raises(ValueError, match="twin"):
        _link.ForestModels(spec["energy"], spec["y"], spec["energy"], True)
    twin = {k: v.tolist() for k, v in t["twin"].items()}
    twin["q"] = twin["q"][:-1]
    with pytest.raises(ValueError, match="q needs"):
        _link.ForestModels(spec["x"], spec["y"], spec["energy"], True, twin)


@pytest.mark.skipif(shutil.which("cc") is None, reason="no host C compiler")
def test_generated_c_matches_sklearn_on_every_drop(exported, session_features, tmp_path):
    from impactsense.models import ImpactModel

    model_dir, out, _ = exported
    _, f = session_features
    pred = ImpactModel.load(model_dir).predict(f)
    use = f.usable & (pred["energy_class"] >= 0)
    # The feature vector and the twin's log10 height estimate (the energy classifier's input of a twin model).
    est = np.log10(pred["height_mm"][use]) if "height_mm" in pred else np.full(use.sum(), np.nan)
    X = np.ascontiguousarray(np.c_[f.vector[use], est], dtype=np.float32)
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
    np.testing.assert_array_equal((got[:, 2] > 0.5).astype(int), pred["energy_class"][use])
    # The node tables give exactly the float32 mean of scikit-learn's leaves, summed tree by tree in float32
    # (the leaf each tree reaches and its value are scikit-learn's; only the sum's rounding is the board's).
    for col, role in enumerate(("x", "y", "energy")):
        forest = getattr(m, role)
        Xr = X[:, m.inputs[role]]
        s = np.zeros(len(X), np.float32)
        for est in forest.estimators_:
            s = (s + _leaf_values(est.tree_, role == "energy").astype(np.float32)[est.apply(Xr)]).astype(np.float32)
        np.testing.assert_array_equal(got[:, col].astype(np.float32), s / np.float32(len(forest.estimators_)))


def test_cli_export(exported, tmp_path, capsys):
    from impactsense.cli import main

    model_dir = exported[0]
    assert main(["export", str(model_dir), "--out", str(tmp_path / "m"), "--no-m2cgen", "--rate", "native"]) == 0
    # the last line names each budget it judges: the flash (the exit status) and the event estimate, never one
    # "within budget" for both
    last = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    est = json.loads((tmp_path / "m" / "export.json").read_text()).get("event_instructions_estimate")
    assert last["within_flash_budget"] is True and "within_budget" not in last
    from impactsense.export_check import event_verdict, within_event_budget

    # every export has an estimate; the JSON line's verdict is export.json's: true ok, false OVER, null near
    done = json.loads((tmp_path / "m" / "export.json").read_text())
    assert done["event_verdict"] == event_verdict(est) in ("ok", "near", "OVER")
    assert last["within_event_budget"] == within_event_budget(est) == {"ok": True, "OVER": False,
                                                                        "near": None}[done["event_verdict"]]
    assert (tmp_path / "m" / "impactsense_forest_tables.c").is_file()
    assert not (tmp_path / "m" / "impactsense_models_m2c.c").exists()
    # --trees auto picks the prefix on the reported position's error: the twin's match for a twin model.
    sweep = json.loads((tmp_path / "m" / "export.json").read_text())["tree_sweep"]
    twin = "twin" in json.loads((model_dir / "model_card.json").read_text())
    assert sweep and all(("forest_mean_distance_mm" in r) == twin for r in sweep)
    # ... and never more trees than a budget allows: the flash, and for a twin model the per-event cycles.
    from impactsense.export import TWIN_MAX_TREES

    chosen = json.loads((tmp_path / "m" / "export.json").read_text())["trees"]["x"]
    assert next(r for r in sweep if r["trees"] == chosen)["within_budgets"]
    if twin:
        assert all(r["within_budgets"] == (r["trees"] <= TWIN_MAX_TREES) for r in sweep)
    else:   # the forests, the energy forest's prefix with them, within what the event budget leaves (board.cost)
        from impactsense.board.cost import EVENT_BUDGET

        done = json.loads((tmp_path / "m" / "export.json").read_text())
        est = done["event_instructions_estimate"]
        left = EVENT_BUDGET - (est["base"] + est["band"] + est["localiser"])
        assert all(r["within_budgets"] <= (r["instructions"] <= left) for r in sweep)
        assert [r["instructions"] for r in sweep] == sorted(r["instructions"] for r in sweep)
        assert done["trees"]["energy"] == min(chosen, 15) and est["total"] <= EVENT_BUDGET


def test_export_rejects_incomplete_model_dir(tmp_path):
    from impactsense.export import ExportError

    (tmp_path / "model_card.json").write_text("{}")
    # a card without its list of model files names the field, and nothing is loaded from the folder
    with pytest.raises(ExportError, match=r"model_card\.json \[files\]"):
        export_models(tmp_path, tmp_path / "out")
