"""calibrate's automatic choice of the four calibration drops (calibration/drop_paths.py): one case per plate
quadrant; on a plate whose localiser fits a travel metric two opposite quadrants take cases near sensor lines
along different material axes, so that the drops' paths run along both axes; an isotropic plate's choice is
the plain one."""

from dataclasses import replace

import numpy as np

from impactsense.calibration.drop_paths import (LINE_QUADRANTS, axis_lines, choose_cases, near_axis_lines,
                                                quadrant_of)
from impactsense.calibration.drops import line_rule
from impactsense.data import load_session

PLATE = (400.0, 300.0)
# Sensors near the corners of a slightly skewed rectangle (no line exactly along x or y).
SENSORS = np.array([[40.0, 40.0], [360.0, 50.0], [355.0, 260.0], [45.0, 255.0]])


def _path_angles_deg(cases, rows, axis_deg=0.0):
    """The angle (0-90 deg) of every source-to-sensor path to material axis 1."""
    out = []
    for c in cases:
        d = SENSORS - np.array([rows[c]["x"], rows[c]["y"]])
        ang = (np.degrees(np.arctan2(d[:, 1], d[:, 0])) - axis_deg) % 180.0
        out += list(np.minimum(ang, 180.0 - ang))
    return np.array(out)


def _case_grid(seed=0):
    """A case table like drops.case_table's: a 20 mm grid 45 mm clear of the sensors, random spreads."""
    rng = np.random.default_rng(seed)
    rows, c = {}, 0
    for x in np.arange(30.0, 380.0, 20.0):
        for y in np.arange(30.0, 280.0, 20.0):
            if np.min(np.hypot(*(SENSORS - [x, y]).T)) >= 45.0:
                rows[c] = {"x": float(x), "y": float(y), "spread_us": float(rng.uniform(1.0, 15.0)), "usable": True}
                c += 1
    return rows


def test_axis_lines_are_the_sensor_sides_along_each_axis():
    lines = axis_lines(SENSORS, 0.0)
    assert sorted((i, j) for i, j, _ in lines) == [(0, 1), (0, 3), (1, 2), (2, 3)]     # no diagonal
    assert {(i, j): k for i, j, k in lines} == {(0, 1): 0, (2, 3): 0, (0, 3): 1, (1, 2): 1}
    # Fibres at 45 deg on a square layout: the diagonals are the lines along the axes, the sides are not.
    square = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [0.0, 100.0]])
    assert sorted((i, j) for i, j, _ in axis_lines(square, 45.0)) == [(0, 2), (1, 3)]
    assert near_axis_lines((200.0, 47.0), SENSORS, 0.0, 10.0) == {0}
    assert near_axis_lines((200.0, 150.0), SENSORS, 0.0, 10.0) == set()


def test_metric_plate_choice_spans_both_axes_one_per_quadrant():
    rows = _case_grid()
    plain = choose_cases(rows, PLATE)
    rule = choose_cases(rows, PLATE, sensors_xy=SENSORS, line_tol_mm=10.0)
    for cases in (plain, rule):
        assert sorted(quadrant_of(rows[c], *PLATE) for c in cases) == [0, 1, 2, 3]
    # The two line quadrants' cases lie near sensor lines of different axes; the others are the plain choice's.
    axes = [near_axis_lines((rows[rule[q]]["x"], rows[rule[q]]["y"]), SENSORS, 0.0, 10.0) for q in LINE_QUADRANTS]
    assert all(axes) and axes[0] | axes[1] == {0, 1}
    assert [rule[q] for q in range(4) if q not in LINE_QUADRANTS] == [plain[q] for q in range(4)
                                                                     if q not in LINE_QUADRANTS]
    # Paths within 10 deg of each axis (a case 10 mm off a line, >= 45 mm from its sensors): the rule's drops
    # have two or more along both axes; the plain choice here (on this table) has none along axis 2.
    ang = _path_angles_deg(rule, rows)
    assert (ang < 10.0).sum() >= 2 and (ang > 80.0).sum() >= 2
    plain_ang = _path_angles_deg(plain, rows)
    assert (plain_ang > 80.0).sum() == 0


