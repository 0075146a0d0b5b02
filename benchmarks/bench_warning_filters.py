"""How often a threaded forest's fit + predict leaves the process's warning filters changed (the race that
makes scikit-learn print "`sklearn.utils.parallel.delayed` should be used with ..." on every later task):
scikit-learn's own forest against impactsense's (host/impactsense/threaded_forests.py).

    python benchmarks/bench_warning_filters.py [--calls 400] [--trees 20]

Prints, for each kind, the calls after which `warnings.filters` was another list than before the call (a
worker's re-applied copy: the same filters with their module patterns compiled) and those after which it had
lost filters (shorter: the harmful case; empty, every later task warns). The list is put back after each
detection, so every call starts from the same filters.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
from sklearn.ensemble import RandomForestRegressor

from impactsense.threaded_forests import ThreadedForestRegressor


def changed_calls(kind, calls: int, trees: int) -> tuple[int, int]:
    rng = np.random.default_rng(0)
    X = rng.random((200, 5))
    y = X[:, 0]
    before = list(warnings.filters)
    changed = lost = 0
    for i in range(calls):
        kind(trees, n_jobs=2, random_state=i).fit(X, y).predict(X)
        if list(warnings.filters) != before:
            changed += 1
            lost += len(warnings.filters) < len(before)
            warnings.filters[:] = before
    return changed, lost


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=400)
    ap.add_argument("--trees", type=int, default=20)
    a = ap.parse_args()
    for name, kind in (("scikit-learn RandomForestRegressor", RandomForestRegressor),
                       ("impactsense ThreadedForestRegressor", ThreadedForestRegressor)):
        changed, lost = changed_calls(kind, a.calls, a.trees)
        print(f"{name}: of {a.calls} calls, {changed} left another filter list, {lost} one with filters lost")


if __name__ == "__main__":
    main()
