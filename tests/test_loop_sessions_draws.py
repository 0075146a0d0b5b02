"""loop_sessions' draws: seed 0 is the canonical layout of docs/findings.md's tables; another seed draws every kind
of change anew (move sizes and directions, the moved sensors, E, D_s, the signal-level changes) within the
issue's ranges; every draw depends on the seed and the declared rig. Spec lists only: nothing simulated."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import loop_sessions  # noqa: E402


def _moves(specs):
    return [s for s in specs if s["name"].startswith("move-")]


def _angle_deg(p):
    return float(np.degrees(np.arctan2(p["dy_mm"], p["dx_mm"])) % 360)


def _rig(material="PMMA", size=(400.0, 300.0, 5.0), sensors=((50, 50), (350, 50), (350, 250), (50, 250)),
         **other):
    from types import SimpleNamespace

    return SimpleNamespace(plate_material=material, plate_x_mm=size[0], plate_y_mm=size[1], thickness_mm=size[2],
                           sensors=[SimpleNamespace(x_mm=x, y_mm=y) for x, y in sensors], **other)


def test_seed_0_keeps_the_canonical_directions_sensors_and_plate_changes():
    for rig in (None, _rig(), _rig("aluminium", (500.0, 400.0, 3.0))):
        specs = {s["name"]: s for s in loop_sessions.spec_list(0, (), rig)}
        for j, deg in enumerate(loop_sessions.DIRECTIONS_DEG):
            t = specs[f"move-{deg}"]["truth"]
            assert t["sensor"] == j % 4
            assert abs((_angle_deg(t["params"]) - deg + 180) % 360 - 180) < 0.01
        assert specs["stiffness"]["truth"]["params"]["e_scale"] == 0.92
        assert specs["damping"]["truth"]["params"]["damping_scale"] == 1.20
    # the seed-only draw (before session 23, `--seed-only-draw`) keeps the sizes of the earlier tables
    # (docs/findings.md, issue 16): move-0 7.6 mm, the delay 4.95 us on channel 2
    specs = {s["name"]: s for s in loop_sessions.spec_list(0)}
    assert abs(specs["move-0"]["truth"]["params"]["dx_mm"] - 7.607) < 1e-9
    assert specs["delay"]["truth"]["sensor"] == 2 and specs["delay"]["truth"]["params"]["delay_us"] == 4.95


def test_every_draw_depends_on_the_seed_and_the_rig():
    """One seed on two rigs: two draws (every drawn size, and each session's own drops' and noise's streams,
    so a hum or white-noise session's samples differ too); the same rig (its notes aside) gives the same draw,
    and a moved sensor or another thickness is another rig."""
    from types import SimpleNamespace

    a, b = _rig(), _rig("aluminium", (500.0, 400.0, 3.0), ((60, 50), (445, 70), (430, 345), (75, 330)))
    assert loop_sessions.rig_key(a) == loop_sessions.rig_key(_rig(notes="other words", bias_counts=0))
    assert loop_sessions.rig_key(a) != loop_sessions.rig_key(_rig(size=(400.0, 300.0, 6.0)))
    assert loop_sessions.rig_key(a) != loop_sessions.rig_key(
        _rig(sensors=((51, 50), (350, 50), (350, 250), (50, 250))))
    for seed in (0, 12):
        sa, sb = (loop_sessions.spec_list(seed, (), r) for r in (a, b))
        assert sa == loop_sessions.spec_list(seed, (), _rig())          # reproducible
        assert [s["name"] for s in sa if not s["name"].startswith("move-")] == \
            [s["name"] for s in sb if not s["name"].startswith("move-")]
        seeds_a, seeds_b = {s["seed"] for s in sa}, {s["seed"] for s in sb}
        assert not seeds_a & seeds_b                                    # no session shares its drops' streams
        canonical = {"stiffness", "damping"} if seed == 0 else set()   # seed 0's plate changes: the tables'
        for x, y in zip(sa, sb):
            if x.get("truth") and x["name"] not in canonical:
                assert x["truth"]["params"] != y["truth"]["params"], x["name"]
        rig = SimpleNamespace(fs_hz=100000.0)
        for name in ("hum", "noise"):
            xa = next(s for s in sa if s["name"] == name)
            xb = next(s for s in sb if s["name"] == name)
            za, zb = (loop_sessions.signal_change(np.zeros((3, 4, 200)), x["truth"], rig, x["seed"]) for x in (xa, xb))
            assert np.abs(za - zb).max() > 1.0                          # the pre-trigger samples differ
    # the seed alone, as before session 23: both rigs one draw
    assert loop_sessions.spec_list(12) == loop_sessions.spec_list(12, (), None)
    assert loop_sessions.draw_seed(12) == 12 != loop_sessions.draw_seed(12, a)


def test_other_seeds_draw_directions_sensors_and_plate_changes_within_the_issue_ranges():
    seen_offsets, seen_perms = set(), set()
    for seed in (1, 2, 3, 4):
        specs = loop_sessions.spec_list(seed)
        names = [s["name"] for s in specs]
        assert len(names) == len(set(names))
        moves = _moves(specs)
        assert len(moves) == 8
        angles = np.array([_angle_deg(m["truth"]["params"]) for m in moves])
        sizes = np.array([np.hypot(m["truth"]["params"]["dx_mm"], m["truth"]["params"]["dy_mm"]) for m in moves])
        assert np.all((sizes >= 5.0 - 1e-3) & (sizes <= 10.0 + 1e-3))
        # eight directions 45 deg apart, all turned by one offset of at most 22.5 deg
        offsets = (angles - np.array(loop_sessions.DIRECTIONS_DEG) + 180) % 360 - 180
        assert np.ptp(offsets) < 0.05 and abs(offsets[0]) <= 22.5
        for m, a in zip(moves, angles):   # the name says the direction
            assert abs((int(m["name"].split("-")[1]) - a + 180) % 360 - 180) <= 0.6   # whole degrees; the offsets rounded to 1 um
        # every sensor moved twice (in opposite directions)
        sensors = [m["truth"]["sensor"] for m in moves]
        assert sorted(sensors) == [0, 0, 1, 1, 2, 2, 3, 3]
        spec = {s["name"]: s for s in specs}
        e = spec["stiffness"]["truth"]["params"]["e_scale"]
        ds = spec["damping"]["truth"]["params"]["damping_scale"]
        assert 0.90 <= e <= 0.94 and 1.15 <= ds <= 1.25
        seen_offsets.add(round(offsets[0], 1))
        seen_perms.add(tuple(sensors[:4]))
    assert len(seen_offsets) == 4 and len(seen_perms) >= 2   # the draws do differ


def test_without_change_takes_an_additive_change_out_to_the_rounding_and_leaves_other_sessions_alone():
    """A hum or white-noise session's recordings with the generator's draw taken out again are the drops as made
    before it (to the ADC's rounding: at most one count, a half from each rounding); a gain session has no
    additive change to take out."""
    from types import SimpleNamespace

    rig = SimpleNamespace(fs_hz=100000.0, bias_counts=2048, adc_max=4095)
    rng = np.random.default_rng(3)
    clean = rng.normal(0.0, 1.5, (6, 4, 1000)) + 40.0 * np.sin(np.arange(1000) / 7.0) * (np.arange(1000) > 300)
    specs = {s["name"]: s for s in loop_sessions.spec_list(1)}
    made = np.rint(clean + 2048).astype(np.uint16)
    for name in ("hum", "noise"):
        spec = specs[name]
        changed = loop_sessions.signal_change(clean, spec["truth"], rig, spec["seed"])
        adc = np.clip(np.rint(changed + 2048), 0, 4095).astype(np.uint16)
        assert np.abs(adc.astype(float) - made).max() > 10            # the change is there
        back = loop_sessions.without_change(adc, spec, rig)
        assert np.abs(back.astype(float) - made).max() <= 1.0
    assert loop_sessions.without_change(made, specs["gain"], rig) is None
