"""The "after" of the loop: diagnosed effects into the twin (plate and sensors in the FEM) and into recordings.

`diagnose` names effects on the residual reference; here they become physics again:
- in the FEM twin: `sensor_position` moves the disc in the simulated rig; `wave_speed` scales the plate's E
  by the picks' own law v ~ E^n: a pick is not one frequency's arrival. At a fixed frequency the A0 group
  velocity goes as E^n, n between 1/4 (thin plate) and 1/2 (shear limit) (`e_scale_for_speed`: the
  frequency f* where the twin's v_g(f*) equals the pick velocity); but a stiffer plate also shifts the cycle
  a threshold or AIC onset catches (a thin plate's whole response scales in time as E^(-1/2); the source's
  and the disc's bands hold the frequency back), so the picks' n lies between, and it depends on the
  distances and the noise, and it is not smooth in E. `plate_scan.e_scale_scan` reads E off the twin's own
  pick-velocity curve on DATA_NEW's declared drops (`size_plate_change` puts it into the effect, `corrected_twin`
  reads it); `damping` scales the twin's mass-proportional D_s as the twin's own decay curve reads the data
  (`plate_scan.damping_scale_scan`, put in by `size_plate_change`), without it by twice the
  envelope's extra log-decay rate (every mode decays as exp(-D_s t / 2));
- at the signal level (after the simulation, or on measured recordings): gains, low-pass, noise, clipping, by
  each effect's own `apply_signal`;
- in the model's picks: a diagnosed `channel_delay` is not put into the training recordings. The retrained model
  subtracts it from that channel's picks at inference (`with_channel_delays`: its rig_delay_us and band_delay_us,
  on top of the delays its localiser fitted on the training drops), as the core subtracts any rig delay. A
  constant delay is then taken out exactly for whatever cycle the picks catch; a sample shift of the training
  recordings by a fraction of a sample is not the analogue delay where the onset is sampled near the Nyquist
  rate (the shifted samples' picks move by a drop-dependent amount the session's picks do not share).
`twin_training_session` simulates DATA_REF's declared drops with the corrected twin: the training data of a
model that needs no new drops (zero-shot from the corrected twin).

A diagnosed noise floor is random: one draw per reference drop shows the forests one pick scatter per drop,
so `measured_training_session` puts NOISE_DRAWS independent draws of it into copies of every drop (same case,
so a case split keeps the copies together). And a raised floor changes which onset threshold gives stable
picks: `pick_settings` re-chooses the core's noise-relative threshold (`onset_noise_factor`, a few fractions
of the configured one) on those training drops by the travel fit's spread (`travel.choose_threshold`, which
chooses the absolute threshold and AIC blend with it). Measured: docs/findings.md (issue 16).
More draws at the same positions do not give the forests what a noisy pick takes: their correction of the
physics position needs more DISTINCT positions when the picks scatter. With a twin (a calibration, or the site
map's twin), `measured_training_session` adds the twin's drops at new positions over the reference's region
(`twin_positions`) until the training data holds TWIN_TRAINING_POSITIONS distinct positions, one drop each, with
every diagnosed effect put in as the
twin path puts it (`twin_drops`: plate and sensor effects in the FEM, the rest, the noise's own draw included,
at the signal level).

A partly debonded disc (a gain loss, with or without a low-pass named on its channel) is not only a gain: the
bond's low-pass tilts the channel's spectrum, so the twin's difference energies of that channel fall more than
its arrival energy and a model trained on a gain alone leaves the channel out. `fit_bond` sizes the bond on the
recordings themselves: the channel_lowpass (first or second order, a grid of cut-offs, or none; the noise given
back or filtered with it) whose signal model, put into a sample of DATA_REF's drops with the diagnosed gain, gives
the channel the median spectral tilt (Delta^1..3 over the arrival energy, the core's twin features) and onset
(against the travel model) DATA_NEW shows; the gain is the diagnosed one with the arrival energy the low-pass
takes from those drops, beyond what the low-pass diagnosed with that gain took, given back; the gain keeps the
channel's noise level (`noise_kept`: the disc's gain lies before the amplifier) when DATA_NEW's noise says so. And `pick_settings` tells the core the channel's gain (`channel_gain`: its onset threshold scales with
it, so the weak channel is picked at the same wave amplitude as the others). Its onset and energies stay the
least certain: the retrained model's twin reports the mean of its four-channel match and the three-channel
match without that channel (`weak_channel`, twin.h twin_match), and flags the channel.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from .plate_scan import e_scale_scan, size_plate_change  # noqa: F401  (the loop's E sizing)
from .signal import with_channel_delays  # noqa: F401  (the model's picks carry a diagnosed delay)

TWIN_EFFECTS = ("sensor_position", "wave_speed", "damping")
PICK_EFFECTS = ("channel_delay",)     # effects the model's picks carry (`with_channel_delays`), not the recordings
RANDOM_EFFECTS = ("noise",)            # effects whose signal model is a random draw
NOISE_DRAWS = 3                        # independent draws of a random effect per reference drop
TWIN_TRAINING_POSITIONS = 1000         # with a twin and a random effect or a moved disc: distinct training positions (the twin's added)
NOISE_FACTOR_SCALES = (0.6, 0.8, 1.0)  # onset_noise_factor tried, as fractions of the configured one
CLEARLY_BETTER = 0.98                  # ... another one is kept when its travel spread is below this x the best
BOND_FC_HZ = np.geomspace(1000.0, 16000.0, 25)   # the bond's cut-offs tried (above ~15 kHz: no first-arrival change)
BOND_ORDERS = (1, 2)                   # first order (an RC-like bond line) and the effect's second order
BOND_PROBE_DROPS = 160                 # DATA_REF drops the bond's candidates are tried on
BOND_MIN_TILT_GAIN = 0.5               # a low-pass is kept when it removes this share of the tilt misfit
PRETRIGGER_SAMPLES = 64                # a record's first samples: its noise


def split_effects(effects) -> tuple[list, list]:
    """(effects the FEM twin carries, effects put in at the signal level); only significant entries."""
    sig = [e for e in effects if e.get("significant", True) and e["effect"] != "none"]
    return ([e for e in sig if e["effect"] in TWIN_EFFECTS], [e for e in sig if e["effect"] not in TWIN_EFFECTS])


def recorded_effects(effects) -> list:
    """The effects (dicts or accepted candidates) put into training recordings: all but PICK_EFFECTS."""
    return [e for e in effects if _name(e) not in PICK_EFFECTS]


def channel_delays(effects) -> list[float]:
    """The per-channel delay (us) the diagnosed `channel_delay` effects add (dicts or accepted candidates)."""
    out = [0.0] * 4
    for e in effects:
        if _name(e) == "channel_delay" and (not isinstance(e, dict) or e.get("significant", True)):
            params, sensor = (e["params"], e["sensor"]) if isinstance(e, dict) else (e.params, e.sensor)
            out[int(sensor)] += float(params["delay_us"])
    return out


def _name(e) -> str:
    return e["effect"] if isinstance(e, dict) else e.effect


def e_scale_for_speed(params, v_ref_m_s: float, change_pct: float) -> float:
    """E_new / E_old of the twin's plate for a pick velocity change of change_pct % (see the module doc)."""
    from scipy.optimize import brentq

    from .sim.dispersion import a0_group_velocity

    def vg(f, e=params.e_pa):
        return float(a0_group_velocity(f, e, params.nu, params.rho_kg_m3, params.thickness_mm * 1e-3,
                                       params.shear_factor))

    lo, hi = 50.0, 200e3
    f = lo if v_ref_m_s <= vg(lo) else hi if v_ref_m_s >= vg(hi) else brentq(lambda x: vg(x) - v_ref_m_s, lo, hi)
    n = np.log(vg(f, params.e_pa * 1.01) / vg(f)) / np.log(1.01)
    return float((1.0 + change_pct / 100.0) ** (1.0 / n))


