import os

# One BLAS/OpenMP thread per process unless the caller says otherwise. The suite's linear algebra is small
# (GP fits of the site terms, least squares): on two shared cores a second BLAS thread mostly spins against
# the first and against the FEM's workers, several times the CPU for the same numbers (docs/findings.md,
# "The suite's time"). Set before numpy loads its BLAS, and in the environment so that the CLI subprocesses
# the tests start inherit it; threadpoolctl covers a BLAS already loaded.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

threadpool_limits(int(os.environ["OMP_NUM_THREADS"]))

from impactsense.data import load_session


@pytest.fixture(scope="session")
def session1():
    return load_session("bundled:session-1")


@pytest.fixture(scope="session")
def synth():
    """The synthetic_capture function below."""
    return synthetic_capture


@pytest.fixture(scope="session")
def band_on_subset(session1):
    """A function giving (rows, cfg, features) of every 8th session-1 drop with the core's band picks on (17 kHz,
    a 1 ms window, the threshold picks' velocity); a new cfg each call."""
    def make():
        from impactsense.pipeline import featurize
        from impactsense.signal import SignalConfig

        rows = np.arange(0, len(session1), 8)
        cfg = SignalConfig.for_rig(session1.rig)
        cfg.band_pick_hz = 17000.0
        cfg.band_window_us = 1000.0
        cfg.band_velocity_mm_per_us = cfg.velocity_mm_per_us
        return rows, cfg, featurize(session1.adc[rows], cfg)
    return make


def synthetic_capture(onsets, n=2000, amp=600.0, freq_hz=20000.0, fs_hz=100000.0, bias=2048, noise=0.0,
                      decay_per_s=800.0, seed=0):
    """4-channel uint16 capture: a decaying sine burst starting exactly at each channel's onset (samples)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs_hz
    out = np.empty((4, n))
    for c, t0 in enumerate(onsets):
        tau = t - t0 / fs_hz
        burst = np.where(tau >= 0, amp * np.sin(2 * np.pi * freq_hz * tau) * np.exp(-decay_per_s * tau), 0.0)
        out[c] = bias + burst + (rng.normal(0, noise, n) if noise else 0.0)
    return np.clip(np.round(out), 0, 4095).astype(np.uint16)


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory):
    """`impactsense demo --out DIR` run once, as the README's first command runs it (a subprocess of this
    Python): (DIR, its stdout). DIR holds the demo's model (session-1's split 0, 100 trees, the bundled twin's
    site map: what `impactsense train bundled` makes) and evaluate-session-1/2.json; tests that need that
    model read it from here instead of training it again."""
    import subprocess
    import sys

    out = tmp_path_factory.mktemp("demo") / "impactsense-demo"
    r = subprocess.run([sys.executable, "-m", "impactsense.cli", "demo", "--out", str(out)], capture_output=True,
                       text=True, timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
    return out, r.stdout


def exported_twin_match(features, signal, start_xy_mm=None, models_dir=None, **kw):
    """The core's twin_match_batch of every row with the twin an export ships (forest_tables.npz's "twin"; the
    shipped models/ unless models_dir): what the board's TableModels runs. start_xy_mm: the match's start per row
    (default the physics position; NaN rows: the three-sensor start). kw: twin_match_batch's keywords
    (full_search, weak_channel)."""
    from pathlib import Path

    from impactsense import _core
    from impactsense.export import load_tables

    models_dir = Path(models_dir) if models_dir else Path(__file__).resolve().parents[1] / "models"
    t = load_tables(models_dir / "forest_tables.npz")["twin"]
    nx, ny, x0, y0, step = t["grid"]
    f32 = lambda a: np.ascontiguousarray(np.asarray(a, np.float32))  # noqa: E731
    f = features
    start = f.phys_xy_mm if start_xy_mm is None else start_xy_mm
    return _core.twin_match_batch(
        np.ascontiguousarray(f.status, np.int32), np.ascontiguousarray(f.flags, np.uint8), f32(f.toa_us),
        f32(f.raw["window_energy"]), f32(f.raw["diff_energy"]), f32(f.phys_xy_mm), f32(start), signal.localiser(),
        np.asarray(t["q"], np.uint8).reshape(-1, 16), int(nx), int(ny), float(x0), float(y0), float(step),
        f32(t["base"]), f32(t["scale"]), f32(t["offset"]), f32(t["slope"]), f32(t["weight"]),
        *map(float, t["config"][:4]), float(t["uncertainty"][2]),   # ref height, prior, cutoff, temperature
        coarse_cutoff_mm=float(t["config"][4]), **kw)


def pytest_collection_modifyitems(config, items):
    """Tests whose data and fit come from the same model say so in their name (`_circular`, `_same_model`)
    and get the `circular` marker: `pytest -m "not circular"` runs only what counts as evidence."""
    for item in items:
        name = item.originalname if hasattr(item, "originalname") else item.name
        if name.endswith(("_circular", "_same_model")):
            item.add_marker(pytest.mark.circular)


@pytest.fixture(scope="session")
def board_site_map_20mm():
    """The bundled twin's site map as the board sees it (4 x 50 kHz) on a coarse 20 mm grid: made once for
    the suite (board.models.board_site_map, ~10-20 s) for the tests that export small twin models."""
    from impactsense.board.models import board_site_map
    from impactsense.sitemap import BUNDLED, SiteMap

    return board_site_map(SiteMap.load(BUNDLED), load_session("bundled").rig, 50000, step_mm=20.0, progress=False)


COARSE_DROPS = ([120.0, 210.0], [100.0, 230.0], [150.0, 110.0])   # x, y, height (mm) of two drops


@pytest.fixture(scope="session")
def coarse_plate_run():
    """(rig, params, volts) of the bundled rig's plate on a coarse 8 mm mesh, 3 ms, fast path, at COARSE_DROPS:
    the band-limited response the disc delay and disc bond tests transform."""
    from impactsense.data import bundled_session_path, load_rig
    from impactsense.sim import SimParams
    from impactsense.sim.simulate import simulate_voltages

    rig = load_rig(bundled_session_path())
    params = SimParams.from_rig(rig, element_mm=8.0, duration_ms=3.0, taper_ms=0.0, method="fast")
    return rig, params, simulate_voltages(params, rig, *COARSE_DROPS, workers=1)["volts"]


def small_board_export(tmp_path_factory, **train_kw):
    """A board-rate model without a twin (half of session-1's drops, 5 trees; train_kw to train_board_models),
    exported without m2cgen: (model folder, export folder, export summary, every other held-out drop)."""
    import json

    from impactsense.board.models import train_board_models
    from impactsense.data import load_session
    from impactsense.export import export_models
    from impactsense.models import ForestSettings

    s1 = load_session()
    sub = s1.subset(np.arange(0, len(s1), 2))
    d = train_board_models(sub, tmp_path_factory.mktemp("m") / "model", settings=ForestSettings(n_estimators=5),
                           **train_kw)
    out = tmp_path_factory.mktemp("export")
    summary = export_models(d, out, write_m2cgen=False)
    card = json.loads((d / "model_card.json").read_text())
    test = sub.subset(np.flatnonzero(np.isin(sub.recording_id, card["test_recording_ids"]))[::2])
    return d, out, summary, test
