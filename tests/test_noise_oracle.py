"""bench_noise_oracle's training data: the reference drops with the session generator's own white noise at the true
level, independent draws per copy, labels tiled (a few drops, nothing trained)."""

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_noise_oracle  # noqa: E402

def _reference(tmp_path, n=4):
    from impactsense.data import load_session, resolve_session_path, rig_from_dict, write_session

    rig = rig_from_dict(json.loads((resolve_session_path("bundled:session-1") / "rig.json").read_text()))
    rng = np.random.default_rng(0)
    adc = np.full((n, 4, rig.samples), rig.bias_counts, float) + rng.normal(0.0, 1.5, (n, 4, rig.samples))
    adc = np.rint(adc).astype(np.uint16)
    case = np.arange(n) // 2
    return load_session(write_session(tmp_path / "ref", rig, 100.0 + 10 * case, 120.0 + 5 * case,
                                      np.full(n, 150.0), adc, case, np.arange(n) % 2))


def test_oracle_training_adds_the_true_white_level_with_independent_draws(tmp_path):
    ref = _reference(tmp_path)
    truth = {"effect": "noise", "sensor": None, "params": {"noise_counts_rms": 8.0}}
    tr = bench_noise_oracle.oracle_training(ref, truth, 3, 12, tmp_path / "oracle")
    n = len(ref)
    assert len(tr) == 3 * n
    assert np.array_equal(tr.case_id, np.tile(ref.case_id, 3)) and np.allclose(tr.x_mm, np.tile(ref.x_mm, 3))
    assert len({(c, r) for c, r in zip(tr.case_id, tr.repetition)}) == 3 * n   # every copy its own repetition
    added = [np.asarray(tr.adc[j * n:(j + 1) * n], float) - np.asarray(ref.adc, float) for j in range(3)]
    for a in added:   # the level within 2 % (80,000 samples a copy: the rms's own sd is ~0.3 %)
        assert abs(np.sqrt(np.mean(a ** 2)) - 8.0) < 0.16
    r = np.corrcoef(added[0].ravel(), added[1].ravel())[0, 1]
    assert abs(r) < 0.02   # independent draws, not one draw copied
