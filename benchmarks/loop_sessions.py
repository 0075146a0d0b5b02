"""Test sessions for the closed loop: one known change each, made from physics, plus unchanged controls.

    python3 benchmarks/loop_sessions.py [--out /tmp/impactsense-loop] [--seed 0] [--cases 40] [--ref-cases 80] [--reps 3]
        [--element-mm 3.0] [--duration-ms 10] [--rig SESSION_DIR] [--calibration CAL.json] [--only NAME,NAME]
        [--noise-counts C,C] [--controls] [--oracles] [--seed-only-draw]

Every session is a folder every tool reads (rig.json = the DECLARED rig, impacts.csv = the declared
positions, recordings.npz), and `manifest.json` in OUT lists each one's truth:

- `ref`                   the reference session (the twin of the rig as declared)
- `same-1 .. same-5`      unchanged: other positions, other position jitter and noise draws
- `<name>-control`        (`--controls`) a changed session's own drops (positions, jitter, noise seed) without
                          its change: the unchanged MAE at the same positions
- `<name>-oracle`         (`--oracles`) the reference's own drops (positions, jitter, noise seed) recorded WITH a
                          changed session's change: the training data a retrain that knew the change exactly would
                          have (the upper bound of any retrain on the reference's drops)
- `move-<deg>`            FEM: one sensor glued 5-10 mm away in direction <deg> (0, 45, ..., 315 on seed 0;
                          another seed rotates the eight and permutes the sensors), rig.json
                          still declaring the old centre; the sensor rotates with the direction, so some moves
                          point along the sensor's look direction (nearly a constant delay) and some across
- `stiffness`             FEM: plate E -8 % (another seed: -6 .. -10 %)
- `damping`               FEM: plate damping D_s +20 % (another seed: +15 .. +25 %)
- `bond`                  one disc's compliant bond, made by the FEM: the plate's strain reaches the disc through the
                          bond's stiffness in series with the disc's (`sim.bond.DiscBond`: a first-order strain
                          transfer with a gain loss, in continuous time before the recorder samples it; the truth's
                          fc_hz and gain are its -3 dB corner and low-frequency gain); not a digital filter of the
                          recorded samples
- `delay`                 a disc's analogue signal delayed before the recorder samples it (the FEM's fast path
                          with the disc's reciprocity run shifted: `sim.simulate.delayed_fields`), as a channel
                          skew does; not a shift of the recorded samples (their onset is aliased on a thin metal
                          plate, and a spline or FFT shift of them reads 1.4 x a fraction of a sample)
- `gain`, `hum`, `noise`  signal level on FEM drops: a channel's gain, 50 Hz mains on every channel, extra white
                          noise
- `noise-<C>`             (`--noise-counts C,C`) extra white noise of C counts rms, other drops and draws
Signal-level changes act on the clean FEM signal; the rig's noise and the ADC's rounding come after (a
delay or a bond acts on the disc's signal, not on the amplifier's noise).

Nothing here calls the effect library (`impactsense.effects`): the changes are made by the FEM or by signal
operations written here, so a diagnosis that recovers them is not fitting its own forward model.
Drops: `--cases` positions (Sobol, away from edges and sensors) x `--reps` repetitions, each repetition hit
within `--jitter-mm` (rms) of the declared position; heights 100..200 mm. FEM cost: one plate model per
physical variant (the base, 8 moves, E, D_s) at `--element-mm` (3 mm: ~10-20 s a model on a quiet core).
Sessions already in OUT with the same settings are kept (cache).

Draws: every number drawn (the changes' sizes, directions and sensors, each session's positions, landing jitter,
rig noise and signal-level change) comes from the seed AND the declared rig: `draw_seed(seed, rig)` is a
SeedSequence of (seed, `rig_key(rig)`: a hash of the plate's material, size and thickness and the sensors'
positions), so `--seed S` on two rigs gives two draws, and the same rig.json gives the same draw anywhere.
Seed 0's layout (the compass directions, sensor j % 4, E -8 %, D_s +20 %) stays the canonical one on every rig;
its sizes are drawn. Before session 23 every draw came from the seed alone (both rigs got one draw):
`--seed-only-draw` remakes those sessions (docs/findings.md's earlier tables).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

DIRECTIONS_DEG = tuple(range(0, 360, 45))
N_SAME = 5


def rig_key(rig) -> int:
    """The declared rig's share of every draw: a 32-bit hash of its plate (material, size, thickness) and its
    sensors' positions (what makes it another rig; not its free-text notes or the logger's bias)."""
    desc = {"plate": [str(rig.plate_material)] + [round(float(v), 3) for v in
                                                  (rig.plate_x_mm, rig.plate_y_mm, rig.thickness_mm)],
            "sensors": [[round(float(s.x_mm), 3), round(float(s.y_mm), 3)] for s in rig.sensors]}
    return int.from_bytes(hashlib.sha256(json.dumps(desc, sort_keys=True).encode()).digest()[:4], "big")


def draw_seed(seed: int, rig=None) -> int:
    """The integer every draw of `--seed seed` on `rig` starts from: SeedSequence((seed, rig_key(rig))) folded to
    31 bits (each session's streams are this + a small offset, as the seed alone was before). rig None: the seed
    alone (the draws before session 23, `--seed-only-draw`)."""
    if rig is None:
        return int(seed)
    state = np.random.SeedSequence([int(seed), rig_key(rig)]).generate_state(1, dtype=np.uint32)[0]
    return int(state) % 2**31


def layout_draw(seed: int, base: int | None = None) -> tuple[float, list[int], float, float]:
    """(rotation of the 8 move directions in deg, the sensor moved in direction j (sensors[j % 4]), E scale,
    D_s scale). Seed 0 is the canonical layout of docs/findings.md's tables (the compass directions, sensor j % 4,
    E -8 %, D_s +20 %) on every rig; any other seed draws them from `base` (`draw_seed`; default the seed alone)
    in its own stream, so the sizes drawn in spec_list are the same numbers either way: directions rotated by up
    to +-22.5 deg, the sensors permuted, E -6 .. -10 %, D_s +15 .. +25 %."""
    if seed == 0:
        return 0.0, [0, 1, 2, 3], 0.92, 1.20
    rng = np.random.default_rng((seed if base is None else base) + 2000)
    offset = round(float(rng.uniform(-22.5, 22.5)), 1)
    sensors = [int(k) for k in rng.permutation(4)]
    return offset, sensors, round(float(1 - rng.uniform(0.06, 0.10)), 4), round(float(1 + rng.uniform(0.15, 0.25)), 4)


def spec_list(seed: int, noise_counts=(), rig=None) -> list[dict]:
    """Every session's truth (drawn from `seed` and `rig` (`draw_seed`; rig None: the seed alone): the kinds are
    fixed, the sizes and sensors are drawn; each session's "seed" starts its drops' and noise's streams); with
    noise_counts, a white-noise session `noise-<counts>` more at each of those levels (its own drops and draw)."""
    user_seed, seed = seed, draw_seed(seed, rig)
    rng = np.random.default_rng(seed + 1000)
    offset_deg, sensors, e_scale, damping_scale = layout_draw(user_seed, seed)
    specs = [{"name": "ref", "kind": "none", "seed": seed}]
    specs += [{"name": f"same-{k}", "kind": "none", "seed": seed + k} for k in range(1, N_SAME + 1)]
    for j, deg0 in enumerate(DIRECTIONS_DEG):
        r = float(rng.uniform(5.0, 10.0))
        deg = (deg0 + offset_deg) % 360
        th = np.deg2rad(deg)
        specs.append({"name": f"move-{int(round(deg)) % 360}", "kind": "fem", "seed": seed + 10 + j,
                      "truth": {"effect": "sensor_position", "sensor": sensors[j % 4],
                                "params": {"dx_mm": round(r * np.cos(th), 3), "dy_mm": round(r * np.sin(th), 3)}}})
    specs.append({"name": "stiffness", "kind": "fem", "seed": seed + 20,
                  "truth": {"effect": "wave_speed", "sensor": None, "params": {"e_scale": e_scale}}})
    specs.append({"name": "damping", "kind": "fem", "seed": seed + 21,
                  "truth": {"effect": "damping", "sensor": None, "params": {"damping_scale": damping_scale}}})
    specs.append({"name": "bond", "kind": "signal", "seed": seed + 22, "made": "analogue bond (FEM)",
                  "truth": {"effect": "channel_lowpass", "sensor": int(rng.integers(4)),
                            "params": {"fc_hz": round(float(rng.uniform(2500, 5000)), 1),
                                       "gain": round(float(rng.uniform(0.6, 0.8)), 3)}}})
    specs.append({"name": "delay", "kind": "signal", "seed": seed + 23, "made": "analogue skew (FEM)",
                  "truth": {"effect": "channel_delay", "sensor": int(rng.integers(4)),
                            "params": {"delay_us": round(float(rng.choice([-1, 1]) * rng.uniform(4, 9)), 2)}}})
    specs.append({"name": "gain", "kind": "signal", "seed": seed + 24,
                  "truth": {"effect": "sensor_gain", "sensor": int(rng.integers(4)),
                            "params": {"gain": round(float(rng.uniform(0.7, 0.85)), 3)}}})
    specs.append({"name": "hum", "kind": "signal", "seed": seed + 25,
                  "truth": {"effect": "noise", "sensor": None,
                            "params": {"hum_hz": 50.0, "hum_counts": round(float(rng.uniform(15, 40)), 1)}}})
    specs.append({"name": "noise", "kind": "signal", "seed": seed + 26,
                  "truth": {"effect": "noise", "sensor": None,
                            "params": {"noise_counts_rms": round(float(rng.uniform(5, 10)), 2)}}})
    for k, c in enumerate(noise_counts):
        specs.append({"name": f"noise-{c:g}", "kind": "signal", "seed": seed + 30 + k,
                      "truth": {"effect": "noise", "sensor": None, "params": {"noise_counts_rms": float(c)}}})
    return specs


def control_specs(specs: list[dict], only=None) -> list[dict]:
    """`<name>-control` per changed session (of `only`, when given): the same declared drops, landing jitter and
    noise seed recorded WITHOUT the change (the unchanged session at the changed one's own positions: a session's
    MAE depends on where its 40 cases fell)."""
    return [{"name": f"{s['name']}-control", "kind": "none", "seed": s["seed"], "control_of": s["name"]}
            for s in specs if s.get("truth") and (only is None or s["name"] in only)]


def oracle_specs(specs: list[dict], only=None) -> list[dict]:
    """`<name>-oracle` per changed session (of `only`, when given): the reference's declared drops, landing jitter
    and noise seed recorded WITH the change (the change's truth, as the changed session was made)."""
    ref = next(s for s in specs if s["name"] == "ref")
    return [{"name": f"{s['name']}-oracle", "kind": s["kind"], "seed": ref["seed"], "truth": s["truth"],
             "oracle_of": s["name"], **({"made": s["made"]} if "made" in s else {})}
            for s in specs if s.get("truth") and (only is None or s["name"] in only)]


# ---- signal-level changes (independent of impactsense.effects) ------------------------------------------
def signal_change(counts: np.ndarray, truth: dict, rig, seed: int) -> np.ndarray:
    """The change on clean counts (float, bias removed) of the FEM drops: before the noise, as on a rig
    (a delay, a bond or a gain acts on the disc's signal; the amplifier and ADC noise comes after)."""
    rng = np.random.default_rng(seed + 77)
    a = counts.copy()
    p, s = truth["params"], truth["sensor"]
    if truth["effect"] in ("channel_delay", "channel_lowpass"):
        pass   # made by the FEM (make_session: disc_delays, disc_bonds)
    elif truth["effect"] == "sensor_gain":
        a[:, s] *= p["gain"]
    elif "hum_hz" in p:
        t = np.arange(a.shape[-1]) / rig.fs_hz
        ph = rng.uniform(0, 2 * np.pi, (a.shape[0], 1, 1))
        amp = p["hum_counts"] * rng.uniform(0.8, 1.2, (1, a.shape[1], 1))
        a += amp * np.sin(2 * np.pi * p["hum_hz"] * t + ph)
    elif "noise_counts_rms" in p:
        a += rng.normal(0.0, p["noise_counts_rms"], a.shape)
    return a



def without_change(adc: np.ndarray, spec: dict, rig) -> np.ndarray | None:
    """A `signal` session's recordings with its additive change (hum, white noise) taken out again: the same
    drops, rig noise and rails as made, the change's exact draw subtracted (`signal_change` on zeros with the
    session's seed; the ADC's rounding leaves at most half a count). None for any other session."""
    truth = spec.get("truth") or {}
    if spec.get("kind") != "signal" or truth.get("effect") != "noise":
        return None
    change = signal_change(np.zeros(adc.shape), truth, rig, spec["seed"])
    return np.clip(np.rint(np.asarray(adc, float) - change), 0, rig.adc_max).astype(np.uint16)

# ---- drops ------------------------------------------------------------------------------------------------
def declared_drops(rig, cases: int, reps: int, seed: int, jitter_mm: float):
    """Declared (x, y, h, case, rep) and the true hit positions (declared + jitter)."""
    from impactsense.sim.doe import virtual_drops

    x, y, h = virtual_drops(rig, cases, seed, 20.0, 32.0)
    rng = np.random.default_rng(seed + 5)
    case = np.repeat(np.arange(cases), reps)
    rep = np.tile(np.arange(reps), cases)
    xd, yd, hd = x[case], y[case], h[case]
    xt = xd + rng.normal(0, jitter_mm, xd.size)
    yt = yd + rng.normal(0, jitter_mm, yd.size)
    return xd, yd, hd, case, rep, xt, yt


def physical(params, rig, truth):
    """(SimParams, rig) of the changed plate: the rig.json a moved sensor really has, E or D_s scaled."""
    from impactsense.data import rig_from_dict

    if truth is None:
        return params, rig
    p = truth["params"]
    if truth["effect"] == "sensor_position":
        raw = json.loads(json.dumps(rig.to_dict()))
        sen = raw["sensors"][truth["sensor"]]
        sen["x_mm"] += p["dx_mm"]
        sen["y_mm"] += p["dy_mm"]
        return params, rig_from_dict(raw)
    if "e_scale" in p:
        return dataclasses.replace(params, e_pa=params.e_pa * p["e_scale"]), rig
    if "damping_scale" in p:
        return dataclasses.replace(params, damping_per_s=params.damping_per_s * p["damping_scale"]), rig
    return params, rig


def disc_delays(truth, rig):
    """A channel delay's time skew per disc (s), or None."""
    if truth is None or truth["effect"] != "channel_delay":
        return None
    d = [0.0] * len(rig.sensors)
    d[truth["sensor"]] = truth["params"]["delay_us"] * 1e-6
    return d


def disc_bonds(truth, rig):
    """A bond's `DiscBond` per disc (None: rigid), or None."""
    from impactsense.sim.bond import DiscBond

    if truth is None or truth["effect"] != "channel_lowpass":
        return None
    bonds = [None] * len(rig.sensors)
    bonds[truth["sensor"]] = DiscBond.from_gain_corner(truth["params"]["gain"], truth["params"]["fc_hz"])
    return bonds


def make_session(spec: dict, base_params, rig, args) -> np.ndarray:
    from impactsense.sim import simulate_drops
    from impactsense.sim.simulate import simulate_voltages, to_adc

    truth = spec.get("truth")
    cases = args.ref_cases if spec["name"] == "ref" or spec.get("oracle_of") else args.cases
    xd, yd, hd, case, rep, xt, yt = declared_drops(rig, cases, args.reps, spec["seed"], args.jitter_mm)
    params, sim_rig = physical(base_params, rig, truth if spec["kind"] == "fem" else None)
    if spec["kind"] != "signal":
        adc = simulate_drops(params, sim_rig, xt, yt, hd, noise=True, seed=spec["seed"], workers=args.workers,
                             progress=False)
    else:   # the change on the clean signal, then the rig's own noise and the ADC's rounding and rails
        volts = simulate_voltages(params, sim_rig, xt, yt, hd, workers=args.workers,
                                  disc_delays_s=disc_delays(truth, rig), disc_bonds=disc_bonds(truth, rig))["volts"]
        clean = to_adc(volts, params, sim_rig, noise=False, clip=False).astype(np.float64) - rig.bias_counts
        a = signal_change(clean, truth, rig, spec["seed"])
        a += np.random.default_rng(spec["seed"]).normal(0.0, params.noise_counts_rms, a.shape)
        adc = np.clip(np.rint(a + rig.bias_counts), 0, rig.adc_max).astype(np.uint16)
    return (xd, yd, hd, case, rep), adc


def file_digest(path) -> str:
    """The content's hash: a session folder's cache key must not change with the checkout it is built from."""
    import hashlib

    if str(path) == "rig" or not Path(path).is_file():
        return str(path)
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def settings_key(args, rig) -> dict:
    return {"cases": args.cases, "ref_cases": args.ref_cases, "reps": args.reps, "element_mm": args.element_mm, "jitter_mm": args.jitter_mm,
            "duration_ms": args.duration_ms, "signal_change": "before the noise",
            "rig": repr(rig), "calibration": file_digest(args.calibration), "seed": args.seed,
            "draw": "seed" if args.seed_only_draw else f"seed and rig {rig_key(rig)}"}


def twin_params(params, args):
    """The twin's SimParams at the benchmark's mesh and simulated window (the generator's and the loop's)."""
    return dataclasses.replace(params, element_mm=args.element_mm, method="fast", duration_ms=args.duration_ms)


def base_params(args, rig):
    """The twin's SimParams: a calibration file's, or (`--calibration rig`) the rig's own material defaults
    (`SimParams.from_rig`: an uncalibrated twin of any rig)."""
    from impactsense.sim import SimParams

    if args.calibration == "rig":
        return SimParams.from_rig(rig)
    cal = json.loads(Path(args.calibration).read_text())
    return SimParams.from_dict(cal["sim_params"], str(args.calibration))


def generate(args) -> dict:
    from impactsense.data import load_session, write_session

    rig = load_session(args.rig).rig
    base = twin_params(base_params(args, rig), args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    man_path = out / "manifest.json"
    man = json.loads(man_path.read_text()) if man_path.exists() else {}
    key = settings_key(args, rig)
    if man.get("settings") != key:
        man = {"settings": key, "sessions": {}}
    only = set(args.only.split(",")) if args.only else None
    specs = spec_list(args.seed, args.noise_counts, None if args.seed_only_draw else rig)
    extra = (control_specs(specs, only) if args.controls else []) + (oracle_specs(specs, only) if args.oracles else [])
    specs = specs + extra
    for spec in specs:
        if only and spec["name"] not in only and spec.get("control_of") not in only \
                and spec.get("oracle_of") not in only:
            continue
        if man["sessions"].get(spec["name"]) == spec and (out / spec["name"] / "recordings.npz").exists():
            continue
        print(f"  {spec['name']}: {spec.get('truth', 'unchanged')}", flush=True)
        (xd, yd, hd, case, rep), adc = make_session(spec, base, rig, args)
        write_session(out / spec["name"], rig, xd, yd, hd, adc, case, rep)
        man["sessions"][spec["name"]] = spec
        man_path.write_text(json.dumps(man, indent=1))
    return man


def parse(argv=None):
    from impactsense.data import bundled_session_path

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="/tmp/impactsense-loop")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", type=int, default=40)
    ap.add_argument("--ref-cases", type=int, default=80, help="positions of the reference session")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--jitter-mm", type=float, default=1.0)
    ap.add_argument("--element-mm", type=float, default=3.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--duration-ms", type=float, default=10.0,
                    help="simulated time after the first touch (the decay observable reads 1-8 ms after the onset)")
    ap.add_argument("--rig", default=str(bundled_session_path("session-1")), help="session folder whose rig.json is used")
    ap.add_argument("--calibration", default=None,
                    help="CAL.json, or 'rig' for the rig's material defaults (default: the bundled twin for the "
                         "bundled rig, 'rig' for any other --rig)")
    ap.add_argument("--only", default=None, help="comma-separated session names")
    ap.add_argument("--controls", action="store_true",
                    help="also `<name>-control` per changed session: its own drops without the change")
    ap.add_argument("--oracles", action="store_true",
                    help="also `<name>-oracle` per changed session: the reference's drops recorded with the change")
    ap.add_argument("--seed-only-draw", action="store_true",
                    help="draw from the seed alone, as before session 23 (every rig the same draw): remakes the "
                         "sessions of earlier findings tables")
    ap.add_argument("--noise-counts", type=lambda v: [float(c) for c in v.split(",")], default=[],
                    metavar="C,C", help="white-noise sessions more (noise-<C>), one at each level (counts rms)")
    args = ap.parse_args(argv)
    if args.calibration is None:
        bundled = Path(bundled_session_path("session-1"))
        args.calibration = str(bundled.parent / "twin" / "calibration.json") \
            if Path(args.rig).resolve() == bundled.resolve() else "rig"
    return args


def main(argv=None) -> int:
    args = parse(argv)
    man = generate(args)
    print(f"{len(man['sessions'])} sessions in {args.out} (manifest.json)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