def diagnosed_rig(rig, effects):
    """`rig` with each significant sensor_position of `effects` (dicts) put in: the discs where the diagnosis
    places them (the corrected twin's rig; with `retrain --moved-rig` the loop's training sessions' too, so the model
    trained on them, its localiser, its features' geometry and the card's rig, carries the diagnosed position:
    `moved_sensors` says which); the inner region stays the declared rig's."""
    from .data import rig_from_dict

    moves = [e for e in split_effects(effects)[0] if e["effect"] == "sensor_position"]
    if not moves:
        return rig
    raw = json.loads(json.dumps(rig.to_dict()))
    raw["inner_region_mm"] = list(rig.inner_region_mm)   # the plate's region the metrics report: the declared one
    for e in moves:
        sen = raw["sensors"][e["sensor"]]
        sen["x_mm"] = float(sen["x_mm"]) + float(e["params"]["dx_mm"])
        sen["y_mm"] = float(sen["y_mm"]) + float(e["params"]["dy_mm"])
    return rig_from_dict(raw)


def training_rig(rig, effects, moved_rig: bool = False):
    """The rig the loop's training sessions are written with: `diagnosed_rig` when moved_rig (`retrain
    --moved-rig`), else `rig` (the declared one, the default; the move is then in the recordings only, and the
    forests learn it). Off by default: measured on loop sessions the moved rig lowers the physics localiser's
    MAE on most moves but moves the reported MAE both ways (docs/findings.md "Session 21: loopmove")."""
    return diagnosed_rig(rig, effects) if moved_rig else rig


