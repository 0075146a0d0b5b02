"""Which case goes in each plate quadrant as a calibration drop, and on an anisotropic plate where along the
sensor lines.

On a plate whose localiser fits a travel metric (travel.wants_metric: an orthotropic or unknown material), the
four drops also read the metric's anisotropy, i.e. how the travel time per mm changes with the path's angle to
the material axes (docs/method.md, zero-shot). Cases near the plate's middle send their paths to the sensors
at diagonal angles, where the ellipse's two axes weigh about equally; a case near the line joining two sensors
sends two of its paths along that line. So two opposite quadrants (the first and third: lower-left, upper-right)
each take a case near a sensor line (within `line_tol_mm` of the segment between two sensors) whose direction is
within `AXIS_TOL_DEG` of a material axis, the two cases on lines along *different* axes, so that the drops'
paths run along both axes, both among the more repeatable half of the usable cases. The other two quadrants, and an isotropic plate's four, keep the plain choice: the
case minimising spread + spread_weight * distance from the quadrant's centre (drops.py).
"""

from __future__ import annotations

import numpy as np

# A sensor line counts as along a material axis within this angle.
AXIS_TOL_DEG = 20.0
# The quadrants in calibrate's order (right, top) and the opposite pair that takes the cases near sensor lines.
QUADRANTS = ((False, False), (True, False), (True, True), (False, True))
LINE_QUADRANTS = (0, 2)


def axis_lines(sensors_xy: np.ndarray, axis_deg: float, tol_deg: float = AXIS_TOL_DEG) -> list[tuple[int, int, int]]:
    """The sensor pairs (i, j) whose joining line runs within tol_deg of material axis k (0: axis 1 at axis_deg
    from the plate's x axis, 1: axis 2): [(i, j, k)]."""
    s = np.asarray(sensors_xy, float)
    out = []
    for i in range(len(s)):
        for j in range(i + 1, len(s)):
            dx, dy = s[j] - s[i]
            rel = (np.degrees(np.arctan2(dy, dx)) - axis_deg) % 180.0      # the line's angle to axis 1
            off1, off2 = min(rel, 180.0 - rel), abs(rel - 90.0)
            if min(off1, off2) <= tol_deg:
                out.append((i, j, 0 if off1 <= off2 else 1))
    return out


def segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance (mm) of point p from the segment a-b."""
    ab = b - a
    t = float(np.clip(np.dot(p - a, ab) / np.dot(ab, ab), 0.0, 1.0))
    return float(np.linalg.norm(p - a - t * ab))


def near_axis_lines(xy: np.ndarray, sensors_xy: np.ndarray, axis_deg: float, line_tol_mm: float) -> set[int]:
    """The material axes (0, 1) along whose sensor lines the point xy lies within line_tol_mm."""
    s = np.asarray(sensors_xy, float)
    p = np.asarray(xy, float)
    return {k for i, j, k in axis_lines(s, axis_deg) if segment_distance(p, s[i], s[j]) <= line_tol_mm}


def quadrant_of(row: dict, px: float, py: float) -> int:
    return QUADRANTS.index((row["x"] >= px / 2, row["y"] >= py / 2))


def choose_cases(rows: dict, plate_xy_mm: tuple[float, float], spread_weight: float = 0.05, *,
                 sensors_xy: np.ndarray | None = None, axis_deg: float = 0.0, line_tol_mm: float = 10.0,
                 rng: np.random.Generator | None = None) -> list[int]:
    """Four usable cases of `rows` (drops.case_table), one per quadrant in QUADRANTS' order. Without rng, per
    quadrant the case minimising spread + spread_weight * distance from the quadrant's centre (a quadrant with
    none borrows the best remaining case elsewhere); with rng, one usable case of the quadrant at random.
    With sensors_xy (a plate whose localiser fits a metric): LINE_QUADRANTS take cases near sensor lines along
    different material axes (the best-scoring such pair, or a random one with rng), when both quadrants have one."""
    px, py = plate_xy_mm
    usable = sorted(c for c, r in rows.items() if r["usable"])
    centres = [((0.75 if right else 0.25) * px, (0.75 if top else 0.25) * py) for right, top in QUADRANTS]

    def score(c, q):
        r = rows[c]
        return (r["spread_us"] + spread_weight * np.hypot(r["x"] - centres[q][0], r["y"] - centres[q][1])
                + (0.0 if quadrant_of(r, px, py) == q else 1e3))

    if rng is not None:     # the plain draw first, so the rule changes only the line quadrants' cases
        chosen = []
        for q in range(4):
            cands = [c for c in usable if quadrant_of(rows[c], px, py) == q]
            if not cands:
                raise ValueError(f"no usable calibration case in plate quadrant {QUADRANTS[q]}")
            chosen.append(int(rng.choice(cands)))
        fixed = _line_pair(rows, usable, px, py, score, sensors_xy, axis_deg, line_tol_mm, rng) \
            if sensors_xy is not None else {}
        return [fixed.get(q, c) for q, c in enumerate(chosen)]
    fixed = _line_pair(rows, usable, px, py, score, sensors_xy, axis_deg, line_tol_mm, None) \
        if sensors_xy is not None else {}
    chosen = []
    for q in range(4):
        if q in fixed:
            chosen.append(fixed[q])
            continue
        cands = [c for c in usable if c not in chosen and c not in fixed.values()]
        chosen.append(cands[int(np.argmin([score(c, q) for c in cands]))])
    return chosen


def _line_pair(rows, usable, px, py, score, sensors_xy, axis_deg, line_tol_mm, rng) -> dict[int, int]:
    """{quadrant: case} for LINE_QUADRANTS: a case near a sensor line along axis k in the first and along the
    other axis in the second (both assignments considered), each among the more repeatable half of the usable
    cases (DToA spread at most their median: a random draw would otherwise take cases whose repetitions scatter
    by a cycle); {} when no such pair exists."""
    qa, qb = LINE_QUADRANTS
    limit = np.median([rows[c]["spread_us"] for c in usable])      # the more repeatable half only
    axes = {c: near_axis_lines((rows[c]["x"], rows[c]["y"]), sensors_xy, axis_deg, line_tol_mm) for c in usable}
    in_q = {q: [c for c in usable if quadrant_of(rows[c], px, py) == q and rows[c]["spread_us"] <= limit]
            for q in LINE_QUADRANTS}
    pairs = [(a, b) for k in (0, 1) for a in in_q[qa] if k in axes[a] for b in in_q[qb] if 1 - k in axes[b]]
    if not pairs:
        return {}
    if rng is not None:
        a, b = pairs[int(rng.integers(len(pairs)))]
    else:
        a, b = min(pairs, key=lambda p: score(p[0], qa) + score(p[1], qb))
    return {qa: int(a), qb: int(b)}
