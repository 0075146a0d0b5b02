"""Train/test split by case: every repetition of a case lands on the same side."""

from __future__ import annotations

import numpy as np


def case_split(case_id: np.ndarray, test_fraction: float, seed: int = 0,
               exclude_rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Row indices (train, test). About `test_fraction` of the cases (not drops) go to test.

    `exclude_rows` (e.g. calibration drops) are in neither set, and their cases are never tested.
    """
    case_id = np.asarray(case_id)
    if not 0.0 <= test_fraction < 1.0:
        raise ValueError(f"test fraction must be in [0, 1), got {test_fraction}")
    rows = np.arange(case_id.size)
    excluded = np.zeros(case_id.size, bool)
    if exclude_rows is not None and len(exclude_rows):
        excluded[np.asarray(exclude_rows)] = True
    cases = np.unique(case_id)
    blocked = np.unique(case_id[excluded])
    candidates = np.setdiff1d(cases, blocked)
    rng = np.random.default_rng(seed)
    n_test = int(round(test_fraction * cases.size))
    n_test = min(n_test, candidates.size)
    test_cases = rng.choice(candidates, size=n_test, replace=False) if n_test else np.array([], int)
    is_test = np.isin(case_id, test_cases) & ~excluded
    return rows[~is_test & ~excluded], rows[is_test]