def moved_sensors(declared, diagnosed) -> list[dict]:
    """The card's record of the discs the diagnosed rig moved: sensor, declared and diagnosed (x, y) in mm."""
    a, b = np.asarray(declared.sensor_xy_mm, float), np.asarray(diagnosed.sensor_xy_mm, float)
    return [{"sensor": int(k), "declared_xy_mm": a[k].round(3).tolist(), "diagnosed_xy_mm": b[k].round(3).tolist()}
            for k in range(len(a)) if np.any(a[k] != b[k])]


def corrected_twin(params, rig, effects):
    """(SimParams, Rig) with the twin effects of `effects` put in (others ignored): the rig is `diagnosed_rig`."""
    twin, _ = split_effects(effects)
    for e in twin:
        p = e["params"]
        if e["effect"] == "wave_speed":
            v_ref = p["velocity_m_s"] / (1.0 + p["change_pct"] / 100.0)
            scale = p["e_scale"] if "e_scale" in p else e_scale_for_speed(params, v_ref, p["change_pct"])
            params = dataclasses.replace(params, e_pa=params.e_pa * scale)
        elif e["effect"] == "damping":
            d_s = params.damping_per_s * p["damping_scale"] if "damping_scale" in p else \
                params.damping_per_s + 2.0 * p["extra_decay_per_s"]
            params = dataclasses.replace(params, damping_per_s=d_s)
    return params, diagnosed_rig(rig, effects)


