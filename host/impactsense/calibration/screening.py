"""Factor screening by Welch's t-test (docs/method.md): main effects and two-factor interactions.

Main effect of factor i: runs split at the median of x_i into low and high halves; effect = mean(y | high)
- mean(y | low), significance by Welch's unequal-variance t-test. Interaction i x j: runs split by the sign
of (x_i - med_i)(x_j - med_j) (the +1 / -1 column of a two-level design); effect = mean(y | +) - mean(y | -).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import ttest_ind


def welch_screen(x: np.ndarray, y: np.ndarray, names) -> list[dict]:
    med = np.median(x, axis=0)
    s = np.where(x > med, 1.0, -1.0)
    rows = []
    d = x.shape[1]

    def one(term, sign):
        hi, lo = y[sign > 0], y[sign < 0]
        if len(hi) < 2 or len(lo) < 2:
            return
        t, p = ttest_ind(hi, lo, equal_var=False)
        rows.append({"term": term, "effect": float(hi.mean() - lo.mean()), "t": float(t), "p": float(p)})

    for i in range(d):
        one(names[i], s[:, i])
    for i in range(d):
        for j in range(i + 1, d):
            one(f"{names[i]} x {names[j]}", s[:, i] * s[:, j])
    n_tests = len(rows)
    for r in rows:
        r["significant"] = bool(r["p"] < 0.05 / n_tests)   # Bonferroni over all terms
    return sorted(rows, key=lambda r: -abs(r["t"]))


def screening_chart(results: dict, path, top: int = 15):
    """Bar chart of |t| for the strongest terms of each output (like the seed's Fig. 10)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(results), figsize=(6.5 * len(results), 5.5))
    axes = np.atleast_1d(axes)
    for ax, (label, rows) in zip(axes, results.items()):
        rows = rows[:top][::-1]
        colours = ["tab:red" if r["significant"] else "tab:gray" for r in rows]
        ax.barh([r["term"].replace("pzt_", "") for r in rows], [abs(r["t"]) for r in rows], color=colours)
        ax.set_xlabel("|t| (Welch)  — red: significant (Bonferroni 5 %)")
        ax.set_title(f"factor screening: {label}")
        ax.tick_params(axis="y", labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
