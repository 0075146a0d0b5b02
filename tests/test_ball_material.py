"""The impactor's material: rig.json's `ball_material` (or `ball_properties`) sets the twin's Hertz contact. Before,
the words were read and never used: every twin hit with steel, so a 10 mm nylon ball on glass was simulated with a
~3x shorter contact and a wider band than the rig's (docs/findings.md "Session 25: newuser6")."""

import numpy as np
import pytest

from impactsense.balls import STEEL, ball_for_rig, lookup
from impactsense.calibration import arrival
from impactsense.data import rig_from_dict
from impactsense.errors import DataError
from impactsense.sim import SimParams


def _raw(ball="steel", **extra):
    sensors = [{"name": f"S{k + 1}", "channel": k, "x_mm": x, "y_mm": y}
               for k, (x, y) in enumerate([(40, 30), (170, 40), (160, 120), (30, 110)])]
    return {"plate_material": "soda-lime glass", "plate_x_mm": 200.0, "plate_y_mm": 150.0, "thickness_mm": 4.0,
            "density_kg_m3": 2500.0, "plate_support": "resting on four rubber pads", "sensors": sensors,
            "channels": 4, "sensor_diameter_mm": 10.0, "ball_material": ball, "ball_diameter_mm": 10.0,
            "ball_mass_g": 0.6, "fs_hz": 96000, "samples": 1024, "adc_bits": 16, "vref": 20.0,
            "bias_counts": 32768, **extra}


def test_words_name_the_ball():
    assert lookup("nylon (PA66)").name == "nylon" and lookup("Delrin acetal").name == "acetal (POM)"
    assert lookup("chrome steel AISI 52100").name == "steel" and lookup("tungsten carbide").e_pa > 500e9
    assert lookup("polycarbonate").name == "polycarbonate"          # not "carbide" (a keyword starts a word)
    unknown = lookup("mystery wood")
    assert not unknown.known and unknown.e_pa == STEEL.e_pa


def test_steel_ball_keeps_the_twin_as_it_was():
    """The measured rigs declare steel: the simulator's parameters are the old defaults, bit for bit."""
    p = SimParams.from_rig(rig_from_dict(_raw("steel")))
    assert (p.ball_e_pa, p.ball_nu) == (SimParams().ball_e_pa, SimParams().ball_nu)


def test_nylon_ball_reaches_the_simulator_and_the_fast_model():
    rig = rig_from_dict(_raw("nylon (PA66)"))
    p = SimParams.from_rig(rig)
    assert p.ball_e_pa == pytest.approx(3.0e9) and p.ball_nu == pytest.approx(0.40)
    assert SimParams.from_rig(rig, ball_e_pa=5e9).ball_e_pa == 5e9           # an explicit value still wins
    setup = arrival.setup_from_rig(rig, [100.0], [75.0], [150.0])
    soft = arrival.synth_unit(setup, [71e9], [0.23])[0, 0, 0]
    steel_setup = arrival.setup_from_rig(rig_from_dict(_raw("steel")), [100.0], [75.0], [150.0])
    hard = arrival.synth_unit(steel_setup, [71e9], [0.23])[0, 0, 0]
    # Hertz: t_c ~ E*^(-2/5), so the soft ball's contact is ~3x longer and its band ~3x narrower
    tc = [arrival.hertz_duration_s(71e9, 0.23, 0.15, 5e-3, 6e-4, s.ball_e_pa, s.ball_nu) for s in (setup, steel_setup)]
    e_star = [1 / ((1 - 0.23 ** 2) / 71e9 + (1 - nu ** 2) / e) for e, nu in ((3.0e9, 0.40), (210e9, 0.30))]
    assert tc[0] / tc[1] == pytest.approx((e_star[0] / e_star[1]) ** -0.4, rel=1e-9)
    assert 2.5 < tc[0] / tc[1] < 4.0

    def centroid(x):
        spec = np.abs(np.fft.rfft(x)) ** 2
        f = np.fft.rfftfreq(x.size, 1 / setup.fs_hz)
        return float((f * spec).sum() / spec.sum())

    assert centroid(soft) < 0.8 * centroid(hard)


def test_ball_properties_declared_and_checked():
    rig = rig_from_dict(_raw("a 10 mm ball", ball_properties={"e_pa": 2.5e9, "nu": 0.42}))
    ball = ball_for_rig(rig)
    assert (ball.e_pa, ball.nu, ball.source) == (2.5e9, 0.42, "rig.json ball_properties")
    assert SimParams.from_rig(rig).ball_e_pa == 2.5e9
    with pytest.raises(DataError, match=r"ball_properties\.nu"):
        rig_from_dict(_raw(ball_properties={"e_pa": 2.5e9, "nu": 0.7}))
    with pytest.raises(DataError, match="ball_properties"):
        rig_from_dict(_raw(ball_properties={"youngs": 2.5e9}))


def test_fem_contact_follows_the_declared_ball():
    """The FEM twin's contact on a small glass plate lasts as Hertz says for the declared ball: nylon ~3x steel."""
    from impactsense.sim import simulate_voltages

    durations = []
    for ball in ("nylon", "steel"):
        rig = rig_from_dict(_raw(ball))
        p = SimParams.from_rig(rig, element_mm=6.0, duration_ms=0.6, taper_ms=0.1, max_height_mm=150.0)
        res = simulate_voltages(p, rig, [100.0], [75.0], [150.0], method="direct", workers=1)
        durations.append(float(res["contact_s"][0]))
    assert 2.3 < durations[0] / durations[1] < 4.2, durations
