"""Synthetic rigs unlike the measured ones, made with the project's own FEM, to run a new user's journey on.

Each rig is a rig.json (another material, sensor layout, disc, ball, logger rate / bits / samples) and a
session written in the measured format (impacts.csv, recordings.npz with uint16 adc): cases at random
positions (edge and sensor clearance), `--reps` drops each at one height, hand-release scatter (the true drop
lands ~1 mm from the declared position), the lab's faults (per-record offsets, rare glitches, gain drift,
noise; `impactsense.faults`) and a circuit gain set so the median peak is ~1/4 of the ADC's half range.

    python3 benchmarks/synthetic_rig.py KIND --out DIR [--cases 40] [--reps 2] [--seed 0] [--element-mm MM]

KIND: steel-diamond (steel, 200 kHz, 16-bit, sensors on a diamond), gfrp-edge (GFRP with fibres at 35 deg,
50 kHz, 12-bit, three sensors near one edge), glass-skew (soda-lime glass, 100 kHz, 14-bit, a skewed
quadrilateral, an unknown-to-the-table plate support), alu-rotated (a 6 mm aluminium plate clamped in a frame,
sensors on a rectangle turned 20 deg, 50 kHz, 12-bit, 1024 samples, 40 of them before the hit), pc-quad (an 8 mm
polycarbonate sheet, sensors on an asymmetric quadrilateral, 200 kHz, 12-bit), brass-trapezoid (2.5 mm brass,
a trapezoid with two sensors 48 mm apart, a 20 mm ball of 33 g, 250 kHz, 10-bit, 6 ms records), cfrp-crossply
(a graphite/epoxy cross-ply, E1 ~ E2 with a low G12, axes at 90 deg, two sensors 14 mm from an edge, 100 kHz,
16-bit with a negative-going front end whose DC sits 2300 counts under the declared bias, 8 ms records of which
30 samples before the hit; its rig.json leaves out the density), ti-nonconvex (1.6 mm titanium, 600 x 260 mm, one
sensor inside the triangle of the other three, 20 mm discs, 62.5 kHz, 12-bit, 40 ms records of which 16 ms before
the hit, a front end hot enough that drops next to a sensor clip, 50 Hz hum, one sensor loose on 10 % of drops),
wear-thick-side (a 10 mm plate of a steel named by its trade name, unknown to the materials table, sensors close
together in one corner region, 200 kHz, 16-bit, 8000 samples, rig.json's optional fields, an impacts.csv with
extra columns in the lab's order; run it with --cases 20 --reps 3), cfrp-ud-strip (a 700 x 200 x 3 mm
unidirectional carbon/epoxy strip, fibres at 30 deg, sensors staggered on the two long edges, a 12.7 mm ball,
250 kHz, 14-bit, 10000 samples of which 2000 before the hit, a second contact on 5 % of the drops; run it with
--reps 3), alu-large-thin (a 1200 x 800 x 1.5 mm aluminium sheet, sensors ~100 mm in from the corners wired in no
geometric order, 50 kHz, 12-bit, 4096 samples, 60 Hz hum, a hot front end; run it with --cases 30 --reps 4),
fr4-scope (a 400 x 300 x 1.6 mm FR-4 circuit-board panel, woven so nearly isotropic, three sensors near one long
edge and one near the middle of the other, channels in no geometric order, a bench oscilloscope: 1 MHz x 20,000
samples, 8-bit, 4,000 before the trigger, a DC offset per channel, 50 Hz hum on one channel; run it with
--cases 25 --reps 4), glass-audio (a 600 x 450 x 6 mm soda-lime glass tabletop, very lightly damped, sensors on an
irregular quadrilateral turned ~12 deg, a 4-channel USB audio interface: 96 kHz, 16-bit, large full scale, AC-coupled
at 10 Hz, a linear-phase anti-alias FIR at 43 kHz, 4,096 samples of which 512 before the hit; a 10 mm nylon ball;
run it with --cases 25 --reps 4), ss-strip-edge (an 850 x 280 x 1.5 mm stainless-steel strip, three sensors along one
long edge and one near an end of the other, channels in no geometric order, a 5 mm silicon-nitride ball from
20-100 mm, 500 kHz x 2,000 samples at 12 bits, rig.json without density or optional fields; run it with --cases 60
--reps 3), mg-clip (a 450 x 350 x 3 mm magnesium AZ31B plate, sensors on an asymmetric trapezoid away from the
corners, drops from 50 to 1000 mm with the logger's gain set on the low ones: the high drops clip on every channel,
200 kHz, 14-bit, 3000 samples; run it with --cases 40 --reps 3), oak-table (a 600 x 400 x 18 mm solid-oak
tabletop, grain along x, 27 mm buzzer discs on a parallelogram, a 12.7 mm ball, 48 kHz, 12-bit, 2048 samples; run
it with --cases 40 --reps 3), hdpe-kite (a 500 x 400 x 12 mm HDPE sheet, slow and heavily damped, sensors on a kite
with one near the middle of an edge, 50 kHz, 14-bit over 2.5 V, rig.json without density or optional fields; run it
with --cases 40 --reps 3), pvc-slowlog (a square
500 x 500 x 5 mm rigid-PVC sheet read by a low-rate microcontroller logger: 20 kHz, 10-bit, 1024 samples of which
128 before the hit; run it with --cases 40 --reps 3).
The mesh is coarse (--element-mm, 4 mm unless the kind sets its own: ss-strip-edge's thin strip and mg-clip's 3 mm plate
2 mm) so a rig costs minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

def _sensors(xy):
    return [{"name": f"S{k + 1}", "channel": k, "x_mm": float(x), "y_mm": float(y)} for k, (x, y) in enumerate(xy)]


def _rotated_rectangle(centre, size, angle_deg):
    """A rectangle's corners (counter-clockwise) turned by angle_deg about its centre."""
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    half = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * np.asarray(size, float) / 2
    return np.round(np.asarray(centre, float) + half @ np.array([[c, s], [-s, c]]), 1)


