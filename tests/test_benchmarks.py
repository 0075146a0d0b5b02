"""`pytest -m bench`: every benchmark with a stated target (benchmarks/run_all.py CHECKED), each a test that
fails when its script exits non-zero (a missed target). Not in the default suite (pyproject addopts); the
table of all of them: `python3 benchmarks/run_all.py`."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import run_all  # noqa: E402


@pytest.mark.bench
@pytest.mark.parametrize("name", sorted(run_all.CHECKED))
def test_benchmark_meets_its_target(name):
    r = run_all.run(name, run_all.CHECKED[name])
    assert r["rc"] == 0, r["output"][-3000:]