def twin_training_session(base, params, effects, out_dir, slowness_us_per_mm: float, seed: int = 0,
                          workers: int = 2, moved_rig: bool = False, new_positions: int = 0):
    """DATA_REF's declared drops simulated by the corrected twin, the signal-level effects put in after (a delay
    not: `recorded_effects`), and `new_positions` drops of it at new positions (`twin_positions`, `twin_drops`;
    each its own case, after DATA_REF's rows; `twin_move_positions` says how many); written as a session folder
    (its rig.json: `training_rig`) and returned loaded."""
    from .data import load_session, write_session
    from .effects import context
    from .effects.apply import apply_effects
    from .sim import simulate_drops

    p, sim_rig = corrected_twin(params, base.rig, effects)
    adc = simulate_drops(p, sim_rig, base.x_mm, base.y_mm, base.height_mm, noise=True, seed=seed,
                         workers=workers, progress=False)
    _, signal = split_effects(recorded_effects(effects))
    adc = apply_effects(adc, signal, context(base, slowness_us_per_mm), seed)
    cols, case, reps = [base.x_mm, base.y_mm, base.height_mm], base.case_id, base.repetition
    if new_positions:
        new = twin_positions(base, new_positions, seed)
        adc, cols, case, reps = append_drops(adc, cols, case, reps, new, twin_drops(
            params, base.rig, *new, effects, slowness_us_per_mm, seed + 1, workers))
    path = write_session(out_dir, training_rig(base.rig, effects, moved_rig), *cols, adc, case, reps)
    return load_session(path)


def append_drops(adc, cols, case, reps, new, new_adc):
    """(adc, [x, y, height], case, repetition) with the drops at `new` (x, y, height) appended, each its own case
    after the last one, repetition 0."""
    n = len(new[0])
    return (np.concatenate([adc, new_adc]), [np.concatenate([c, v]) for c, v in zip(cols, new)],
            np.concatenate([case, int(np.max(case)) + 1 + np.arange(n)]),
            np.concatenate([reps, np.zeros(n, np.asarray(reps).dtype)]))


def twin_positions(base, n: int, seed: int = 0):
    """(x_mm, y_mm, height_mm) of n new drops over DATA_REF's region: a Sobol set (`sim.doe.virtual_drops`) as far
    from the edges and the sensors as DATA_REF's nearest declared drop, its heights in DATA_REF's range."""
    from .sim.doe import virtual_drops

    rig = base.rig
    ok = np.isfinite(base.x_mm) & np.isfinite(base.y_mm) & np.isfinite(base.height_mm)
    x, y, h = base.x_mm[ok], base.y_mm[ok], base.height_mm[ok]
    edge = float(max(0.0, min(x.min(), y.min(), rig.plate_x_mm - x.max(), rig.plate_y_mm - y.max())))
    clearance = float(np.hypot(x[:, None] - rig.sensor_x_mm, y[:, None] - rig.sensor_y_mm).min())
    return virtual_drops(rig, n, seed, edge, clearance, (float(h.min()), float(h.max())))


def twin_drops(params, rig, x_mm, y_mm, height_mm, effects, slowness_us_per_mm: float, seed: int = 0,
               workers: int = 2) -> np.ndarray:
    """ADC records of drops at the given declared positions by the corrected twin (`corrected_twin`: the plate
    and sensor effects in the FEM), the signal-level effects put in after (each with its own draw; a delay not:
    `recorded_effects`); the batch's
    solver as the batch commands choose it (`sim.simulate.batch_solver`: the modal basis when it pays)."""
    from .effects.apply import apply_effects
    from .sim import simulate_drops
    from .sim.simulate import batch_solver

    p, sim_rig = corrected_twin(params, rig, effects)
    _, signal = split_effects(recorded_effects(effects))
    adc = simulate_drops(p, sim_rig, x_mm, y_mm, height_mm, noise=True, seed=seed, workers=workers, progress=False,
                         solver=batch_solver(p, sim_rig, "auto", x_mm, y_mm, height_mm))
    ctx = {"x_mm": np.asarray(x_mm, float), "y_mm": np.asarray(y_mm, float),
           "sensor_xy_mm": rig.sensor_xy_mm.astype(float), "fs_hz": float(rig.fs_hz),
           "bias": float(rig.bias_counts), "adc_max": int(rig.adc_max), "slowness_us_per_mm": slowness_us_per_mm}
    # the effects' draws from another stream than the twin's own noise (the same seed would repeat its numbers)
    return apply_effects(adc, signal, ctx, [seed, 1])