KINDS = {
    "steel-diamond": dict(
        rig={"plate_material": "structural steel S235", "plate_x_mm": 400.0, "plate_y_mm": 300.0,
             "thickness_mm": 2.0, "density_kg_m3": 7850.0, "plate_support": "edges resting on a rubber rim",
             "sensors": _sensors([(200, 40), (355, 150), (200, 262), (48, 150)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 7.0, "ball_material": "steel",
             "ball_diameter_mm": 6.0, "ball_mass_g": 0.88, "channels": 4, "fs_hz": 200000, "samples": 4000,
             "adc_bits": 16, "vref": 3.3, "bias_counts": 32768},
        sim=dict(e_pa=205e9, nu=0.29, pretrigger_samples=400, damping_per_s=600.0),
        heights=(60, 90, 120, 150, 180, 210, 240)),
    "gfrp-edge": dict(
        rig={"plate_material": "GFRP laminate (E-glass/epoxy), fibres at 35 deg", "plate_x_mm": 420.0,
             "plate_y_mm": 320.0, "thickness_mm": 3.0, "density_kg_m3": 1900.0,
             "plate_support": "edges resting on a rubber rim",
             "material_axes": {"fibre_angle_deg": 35.0},
             "sensors": _sensors([(60, 45), (210, 30), (360, 45), (210, 270)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 12.0, "ball_material": "steel",
             "ball_diameter_mm": 10.0, "ball_mass_g": 4.07, "channels": 4, "fs_hz": 50000, "samples": 1500,
             "adc_bits": 12, "vref": 3.3, "bias_counts": 2048},
        sim=dict(e_pa=32e9, e2_pa=11e9, g12_pa=4.2e9, nu=0.26, material_axes_deg=35.0, pretrigger_samples=100,
                 damping_per_s=1500.0),
        heights=(100, 150, 200, 250, 300)),
    "glass-skew": dict(
        rig={"plate_material": "soda-lime float glass", "plate_x_mm": 360.0, "plate_y_mm": 360.0,
             "thickness_mm": 4.0, "density_kg_m3": 2500.0, "plate_support": "four felt pads at the corners",
             "sensors": _sensors([(40, 70), (300, 35), (320, 310), (90, 280)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 15.0, "ball_material": "steel",
             "ball_diameter_mm": 5.0, "ball_mass_g": 0.51, "channels": 4, "fs_hz": 100000, "samples": 3000,
             "adc_bits": 14, "vref": 2.5, "bias_counts": 8192},
        sim=dict(e_pa=72e9, nu=0.22, pretrigger_samples=300, damping_per_s=400.0),
        heights=(80, 120, 160, 200, 240)),
    "alu-rotated": dict(
        rig={"plate_material": "aluminium 5083-H111", "plate_x_mm": 500.0, "plate_y_mm": 360.0,
             "thickness_mm": 6.0, "density_kg_m3": 2660.0, "plate_support": "clamped in a steel frame",
             "sensors": _sensors(_rotated_rectangle((250, 180), (260, 170), 20.0)),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 10.0, "ball_material": "steel",
             "ball_diameter_mm": 12.0, "ball_mass_g": 7.05, "channels": 4, "fs_hz": 50000, "samples": 1024,
             "adc_bits": 12, "vref": 3.0, "bias_counts": 2048},
        sim=dict(e_pa=71e9, nu=0.33, pretrigger_samples=40, damping_per_s=500.0),
        heights=(50, 100, 150, 200, 250, 300)),
    "pc-quad": dict(
        rig={"plate_material": "polycarbonate sheet", "plate_x_mm": 560.0, "plate_y_mm": 420.0,
             "thickness_mm": 8.0, "density_kg_m3": 1200.0, "plate_support": "edges resting on a rubber rim",
             "sensors": _sensors([(95, 60), (470, 110), (420, 365), (150, 330)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 10.0, "ball_material": "steel",
             "ball_diameter_mm": 10.0, "ball_mass_g": 4.07, "channels": 4, "fs_hz": 200000, "samples": 3000,
             "adc_bits": 12, "vref": 3.3, "bias_counts": 2048},
        # an unknown material to the table (wide, laminate-like priors): the truth given as an isotropic laminate
        sim=dict(e_pa=2.4e9, e2_pa=2.4e9, g12_pa=2.4e9 / 2.74, nu=0.37, material_axes_deg=0.0,
                 pretrigger_samples=200, damping_per_s=900.0),
        heights=(70, 110, 150, 190, 230, 270)),
    "brass-trapezoid": dict(
        rig={"plate_material": "brass CuZn37", "plate_x_mm": 380.0, "plate_y_mm": 300.0,
             "thickness_mm": 2.5, "density_kg_m3": 8440.0, "plate_support": "edges resting on a rubber rim",
             "sensors": _sensors([(45, 40), (92, 48), (340, 55), (240, 262)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 8.0, "ball_material": "steel",
             "ball_diameter_mm": 20.0, "ball_mass_g": 32.6, "channels": 4, "fs_hz": 250000, "samples": 1500,
             "adc_bits": 10, "vref": 3.3, "bias_counts": 512},
        sim=dict(e_pa=100e9, nu=0.34, pretrigger_samples=150, damping_per_s=700.0),
        heights=(30, 60, 90, 120, 150)),
    "cfrp-crossply": dict(
        # no density (the user left it out), the material in another spelling, axes at 90 deg, a negative-going
        # front end whose DC sits ~2300 counts under the declared bias
        rig={"plate_material": "Graphite/epoxy cross-ply [0/90]2s", "plate_x_mm": 400.0, "plate_y_mm": 300.0,
             "thickness_mm": 2.0, "plate_support": "edges resting on a rubber rim",
             "material_axes": {"fibre_angle_deg": 90.0},
             "sensors": _sensors([(200, 14), (386, 150), (215, 272), (30, 190)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 10.0, "ball_material": "steel",
             "ball_diameter_mm": 8.0, "ball_mass_g": 2.09, "channels": 4, "fs_hz": 100000, "samples": 800,
             "adc_bits": 16, "vref": 3.3, "bias_counts": 32768},
        sim=dict(e_pa=58e9, e2_pa=54e9, g12_pa=3.8e9, nu=0.05, material_axes_deg=90.0, pretrigger_samples=30,
                 damping_per_s=1200.0, density_kg_m3=1560.0),
        front_end=dict(gain_sign=-1.0, dc_offset_counts=-2300),
        heights=(50, 100, 150, 200, 250)),
    "ti-nonconvex": dict(
        # titanium on a long narrow plate, one sensor inside the triangle of the other three (a non-convex
        # layout: the hull is a triangle), 20 mm discs, a 62.5 kHz 12-bit logger keeping 16 ms before the hit,
        # a hot front end (the drops next to a sensor clip), 50 Hz hum, one sensor loose on a tenth of the drops
        rig={"plate_material": "Titanium Ti-6Al-4V (grade 5) sheet", "plate_x_mm": 600.0, "plate_y_mm": 260.0,
             "thickness_mm": 1.6, "density_kg_m3": 4430.0, "plate_support": "bolted at the four corners",
             "sensors": _sensors([(60, 40), (540, 50), (300, 220), (330, 95)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 20.0, "ball_material": "steel",
             "ball_diameter_mm": 15.0, "ball_mass_g": 13.8, "channels": 4, "fs_hz": 62500, "samples": 2500,
             "adc_bits": 12, "vref": 3.3, "bias_counts": 2048},
        sim=dict(e_pa=113.8e9, nu=0.342, pretrigger_samples=1000, damping_per_s=400.0),
        front_end=dict(peak_fraction=0.6),
        lab=dict(hum=25.0, hum_hz=50.0),
        loose=dict(channel=2, fraction=0.1, gain=0.5, hz=4000.0),
        heights=(40, 80, 120, 160, 200, 240)),
    "alu-large-thin": dict(
        # a large thin sheet (1200 x 800 x 1.5 mm aluminium: strongly dispersive, paths up to ~1 m), the four
        # sensors ~100 mm in from the corners but wired in no geometric order (channel 0 bottom-left, 1 top-right,
        # 2 bottom-right, 3 top-left: the diagonals), a low-rate 12-bit logger (50 kHz, 4096 samples, 1024 before
        # the hit), 60 Hz mains hum (a lab outside Europe), a hot front end (the drops next to a sensor clip),
        # 30 cases x 4 drops (run it with --cases 30 --reps 4)
        rig={"plate_material": "aluminium 1050A-H14 sheet", "plate_x_mm": 1200.0, "plate_y_mm": 800.0,
             "thickness_mm": 1.5, "density_kg_m3": 2710.0, "plate_support": "resting on four rubber feet",
             "sensors": _sensors([(104, 97), (1096, 706), (1101, 95), (97, 702)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 12.0, "ball_material": "steel",
             "ball_diameter_mm": 10.0, "ball_mass_g": 4.07, "channels": 4, "fs_hz": 50000, "samples": 4096,
             "adc_bits": 12, "vref": 3.3, "bias_counts": 2048},
        sim=dict(e_pa=69e9, nu=0.33, pretrigger_samples=1024, damping_per_s=250.0),
        front_end=dict(peak_fraction=0.5),
        lab=dict(hum=30.0, hum_hz=60.0),
        heights=(50, 100, 150, 200, 250, 300)),
    "wear-thick-side": dict(
        # a 10 mm plate of a steel the table does not know by its trade name (wide priors), fast and little
        # dispersive; the four sensors close together in one corner region (most of the plate outside their
        # hull), a 200 kHz 16-bit logger keeping 8000 samples (1000 before the hit), few drops (20 cases x 3),
        # rig.json with optional fields and an impacts.csv with the lab's own extra columns, reordered
        rig={"plate_material": "Hardox 450 wear plate", "plate_x_mm": 520.0, "plate_y_mm": 380.0,
             "thickness_mm": 10.0, "density_kg_m3": 7850.0, "plate_support": "resting on four rubber feet",
             "sensors": _sensors([(45, 50), (235, 40), (250, 200), (60, 215)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 10.0, "ball_material": "steel",
             "ball_diameter_mm": 16.0, "ball_mass_g": 16.7, "channels": 4, "fs_hz": 200000, "samples": 8000,
             "adc_bits": 16, "vref": 3.3, "bias_counts": 32768, "pretrigger_samples": 1000,
             "inner_region_mm": [60.0, 460.0, 50.0, 330.0],
             "board_front_end": {"anti_alias_hz": 20000, "anti_alias_poles": 4}},
        sim=dict(e_pa=207e9, nu=0.29, pretrigger_samples=1000, damping_per_s=300.0),
        impacts_csv=dict(extra={"operator": "AK", "ball_id": "B16-2", "notes": ""}, first=("x_mm", "y_mm")),
        heights=(100, 200, 300, 400)),
    "cfrp-ud-strip": dict(
        # a narrow unidirectional carbon/epoxy strip (E1/E2 ~14) with its fibres at 30 deg to the plate's x axis
        # (declared `material_axes`); 700 x 200 mm, so y is the short, ill-conditioned direction; the sensors on the
        # two long edges, two near each end, staggered; a 12.7 mm ball; a 250 kHz 14-bit logger keeping 10000
        # samples, 2000 of them (8 ms) before the hit (undeclared); a few drops hit twice (the strip's own
        # vibration throws the ball back onto it 0.5-3 ms later)
        rig={"plate_material": "unidirectional carbon/epoxy prepreg strip (T700/epoxy, UD)", "plate_x_mm": 700.0,
             "plate_y_mm": 200.0, "thickness_mm": 3.0, "density_kg_m3": 1570.0,
             "plate_support": "edges resting on a rubber rim",
             "material_axes": {"fibre_angle_deg": 30.0},
             "sensors": _sensors([(45, 18), (130, 184), (570, 16), (655, 182)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 10.0, "ball_material": "steel",
             "ball_diameter_mm": 12.7, "ball_mass_g": 8.42, "channels": 4, "fs_hz": 250000, "samples": 10000,
             "adc_bits": 14, "vref": 3.3, "bias_counts": 8192},
        sim=dict(e_pa=120e9, e2_pa=8.5e9, g12_pa=4.6e9, nu=0.31, material_axes_deg=30.0, pretrigger_samples=2000,
                 damping_per_s=800.0),
        double=dict(fraction=0.05, delay_ms=(0.5, 3.0), height_fraction=(0.1, 0.3)),
        heights=(25, 50, 80, 120, 170, 230)),
    "fr4-scope": dict(
        # a bare FR-4 circuit-board panel (woven glass-epoxy: nearly isotropic in-plane, 1.6 mm, thin and
        # dispersive), three sensors near one long edge and one near the middle of the other (not a rectangle;
        # without the far one the other three lie near one line), the channels wired in no geometric order, read by
        # a bench oscilloscope: 1 MHz x 20,000 samples, 8-bit, 4,000 samples before the trigger, each channel with
        # its own DC offset, 50 Hz hum on one channel only (its probe's ground loop), 25 cases x 4 drops
        # (run it with --cases 25 --reps 4)
        rig={"plate_material": "FR-4 glass-epoxy laminate", "plate_x_mm": 400.0, "plate_y_mm": 300.0,
             "thickness_mm": 1.6, "density_kg_m3": 1850.0, "plate_support": "four nylon standoffs at the corners",
             "sensors": _sensors([(335, 42), (205, 262), (62, 36), (198, 28)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 12.0, "ball_material": "steel",
             "ball_diameter_mm": 6.0, "ball_mass_g": 0.88, "channels": 4, "fs_hz": 1000000, "samples": 20000,
             "adc_bits": 8, "vref": 5.0, "bias_counts": 128},
        sim=dict(e_pa=24e9, e2_pa=21e9, g12_pa=5.5e9, nu=0.13, material_axes_deg=0.0, pretrigger_samples=4000,
                 damping_per_s=900.0),
        front_end=dict(peak_fraction=0.35, channel_dc_counts=(9, -14, 4, -6), noise_counts=0.4),
        hum_one=dict(channel=1, hum=3.0, hum_hz=50.0),
        heights=(80, 120, 160, 200, 250)),
    "glass-audio": dict(
        # a soda-lime glass tabletop (600 x 450 x 6 mm on four rubber pads: fast, and so lightly damped that it rings
        # through the whole record and beyond), sensors on an irregular quadrilateral turned ~12 deg, read by a
        # 4-channel USB audio interface: 96 kHz, 16-bit with a large full scale (the arrivals are small in counts),
        # AC-coupled (a first-order 10 Hz high-pass), a delta-sigma converter's linear-phase anti-alias FIR at
        # 43 kHz (it rings a little before each arrival), short records (4,096 samples, 512 before the hit), a
        # 10 mm nylon ball (a soft impactor: a longer contact, a lower band), 25 cases x 4 drops
        # (run it with --cases 25 --reps 4)
        rig={"plate_material": "soda-lime glass", "plate_x_mm": 600.0, "plate_y_mm": 450.0,
             "thickness_mm": 6.0, "density_kg_m3": 2500.0, "plate_support": "resting on four rubber pads",
             "sensors": _sensors([(118, 64), (532, 131), (488, 402), (71, 318)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 20.0, "ball_material": "nylon (PA66)",
             "ball_diameter_mm": 10.0, "ball_mass_g": 0.60, "channels": 4, "fs_hz": 96000, "samples": 4096,
             "adc_bits": 16, "vref": 20.0, "bias_counts": 32768},
        sim=dict(e_pa=71e9, nu=0.23, pretrigger_samples=512, damping_per_s=40.0, ball_e_pa=3.2e9, ball_nu=0.40,
                 duration_ms=37.5),
        front_end=dict(peak_fraction=0.012, noise_counts=2.0, highpass_hz=10.0, anti_alias_fir_hz=43000.0,
                       anti_alias_taps=127),
        heights=(50, 80, 110, 140, 170, 200)),
    "ss-strip-edge": dict(
        # a long narrow stainless-steel strip (850 x 280 x 1.5 mm, aspect 3.0: thin and dispersive), three sensors
        # along one long edge (staggered) and the fourth near one END of the other edge, so the hull is a skewed
        # triangle over one end and the far end is seen from outside it; the channels wired in no geometric order;
        # a small silicon-nitride ball (5 mm, 0.21 g) dropped from 20-100 mm (light hits: a weak, short, broad-band
        # contact), a fast 12-bit logger with a short record (500 kHz x 2,000 samples = 4 ms, 200 before the hit);
        # rig.json as a user writes it: the material by its grade, no density (the table's), no optional fields;
        # many drops (run it with --cases 60 --reps 3)
        rig={"plate_material": "stainless steel 1.4301 (AISI 304), 2B finish", "plate_x_mm": 850.0,
             "plate_y_mm": 280.0, "thickness_mm": 1.5, "plate_support": "resting on four rubber feet",
             "sensors": _sensors([(420, 30), (130, 232), (770, 42), (68, 38)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 10.0,
             "ball_material": "silicon nitride (Si3N4) bearing ball, grade 5",
             "ball_diameter_mm": 5.0, "ball_mass_g": 0.21, "channels": 4, "fs_hz": 500000, "samples": 2000,
             "adc_bits": 12, "vref": 3.3, "bias_counts": 2048},
        sim=dict(e_pa=193e9, nu=0.29, pretrigger_samples=200, damping_per_s=150.0, density_kg_m3=7930.0,
                 ball_e_pa=310e9, ball_nu=0.27),
        front_end=dict(peak_fraction=0.15),
        heights=(20, 35, 50, 65, 80, 100),
        # the truth's mesh: at 4 mm the 1.5 mm strip's first arrivals (up to ~250 kHz) travel ~6 % faster than
        # the converged plate's (the coarse mesh's dispersion), which calibrate's fast model reads as E and nu at
        # the steel entry's upper bounds (docs/findings.md, "Session 26: calbound")
        element_mm=2.0),
    "oak-table": dict(
        # a solid-oak tabletop (glued-up staves, 600 x 400 x 18 mm, grain along x: E_L/E_T ~ 12, a low in-plane
        # shear modulus, slow and damped) on four rubber feet, four 27 mm piezo buzzer discs on a parallelogram
        # (a sheared rectangle), a 12.7 mm steel ball, read by a 48 kHz 12-bit logger (2048 samples, 256 before
        # the hit): the material no kind ran, a rate that is no divisor of the board's (run it with --cases 40
        # --reps 3)
        rig={"plate_material": "European oak tabletop, glued-up staves", "plate_x_mm": 600.0, "plate_y_mm": 400.0,
             "thickness_mm": 18.0, "density_kg_m3": 690.0, "plate_support": "resting on four rubber feet",
             "material_axes": {"fibre_angle_deg": 0.0},
             "sensors": _sensors([(70, 60), (420, 45), (530, 340), (175, 352)]),
             "sensor_type": "piezo buzzer disc (brass-backed PZT)", "sensor_diameter_mm": 27.0,
             "ball_material": "steel", "ball_diameter_mm": 12.7, "ball_mass_g": 8.42, "channels": 4,
             "fs_hz": 48000, "samples": 2048, "adc_bits": 12, "vref": 3.3, "bias_counts": 2048},
        sim=dict(e_pa=12.5e9, e2_pa=1.05e9, g12_pa=0.85e9, nu=0.40, material_axes_deg=0.0, pretrigger_samples=256,
                 damping_per_s=900.0),
        heights=(50, 100, 150, 200, 250, 300)),
    "hdpe-kite": dict(
        # a 12 mm HDPE sheet (a machine-guard / cutting-board polymer: slow, heavily damped, its modulus at acoustic
        # rates well above the quasi-static figure), 500 x 400 mm on four rubber feet; sensors on no rectangle: two
        # near the bottom corners, one near the middle of the top edge, one on the left edge (a kite); a 10 mm
        # steel ball; a 50 kHz 14-bit logger (2500 samples, 300 before the hit) over 2.5 V; rig.json as a new user
        # writes it: no density (the table's), no optional field (run it with --cases 40 --reps 3)
        rig={"plate_material": "HDPE sheet (PE 300), natural", "plate_x_mm": 500.0, "plate_y_mm": 400.0,
             "thickness_mm": 12.0, "plate_support": "resting on four rubber feet",
             "sensors": _sensors([(48, 42), (455, 58), (262, 372), (30, 248)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 12.0, "ball_material": "steel",
             "ball_diameter_mm": 10.0, "ball_mass_g": 4.07, "channels": 4, "fs_hz": 50000, "samples": 2500,
             "adc_bits": 14, "vref": 2.5, "bias_counts": 8192},
        sim=dict(e_pa=1.6e9, nu=0.44, pretrigger_samples=300, damping_per_s=1400.0, density_kg_m3=955.0),
        heights=(50, 100, 150, 200, 250, 300)),
    "pvc-slowlog": dict(
        # a square 500 x 500 x 5 mm grey rigid-PVC sheet (slow, damped) on four rubber feet read by a low-rate logger
        # a microcontroller board gives: 20 kHz a channel (50 us a sample: the A0 arrivals move ~20 mm a sample),
        # 10 bits, 1024 samples of which 128 before the hit; sensors on an irregular quadrilateral; a 10 mm steel
        # ball from 50-300 mm; rig.json names the sheet by its trade grade, with its density (run it with --cases 40
        # --reps 3). The simulated truth holds nothing above the logger's Nyquist (an anti-aliased logger).
        rig={"plate_material": "grey PVC-U sheet (rigid PVC)", "plate_x_mm": 500.0, "plate_y_mm": 500.0,
             "thickness_mm": 5.0, "density_kg_m3": 1420.0, "plate_support": "resting on four rubber feet",
             "sensors": _sensors([(72, 85), (428, 58), (447, 412), (90, 436)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 12.0, "ball_material": "steel",
             "ball_diameter_mm": 10.0, "ball_mass_g": 4.07, "channels": 4, "fs_hz": 20000, "samples": 1024,
             "adc_bits": 10, "vref": 3.3, "bias_counts": 512},
        sim=dict(e_pa=3.3e9, nu=0.38, pretrigger_samples=128, damping_per_s=1000.0),
        heights=(50, 100, 150, 200, 250, 300)),
    "mg-clip": dict(
        # a drop-height sweep over 20:1 (50-1000 mm) on a 3 mm magnesium tooling plate, the logger's gain set on
        # the low drops, so the front end clips heavily from ~200 mm up: on the highest drops every channel sits on
        # its rails for hundreds of samples (the peak amplitude says nothing there); sensors on an asymmetric
        # trapezoid away from the corners; a 200 kHz 14-bit logger, 3000 samples of which 300 before the hit;
        # rig.json names the alloy by its grade and temper (run it with --cases 40 --reps 3)
        rig={"plate_material": "AZ31B-H24 magnesium tooling plate", "plate_x_mm": 450.0, "plate_y_mm": 350.0,
             "thickness_mm": 3.0, "density_kg_m3": 1770.0, "plate_support": "resting on four rubber feet",
             "sensors": _sensors([(85, 70), (330, 95), (300, 265), (140, 290)]),
             "sensor_type": "PZT disc", "sensor_diameter_mm": 10.0, "ball_material": "steel",
             "ball_diameter_mm": 8.0, "ball_mass_g": 2.09, "channels": 4, "fs_hz": 200000, "samples": 3000,
             "adc_bits": 14, "vref": 3.3, "bias_counts": 8192},
        sim=dict(e_pa=45e9, nu=0.35, pretrigger_samples=300, damping_per_s=500.0),
        front_end=dict(peak_fraction=1.6),
        heights=(50, 100, 200, 350, 550, 800, 1000),
        # at 4 mm the mesh resolves the 3 mm plate's A0 to 46 kHz of the contact's 98 kHz band; 2 mm resolves it all
        element_mm=2.0),
}


def cases(rig, n: int, heights, rng, edge_mm: float = 18.0, clearance_mm: float = 22.0):
    x, y = [], []
    sxy = np.array([[s["x_mm"], s["y_mm"]] for s in rig["sensors"]])
    while len(x) < n:
        px = rng.uniform(edge_mm, rig["plate_x_mm"] - edge_mm)
        py = rng.uniform(edge_mm, rig["plate_y_mm"] - edge_mm)
        if np.hypot(*(sxy - (px, py)).T).min() >= clearance_mm:
            x.append(px)
            y.append(py)
    return np.round(x, 1), np.round(y, 1), rng.choice(np.asarray(heights, float), n)


def _lab_columns(out: str, extra: dict, first: tuple) -> None:
    import csv
    from pathlib import Path

    path = Path(out) / "impacts.csv"
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    names = [*first, *(c for c in rows[0] if c not in first), *extra]
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=names)
        w.writeheader()
        w.writerows({**r, **extra} for r in rows)


def sim_duration_ms(rig, pretrigger_samples: int, default_ms: float) -> float:
    """The simulated span after the touch: at least what calibrate's envelope-decay window reads
    (calibration.damping.DECAY_DURATION_MS) where the record keeps that much after the hit. A shorter truth fades
    out (the simulator's taper) inside that window and the session's ring-down reads ~2-3x too fast."""
    from impactsense.calibration.damping import DECAY_DURATION_MS

    after_ms = (rig.samples - pretrigger_samples) / rig.fs_hz * 1e3
    return max(default_ms, min(DECAY_DURATION_MS, after_ms))


def _filtered_adc(volts, params, logger, front, seed) -> np.ndarray:
    """An AC-coupled logger with a linear-phase anti-alias filter (an audio interface): the noise-free record
    (volts placed as `to_adc` places them) through a first-order high-pass at `highpass_hz` (the input's coupling
    capacitor: the baseline sags after a large hit) and a centred linear-phase FIR low-pass at `anti_alias_fir_hz`
    (a delta-sigma converter's decimation filter: it rings a little before each arrival), then the noise, rounded
    and clipped at the rails."""
    from scipy import ndimage
    from scipy import signal as sps

    n, c, n_sim = volts.shape
    start = params.pretrigger_samples
    rec = np.zeros((n, c, logger.samples))
    take = min(n_sim, logger.samples - start)
    rec[:, :, start:start + take] = volts[:, :, :take]
    x = params.circuit_gain * rec * (2 ** logger.adc_bits) / logger.vref
    if front.get("highpass_hz"):
        b, a = sps.butter(1, front["highpass_hz"], "highpass", fs=logger.fs_hz)
        x = sps.lfilter(b, a, x, axis=-1)
    if front.get("anti_alias_fir_hz"):
        taps = sps.firwin(int(front.get("anti_alias_taps", 127)), front["anti_alias_fir_hz"], fs=logger.fs_hz)
        x = ndimage.convolve1d(x, taps, axis=-1, mode="constant")
    x = x + np.random.default_rng(seed).normal(0.0, params.noise_counts_rms, x.shape)
    return np.clip(np.rint(logger.bias_counts + x), 0, logger.adc_max).astype(np.uint16)


# An A0 wavelength resolved by fewer elements than this carries the mesh's numerical dispersion into the picks
# (docs/findings.md "Session 26: stripfit": on ss-strip-edge the travel fit's dispersion exponent follows the mesh).
RESOLVED_ELEMENTS_PER_WAVELENGTH = 6.0


def mesh_note(params, rig) -> str | None:
    """A line saying the mesh is coarse for the logger's band, or None: the highest frequency whose A0 wavelength
    (the softest direction's) spans RESOLVED_ELEMENTS_PER_WAVELENGTH elements against the band Eq. 1 meshes for
    (the contact's spectrum, at most the logger's Nyquist); above it the simulated arrivals' speed is the mesh's,
    not the plate's."""
    from scipy.optimize import brentq

    from impactsense.sim.model import mesh_element_m, mesh_size

    f_max, _, _, hx, hy = mesh_size(params, rig)
    element = max(hx, hy)
    per_wavelength = lambda f: 10.0 * mesh_element_m(params, f) / element - RESOLVED_ELEMENTS_PER_WAVELENGTH
    if per_wavelength(f_max) >= 0:
        return None
    f_ok = brentq(per_wavelength, 1.0, f_max) if per_wavelength(1.0) > 0 else 0.0
    eq1 = mesh_element_m(params, f_max)
    return (f"mesh {element * 1e3:.2g} mm (Eq. 1: {eq1 * 1e3:.2g} mm for {f_max / 1e3:.0f} kHz): A0 resolved "
            f"({RESOLVED_ELEMENTS_PER_WAVELENGTH:g} elements a wavelength) up to {f_ok / 1e3:.0f} kHz only; picks "
            f"above it travel at the mesh's speed, not the plate's (--element-mm smaller to resolve them)")


def make(kind: str, out: str, n_cases: int, reps: int, seed: int, element_mm: float) -> None:
    from impactsense.data import rig_from_dict, write_session
    from impactsense.faults import FaultSpec, inject
    from impactsense.sim import SimParams, simulate_voltages, to_adc

    spec = KINDS[kind]
    raw = dict(spec["rig"], notes=f"SYNTHETIC rig ({kind}) made by benchmarks/synthetic_rig.py, seed {seed}")
    sim = dict(spec["sim"])
    # the simulated truth's density (a rig.json may leave it out), the logger's wiring sign and DC error
    rig = rig_from_dict(dict(raw, density_kg_m3=sim.pop("density_kg_m3", raw.get("density_kg_m3"))))
    front = {"gain_sign": 1.0, "dc_offset_counts": 0, "peak_fraction": 0.25, **spec.get("front_end", {})}
    rng = np.random.default_rng(seed)
    cx, cy, ch = cases(raw, n_cases, spec["heights"], rng)
    case_id = np.repeat(np.arange(n_cases), reps)
    rep = np.tile(np.arange(reps), n_cases)
    x, y, h = cx[case_id], cy[case_id], ch[case_id]
    # hand-release scatter: where the ball really lands
    xt = np.clip(x + rng.normal(0, 1.0, x.size), 1, rig.plate_x_mm - 1)
    yt = np.clip(y + rng.normal(0, 1.0, y.size), 1, rig.plate_y_mm - 1)
    params = SimParams.from_rig(rig).replace(element_mm=element_mm, max_height_mm=float(max(spec["heights"])),
                                             **sim)
    params = params.replace(duration_ms=sim_duration_ms(rig, params.pretrigger_samples, params.duration_ms))
    note = mesh_note(params, rig)
    if note:
        print(f"{kind}: {note}")
    t0 = time.perf_counter()
    volts = simulate_voltages(params, rig, xt, yt, h, workers=2, progress=True)["volts"]
    double = spec.get("double")
    if double:   # a second contact on a few drops: the same spot, a fraction of the height, a little later
        rows = np.sort(rng.choice(x.size, max(1, round(double["fraction"] * x.size)), replace=False))
        delay = np.rint(rng.uniform(*double["delay_ms"], rows.size) * 1e-3 * rig.fs_hz).astype(int)
        frac = rng.uniform(*double["height_fraction"], rows.size)
        second = simulate_voltages(params, rig, xt[rows] + rng.normal(0, 0.5, rows.size),
                                   yt[rows] + rng.normal(0, 0.5, rows.size), h[rows] * frac, workers=2)["volts"]
        for k, (r, d) in enumerate(zip(rows, delay)):
            volts[r, :, d:] += second[k, :, :volts.shape[2] - d]
        print(f"{kind}: second hits on rows {rows.tolist()} ({np.round(delay / rig.fs_hz * 1e3, 2).tolist()} ms "
              f"later, {np.round(frac, 2).tolist()} of the height)")
    peak = np.median(np.abs(volts).max(axis=2))
    gain = front["gain_sign"] * front["peak_fraction"] * (rig.adc_max / 2) * rig.vref / (peak * 2 ** rig.adc_bits)
    params = params.replace(circuit_gain=float(gain),
                            noise_counts_rms=front.get("noise_counts", 1.5 * 2 ** (rig.adc_bits - 12)))
    logger = rig if not front["dc_offset_counts"] else dataclasses.replace(
        rig, bias_counts=rig.bias_counts + int(front["dc_offset_counts"]))
    if front.get("highpass_hz") or front.get("anti_alias_fir_hz"):
        adc = _filtered_adc(volts, params, logger, front, seed)
    else:
        adc = to_adc(volts, params, logger, noise=True, seed=seed)
    if "channel_dc_counts" in front:   # each channel's own DC error (a scope's per-channel offset)
        dc = np.asarray(front["channel_dc_counts"], float)[None, :, None]
        adc = np.clip(adc.astype(float) + dc, 0, rig.adc_max).astype(adc.dtype)
    faults = FaultSpec(offset=6.0 * 2 ** (rig.adc_bits - 12), glitch=0.05, drift=0.02, seed=seed + 1,
                       **spec.get("lab", {}))
    adc = inject(adc, faults, rig.fs_hz, rig.bias_counts, rig.adc_max)
    one = spec.get("hum_one")
    if one:   # mains hum on one channel only (one probe's ground loop)
        k = one["channel"]
        adc[:, k:k + 1] = inject(adc[:, k:k + 1], FaultSpec(hum=one["hum"], hum_hz=one["hum_hz"], seed=seed + 3),
                                 rig.fs_hz, rig.bias_counts, rig.adc_max)
        print(f"{kind}: {one['hum_hz']:g} Hz hum of up to {one['hum']:g} counts on channel {k} only")
    loose = spec.get("loose")
    if loose:   # one sensor loose on a few drops: its signal low-passed and weaker there
        rows = np.sort(rng.choice(adc.shape[0], max(1, round(loose["fraction"] * adc.shape[0])), replace=False))
        adc[rows] = inject(adc[rows], FaultSpec(debond=loose["channel"], debond_gain=loose["gain"],
                                                debond_hz=loose["hz"], seed=seed + 2),
                           rig.fs_hz, rig.bias_counts, rig.adc_max)
        print(f"{kind}: channel {loose['channel']} loose on rows {rows.tolist()}")
    write_session(out, raw, x, y, h, adc, case_id=case_id, repetition=rep, force=True)
    if "impacts_csv" in spec:   # the lab's own columns beside the format's, in the lab's order
        _lab_columns(out, **spec["impacts_csv"])
    print(f"{kind}: {x.size} drops in {time.perf_counter() - t0:.0f} s, circuit gain {gain:.4g}, "
          f"median peak {np.median(np.abs(adc.astype(int) - logger.bias_counts).max(axis=2)):.0f} counts -> {out}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kind", choices=sorted(KINDS))
    ap.add_argument("--out", required=True)
    ap.add_argument("--cases", type=int, default=40)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--element-mm", type=float, default=None,
                    help="the truth's FEM element size (default: the kind's, else 4 mm)")
    a = ap.parse_args(argv)
    element_mm = a.element_mm if a.element_mm is not None else KINDS[a.kind].get("element_mm", 4.0)
    make(a.kind, a.out, a.cases, a.reps, a.seed, element_mm)
    return 0


if __name__ == "__main__":
    sys.exit(main())