def test_random_draws_change_only_the_line_quadrants():
    rows = _case_grid(1)
    for draw in (1, 2, 3):
        plain = choose_cases(rows, PLATE, rng=np.random.default_rng(draw))
        rule = choose_cases(rows, PLATE, sensors_xy=SENSORS, rng=np.random.default_rng(draw))
        assert [plain[q] for q in (1, 3)] == [rule[q] for q in (1, 3)]
        axes = [near_axis_lines((rows[rule[q]]["x"], rows[rule[q]]["y"]), SENSORS, 0.0, 10.0) for q in LINE_QUADRANTS]
        assert axes[0] | axes[1] == {0, 1}


def test_rule_applies_only_where_the_localiser_fits_a_metric():
    rig = load_session("bundled").rig              # aluminium: isotropic and known
    assert line_rule(rig) == {}
    laminate = replace(rig, plate_material="carbon-fibre laminate",
                       raw={**rig.raw, "plate_material": "carbon-fibre laminate", "material_axes": {"fibre_angle_deg": 30.0}})
    rule = line_rule(laminate)
    assert rule["axis_deg"] == 30.0 and rule["sensors_xy"].shape == (4, 2)
    assert line_rule(laminate, 0.0) == {}


def test_a_strongly_orthotropic_strips_drops_are_ordered_in_its_travel_metric():
    """A narrow unidirectional strip, fibres at 30 deg: a sensor farther in millimetres along the fibres hears a
    hit before a nearer one across them, so Eq. 35 by distance rejects most drops and calibrate found no four
    cases; where distance leaves fewer than four, the material's metric orders them (an isotropic plate and a
    laminate with four usable cases by distance keep the distance)."""
    from types import SimpleNamespace

    from impactsense import _core
    from impactsense.calibration.drops import order_metric, select_drops
    from impactsense.data import rig_from_dict
    from impactsense.materials import kirchhoff_ray_metric
    from impactsense.travel import travel_distances

    bundled = load_session("bundled").rig
    sensors = [(45, 18), (130, 184), (570, 16), (655, 182)]
    raw = dict(bundled.to_dict(), plate_material="unidirectional carbon/epoxy strip", plate_x_mm=700.0,
               plate_y_mm=200.0, density_kg_m3=1570.0, material_axes={"fibre_angle_deg": 30.0},
               sensors=[{"name": f"S{k + 1}", "channel": k, "x_mm": float(x), "y_mm": float(y)}
                        for k, (x, y) in enumerate(sensors)])
    rig = rig_from_dict(raw)
    assert order_metric(rig) and order_metric(bundled) == []
    rng = np.random.default_rng(0)
    n_cases, reps = 30, 3
    cx, cy = rng.uniform(60, 640, n_cases), rng.uniform(40, 160, n_cases)
    x, y = np.repeat(cx, reps), np.repeat(cy, reps)
    truth = kirchhoff_ray_metric(120e9, 8.5e9, 4.6e9, 0.31, 30.0)     # the strip's own constants (E1/E2 ~14)
    toa = travel_distances(np.c_[x, y], np.array(sensors, float), truth) / 1.0 + rng.normal(0, 1.0, (x.size, 4))
    n = x.size
    feats = {"toa_us": toa.astype(np.float32), "flags": np.zeros((n, 4), np.uint8),
             "status": np.full(n, _core.STATUS_OK), "dtoa_us": rng.normal(0, 1, (n, 6)),
             **{k: np.ones((n, 4)) for k in ("energy", "residual_ratio", "peak", "first_peak", "noise_rms")}}
    session = SimpleNamespace(rig=rig, path="strip", case_id=np.repeat(np.arange(n_cases), reps), x_mm=x, y_mm=y,
                              xy_mm=np.c_[x, y], height_mm=np.full(n, 100.0))
    by_distance = _core.accept_batch(feats["toa_us"], [float(v) for v in rig.sensor_x_mm],
                                     [float(v) for v in rig.sensor_y_mm], session.xy_mm.astype(np.float32), 0.0, 0.0)
    chosen = select_drops(session, feats)
    assert len(set(chosen.case_ids)) == 4 and chosen.info["eq35_travel_metric"] is not None
    assert chosen.info["accepted_recordings"] > 2 * int(by_distance.sum())
    # isotropic arrivals on the same strip: four cases by distance, so the distance stays
    iso = travel_distances(np.c_[x, y], np.array(sensors, float)) + rng.normal(0, 1.0, (n, 4))
    plain = select_drops(session, {**feats, "toa_us": iso.astype(np.float32)})
    assert plain.info["eq35_travel_metric"] is None