def moves_disc(accepted) -> bool:
    """True when a sensor_position is among the accepted effects (Candidates): with a twin, retrain then also fits
    on the corrected twin's drops (`twin_training_session`: the disc moved in the FEM, its amplitude and onset with
    it) beside DATA_REF's recordings with the move put in as one time shift per channel
    (`effects.sensor_position.apply_signal`), and keeps the better on DATA_NEW (`commands.retrain.training_session`;
    docs/findings.md "Session 22: loopmove2")."""
    return any(c.effect == "sensor_position" for c in accepted)


def effect_dicts(accepted) -> list[dict]:
    return [{"effect": c.effect, "sensor": c.sensor, "params": c.params, "significant": True} for c in accepted]


def training_draws(accepted) -> int:
    """Copies of each reference drop in the measured training data: NOISE_DRAWS with a random effect, else 1."""
    return NOISE_DRAWS if any(c.effect in RANDOM_EFFECTS for c in accepted) else 1


def twin_positions_wanted(base, accepted, twin) -> int:
    """New positions the twin adds to the measured training data when a random effect was diagnosed and a twin
    is given: as many as bring DATA_REF's positions (cases) to TWIN_TRAINING_POSITIONS; else 0."""
    if twin is None or not accepted or training_draws(accepted) == 1:
        return 0
    return max(0, TWIN_TRAINING_POSITIONS - len(np.unique(base.case_id)))


def twin_move_positions(base, effects) -> int:
    """New positions the corrected twin's training drops add to DATA_REF's declared ones when a disc moved
    (`effects`: dicts; a significant sensor_position among them): as many as bring DATA_REF's positions (cases) to
    TWIN_TRAINING_POSITIONS; else 0. The forests correct the physics position of the declared rig, whose error
    near a moved disc is a new function of position: learned from the reference's positions alone it is not
    (docs/findings.md "Session 26: moveretrain")."""
    if not any(e["effect"] == "sensor_position" and e.get("significant", True) for e in effects):
        return 0
    return max(0, TWIN_TRAINING_POSITIONS - len(np.unique(base.case_id)))


def measured_training_session(base, accepted, ref, out_dir, seed: int = 0, twin=None, workers: int = 2,
                              moved_rig: bool = False):
    """DATA_REF's recordings with every diagnosed effect's signal model put in but a delay's (`recorded_effects`:
    the model carries it, `with_channel_delays`) (`training_draws` copies, each
    with its own random draws), and with a twin (SimParams) and a random effect, `twin_positions_wanted` drops
    of the corrected twin at new positions (`twin_positions`, `twin_drops`; each its own case, after DATA_REF's
    rows), written (rig.json: `training_rig`: with moved_rig a moved disc where the diagnosis places it)
    and loaded."""
    from .commands.retrain import augment
    from .data import load_session, write_session

    k = training_draws(accepted) if accepted else 1
    adc = np.concatenate([augment(base, recorded_effects(accepted), ref, seed + j) for j in range(k)]) if accepted \
        else np.asarray(base.adc)
    rep = np.asarray(base.repetition)
    reps = np.concatenate([rep + j * (int(rep.max()) + 1) for j in range(k)])
    cols = [np.tile(base.x_mm, k), np.tile(base.y_mm, k), np.tile(base.height_mm, k)]
    case = np.tile(base.case_id, k)
    n = twin_positions_wanted(base, accepted, twin)
    if n:
        new = twin_positions(base, n, seed)
        adc, cols, case, reps = append_drops(adc, cols, case, reps, new, twin_drops(
            twin, base.rig, *new, effect_dicts(accepted), ref.slowness_us_per_mm, seed + k, workers))
    path = write_session(out_dir, training_rig(base.rig, effect_dicts(accepted), moved_rig), *cols, adc, case, reps)
    return load_session(path)


