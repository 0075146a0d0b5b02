"""The seed paper's figures, the reference the demo's tables print beside ours (one place for them).

SEED_ROWS: the seed's Tables 7-9 (docs/method.md, "The seed's results"): per model and region, (R2, RMSE mm,
MAE mm, energy-class accuracy) on the held-out drops; measured-trained models learnt from measured drops,
sim-trained ones from virtual drops of the calibrated twin only.
"""

from __future__ import annotations

SEED_ROWS = {
    "measured-trained, whole plate": (0.82, 30.0, 22.4, 0.78),
    "measured-trained, inner region": (0.90, 18.5, 14.9, 0.83),
    "sim-trained, whole plate": (0.81, 30.4, 22.4, 0.78),
    "sim-trained, inner region": (0.90, 20.1, 15.5, 0.78),
}
