"""Where the virtual drops fall: the lab's design of experiments, for the simulator.

Sobol (x, y, h) points (scipy.stats.qmc, scrambled): x, y at least `edge_mm` inside the plate's edges and
`clearance_mm` from every sensor centre (never on a disc: at least the disc's radius plus the ball's plus
1 mm), h in 5 mm steps over `heights_mm` (lo, hi): the calibrated session's measured range
(`measured_heights`), else 100 to 200 mm like the bundled lab's drops. Points are drawn in powers of two (the Sobol
sequence's balanced blocks) and the first n that pass are kept, so a seed gives the same drops every time.
`impactsense simulate-dataset` and the zero-shot's virtual set both use it."""

from __future__ import annotations

import numpy as np

from ..errors import ConfigError


DEFAULT_HEIGHTS_MM = (100.0, 200.0)
HEIGHT_STEP_MM = 5.0


def measured_heights(session) -> tuple[float, float]:
    """(lo, hi) of a session's known drop heights on the 5 mm grid; DEFAULT_HEIGHTS_MM when none is known."""
    h = np.asarray(session.height_mm, float)
    h = h[np.isfinite(h) & (h > 0)]
    if h.size == 0:
        return DEFAULT_HEIGHTS_MM
    lo = max(HEIGHT_STEP_MM, HEIGHT_STEP_MM * np.floor(h.min() / HEIGHT_STEP_MM))
    hi = max(lo, HEIGHT_STEP_MM * np.ceil(h.max() / HEIGHT_STEP_MM))
    return float(lo), float(hi)


def virtual_drops(rig, n: int, seed: int = 0, edge_mm: float = 20.0, clearance_mm: float = 25.0,
                  heights_mm: tuple[float, float] = DEFAULT_HEIGHTS_MM):
    """(x_mm, y_mm, height_mm), each [n]."""
    from scipy.stats import qmc

    lo, hi = (float(v) for v in heights_mm)
    if not (0 < lo <= hi):
        raise ConfigError(f"drop heights {lo:g}..{hi:g} mm: need 0 < lo <= hi")
    steps = int(round((hi - lo) / HEIGHT_STEP_MM)) + 1
    if n < 1:
        raise ConfigError(f"--n must be >= 1, got {n}")
    if not (0 <= edge_mm < min(rig.plate_x_mm, rig.plate_y_mm) / 2):
        raise ConfigError(f"--edge-mm {edge_mm} leaves no plate")
    sob = qmc.Sobol(d=3, scramble=True, seed=seed)
    pts = np.empty((0, 3))
    while pts.shape[0] < n:
        u = sob.random(1 << int(np.ceil(np.log2(max(2 * n, 2)))))
        x = edge_mm + u[:, 0] * (rig.plate_x_mm - 2 * edge_mm)
        y = edge_mm + u[:, 1] * (rig.plate_y_mm - 2 * edge_mm)
        h = lo + HEIGHT_STEP_MM * np.minimum(np.floor(u[:, 2] * steps), steps - 1)
        d = np.hypot(x[:, None] - rig.sensor_x_mm, y[:, None] - rig.sensor_y_mm).min(axis=1)
        ok = d >= max(clearance_mm, rig.sensor_diameter_mm / 2 + rig.ball_diameter_mm / 2 + 1)
        pts = np.vstack([pts, np.stack([x, y, h], axis=1)[ok]])
    return pts[:n, 0], pts[:n, 1], pts[:n, 2]