def pick_settings(session, accepted, reference=None):
    """The core's settings to train on `session` (a measured training session) with: None (the rig's) unless a
    raised white noise floor was diagnosed (material: >= the noise effect's min_white_counts); then the
    onset_noise_factor among NOISE_FACTOR_SCALES x the configured one whose travel fit (with its own absolute
    threshold and AIC blend) has the smallest robust spread on the training drops, kept only when
    CLEARLY_BETTER than the one before it (ties keep the configured one) and when the training drops' physics
    MAE under it (the localiser fitted on them) is not above the one before it's. With `reference` (DATA_REF,
    the session without the change) that configuration also carries the band picks' noise floor: the reference
    drops' (pipeline.training_noise_floor, pipeline.band_floor_preset), the lab's floor before the change; the
    band envelope's own noise under the raised floor is then the core's envelope term (band_onset). Without it
    the band picks take the noisy training drops' floor (3 x ~their broadband noise), which leaves them out."""
    from .effects import EFFECTS
    from .pipeline import fit_localiser, physics_mae, training_noise_floor
    from .signal import SignalConfig
    from .travel import choose_threshold, wants_metric

    from .bond_inverse import bond_inverse_fields

    inverse = bond_inverse_fields(session, accepted)
    gains = onset_gains(session, accepted)
    for ch, fc in enumerate(inverse.get("bond_corner_hz", [0.0] * 4)):
        if fc > 0.0:
            gains[ch] = 1.0   # the inverse gives the channel its gain back
    given = {**({"channel_gain": gains} if gains != [1.0] * 4 else {}), **inverse}
    floor = EFFECTS["noise"].min_white_counts   # the white part the noise effect calls material
    if not any(c.effect == "noise" and c.params.get("white_rms_counts", 0.0) >= floor for c in accepted):
        return SignalConfig.for_rig(session.rig, **given) if given else None
    base = SignalConfig.for_rig(session.rig, **given)
    rows = np.arange(len(session))
    best, best_spread, best_mae = None, np.inf, np.inf
    for scale in sorted(NOISE_FACTOR_SCALES, reverse=True):   # the configured one first: ties keep it
        cfg = SignalConfig.for_rig(session.rig, onset_noise_factor=float(base.onset_noise_factor) * scale, **given)
        try:
            _, _, fit, _ = choose_threshold(session.adc, session.xy_mm, cfg, wants_metric(session.rig))
        except ValueError:
            continue
        # the travel spread is robust: it does not see drops whose onset was a crossing in the noise, which
        # the positions do (a lower threshold near the noise's extremes): a factor is kept only when the
        # training drops' physics positions, with the localiser fitted as `train` fits it, are not worse
        mae = physics_mae(session, rows, fit_localiser(session, rows, cfg))
        if fit.spread_mm < CLEARLY_BETTER * best_spread and mae <= best_mae:
            best, best_spread, best_mae = cfg, fit.spread_mm, mae
    if best is not None and reference is not None:
        best.band_noise_counts = training_noise_floor(reference, np.arange(len(reference)), best)
    return best


def onset_gains(session, accepted) -> list[float]:
    """The core's channel_gain per channel: a diagnosed gain times, on a channel with a bond low-pass, the
    low-pass's gain at the arrival the picks catch (the other channels' median pick frequency on `session`,
    fs / pick_period): the onset threshold then meets the weak channel's first cycles where it meets the
    others', down to the noise floor (onset_noise_factor x its noise rms)."""
    from .bond_inverse import others_pick_hz
    from .effects.channel_lowpass import lowpass_gain_at

    gains = [1.0] * 4
    for c in accepted:
        if c.effect == "sensor_gain":
            gains[c.sensor] *= float(c.params["gain"])
    lows = [c for c in accepted if c.effect == "channel_lowpass"]
    for c in lows:
        f_pick = others_pick_hz(session, c.sensor)
        fs = float(session.rig.fs_hz)
        gains[c.sensor] *= lowpass_gain_at(f_pick, c.params["fc_hz"], fs, c.params.get("order", 2))
    return gains


