"""loop_sessions' oracles (the reference's drops recorded with a changed session's change) and bench_bond_floor's
measured transfer (a bond channel's spectrum against its control's on the same drops). Spec lists and synthetic
records only: nothing simulated."""

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import loop_sessions  # noqa: E402


def test_an_oracle_is_the_references_drops_with_the_changed_sessions_truth():
    specs = loop_sessions.spec_list(12)
    ref = next(s for s in specs if s["name"] == "ref")
    oracles = {s["oracle_of"]: s for s in loop_sessions.oracle_specs(specs)}
    changed = [s for s in specs if s.get("truth")]
    assert set(oracles) == {s["name"] for s in changed}          # one per changed session, none for same-k
    for s in changed:
        o = oracles[s["name"]]
        assert o["seed"] == ref["seed"] and o["truth"] == s["truth"] and o["kind"] == s["kind"]
        assert o["name"] == f"{s['name']}-oracle"
    assert set(o["oracle_of"] for o in loop_sessions.oracle_specs(specs, {"bond"})) == {"bond"}


def test_the_measured_transfer_reads_back_a_one_pole_bond():
    import bench_bond_floor

    fs, n, fc, g = 100_000.0, 4096, 3000.0, 0.7
    rng = np.random.default_rng(0)
    clean = rng.normal(size=(40, 1, n)) * np.hanning(n)          # broadband drops on one channel
    f = np.fft.rfftfreq(2 * n, 1.0 / fs)                         # the analogue one-pole, applied exactly
    bonded = np.fft.irfft(np.fft.rfft(clean, 2 * n) * g / (1.0 + 1j * f / fc), 2 * n)[..., :n]
    rig = SimpleNamespace(fs_hz=fs)
    as_session = lambda x: SimpleNamespace(adc=1000.0 * x, rig=rig)   # noqa: E731
    _, h, fc_fit, g_fit = bench_bond_floor.measured_transfer(as_session(bonded), as_session(clean), 0)
    assert abs(fc_fit / fc - 1.0) < 0.03 and abs(g_fit / g - 1.0) < 0.02
    # and a plain gain is no low-pass: its corner runs to the top of the band
    _, _, fc_gain, g_gain = bench_bond_floor.measured_transfer(as_session(0.5 * clean), as_session(clean), 0)
    assert abs(g_gain - 0.5) < 0.01 and fc_gain > 10 * fc