def _bond_stats(session, cfg, channel: int) -> tuple[np.ndarray, np.ndarray]:
    """The channel's medians over usable drops, and their standard errors: log10 Delta^1..3 minus arrival
    energy (the tilt), log10 arrival energy minus the other channels' mean (the level), and its onset minus
    the others' mean, less the travel model's difference for the declared position (us)."""
    from .pipeline import featurize
    from .sitemap import twin_features

    F = featurize(session.adc, cfg)
    feats, usable = twin_features(F)
    kinds = 4
    cols = channel * kinds + np.arange(kinds)          # bit i of the mask: feature i usable
    ok = ((np.asarray(usable, np.int64)[:, None] >> cols[None, :]) & 1).all(1) & np.isfinite(F.toa_us).all(1)
    if ok.sum() < 5:
        return np.full(5, np.nan), np.full(5, np.nan)
    f, toa = feats[ok], np.asarray(F.toa_us, float)[ok]
    d = np.linalg.norm(session.xy_mm[ok][:, None, :] - np.asarray(cfg.sensor_xy_mm, float)[None], axis=2)
    travel = toa - d / float(cfg.velocity_mm_per_us)
    others = [c for c in range(4) if c != channel]
    arrival = f[:, channel * kinds]
    cols = [f[:, channel * kinds + k] - arrival for k in range(1, kinds)]
    cols += [arrival - f[:, [c * kinds for c in others]].mean(1), travel[:, channel] - travel[:, others].mean(1)]
    x = np.stack(cols, 1)
    med = np.median(x, 0)
    se = 1.2533 * 1.4826 * np.median(np.abs(x - med), 0) / np.sqrt(len(x))   # the median's standard error
    return med, np.maximum(se, 1e-6)


def _noise_rms(adc, channel: int) -> float:
    """Median over records of the channel's rms about the mean over the record's first samples (counts)."""
    return float(np.median(np.asarray(adc[:, channel, :PRETRIGGER_SAMPLES], float).std(axis=-1))) + 1e-9


def weak_channel(effects) -> int:
    """The channel the models treat as weak (twin.h TwinConfig.weak_channel): the one channel a bond low-pass
    was put on (fit_bond), else -1."""
    chans = sorted({c.sensor for c in effects if c.effect == "channel_lowpass"})
    return chans[0] if len(chans) == 1 else -1


def bond_channels(accepted) -> list[int]:
    """Channels with a diagnosed gain loss or low-pass (a partly debonded disc's signature)."""
    return sorted({c.sensor for c in accepted if (c.effect == "sensor_gain" and c.params["gain"] < 1.0)
                   or c.effect == "channel_lowpass"})


def fit_bond(base, data, accepted, seed: int = 0) -> list:
    """`accepted` with each bond channel's gain and low-pass sized on the recordings (see the module doc):
    the channel's sensor_gain and channel_lowpass entries replaced by the fitted ones (the low-pass left out
    when none removes BOND_MIN_TILT_GAIN of the tilt misfit of no low-pass)."""
    from .diagnose import Candidate
    from .effects import context
    from .effects.apply import apply_effects
    from .signal import SignalConfig

    channels = bond_channels(accepted)
    if not channels:
        return list(accepted)
    from .pipeline import fit_localiser

    rng = np.random.default_rng(seed)
    rows = np.sort(rng.choice(len(base), min(BOND_PROBE_DROPS, len(base)), replace=False))
    probe = base.subset(rows)
    cfg = fit_localiser(probe, np.arange(len(probe)), SignalConfig.for_rig(base.rig), choose_threshold=False)
    ctx = context(probe)
    # the bond's low-pass delays the channel's onset: a delay named on that channel is the low-pass's
    bonded = ("sensor_gain", "channel_lowpass", "channel_delay")
    out = [c for c in accepted if c.sensor not in channels or c.effect not in bonded]
    for ch in channels:
        target, target_se = _bond_stats(data, cfg, ch)
        gain0 = next((c.params["gain"] for c in accepted if c.effect == "sensor_gain" and c.sensor == ch), 1.0)
        lp0 = next((c.params for c in accepted if c.effect == "channel_lowpass" and c.sensor == ch), None)
        skip = [True, True, True, False, True]   # tilt and timing: the level is the gain's, fitted after

        def trial(lowpass):
            eff = ([{"effect": "channel_lowpass", "sensor": ch, "params": lowpass}] if lowpass else []) + \
                  [{"effect": "sensor_gain", "sensor": ch, "params": {"gain": gain0}}]
            got, se = _bond_stats(dataclasses.replace(probe, adc=apply_effects(probe.adc, eff, ctx, seed)), cfg, ch)
            z = (got - target) / np.hypot(se, target_se)
            return float(np.sum(z[skip] ** 2)), got

        none_err, none_got = trial(None)
        variants = []   # per noise model (given back: the amplifier's noise after the bond; or filtered)
        for filtered in (False, True):
            best = (none_err, None, none_got)
            for order in BOND_ORDERS:
                for fc in BOND_FC_HZ:
                    lp = {"fc_hz": float(fc), "order": order, "noise_filtered": filtered}
                    err, got = trial(lp)
                    if err < best[0]:
                        best = (err, lp, got)
            variants.append(best)
        # the noise model whose channel noise is DATA_NEW's (log of the pre-trigger rms, median over drops)
        def noise_misfit(lp):
            eff = ([{"effect": "channel_lowpass", "sensor": ch, "params": lp}] if lp else []) + \
                  [{"effect": "sensor_gain", "sensor": ch, "params": {"gain": gain0}}]
            return abs(np.log(_noise_rms(apply_effects(probe.adc, eff, ctx, seed), ch)) - np.log(target_noise))
        target_noise = _noise_rms(data.adc, ch)
        best_err, best_lp, best_got = min(variants, key=lambda v: noise_misfit(v[1]))
        if best_lp is not None and not best_err <= (1.0 - BOND_MIN_TILT_GAIN) * none_err:
            best_lp, best_got = None, none_got
        # the diagnosed gain, with the low-pass diagnosed with it, explains DATA_NEW's level (against its
        # position-aware reference); the fitted low-pass takes some of it: the gain is the diagnosed one with the
        # level difference of the two on the same drops (energies go as gain^2: 2 log10 gain)
        diag_got = trial(lp0)[1] if lp0 is not None else none_got
        lost = diag_got[3] - best_got[3]
        gain = float(gain0 * 10.0 ** (lost / 2.0)) if np.isfinite(lost) else gain0
        common = dict(score=0.0, p_value=0.0, material=True, significant=True, fold_params=[])
        if best_lp is not None:
            out.append(Candidate("channel_lowpass", ch, best_lp, **common))
        kept = gain < 1.0 and _bond_keeps_noise(probe, ctx, ch, best_lp, gain, target_noise, seed)
        out.append(Candidate("sensor_gain", ch, {"gain": gain, **({"noise_kept": True} if kept else {})}, **common))
    return out


def _bond_keeps_noise(probe, ctx, ch: int, lowpass, gain: float, target_noise: float, seed: int) -> bool:
    """True when DATA_NEW's channel noise (target_noise) is nearer the bond put in with its gain keeping the
    amplifier's noise (sensor_gain's noise_kept: the gain lies before the amplifier) than with the noise scaled
    by the gain: a weaker disc's onset crosses the threshold at the noise it has (docs/findings.md, bondpick)."""
    from .effects.apply import apply_effects

    def misfit(kept: bool) -> float:
        eff = ([{"effect": "channel_lowpass", "sensor": ch, "params": lowpass}] if lowpass else []) + \
              [{"effect": "sensor_gain", "sensor": ch, "params": {"gain": gain, "noise_kept": kept}}]
        return abs(np.log(_noise_rms(apply_effects(probe.adc, eff, ctx, seed), ch)) - np.log(target_noise))
    return misfit(True) < misfit(False)
