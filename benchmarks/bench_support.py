"""Benchmark: which plate support explains the rig's low-band dispersion? (docs/findings.md, "Can four drops tell nu?")

    python3 benchmarks/bench_support.py [--calibration CAL.json] [--supports simply_supported,free,clamped]
                                        [--held-out 16] [--rounds 1] [--max-nfev 8]
                                        [--per-band-e] [--per-band-ds] [--channel-delays] [--sensor-positions]
    supports: free, simply_supported, clamped, elastic_rim:K[:C] (N/m and N s/m per metre of edge), each
    optionally with @FIELD=VALUE overrides (`parse_suspect`): SimParams fields (elastic_rim:1e10@rim_inset_mm=4,
    simply_supported@disc_mass=0, @pzt_thickness_mm=0.4, the mesh @element_mm=1.03, @thickness_mm=4.0@e_pa=5.0e9),
    the twin's rig geometry (@rig.sensor_diameter_mm=16, @rig.plate_x_mm=321) or the group-delay window, measured
    and twin alike (@gd.flat=500/250/250, @gd.TAPER_US=300, @gd.ANCHOR_OFFSET_US=650)

    numerics or sensor/geometry? (docs/findings.md; --rounds 0 scores every suspect at the calibration's E, nu, D_s):
    S=simply_supported; python3 benchmarks/bench_support.py --calibration CAL.json --rounds 0 --supports \
        $S,$S@element_mm=1.54,$S@element_mm=1.03                    # mesh (and dt: it follows the mesh)
    ... --supports $S,$S@element_mm=1.54,$S@gd.flat=250/125/125@gd.TAPER_US=300,\
        $S@gd.flat=250/125/125@gd.TAPER_US=300@element_mm=1.54,$S@gd.flat=2000/1000/1000   # the window
    ... --supports $S,$S@rig.sensor_diameter_mm=16,$S@rig.sensor_diameter_mm=24,$S@rig.plate_x_mm=321,\
        $S@thickness_mm=4.0@e_pa=5.0026e9                            # disc, plate size, thickness at E t^2 fixed
    ... --supports $S,$S@disc_stiffness_scale=0.5,$S@disc_mass_scale=0.5,$S@disc_patch_diameter_mm=16
                                                # the disc's mechanical coupling only (bond, footprint; it senses
                                                # over the rig's disc): SimParams.disc_*

The rig's plate rests on a rubber rim (rig.json `plate_support`); the twin holds its edges (simply supported).
Every sensor is 30-33 mm from two edges, so edge reflections sit inside every low-band packet and the edge
condition sets their phase. For each support this prints, on session-1:

- the four calibration drops' band group delays (`calibration/group_delay.py`), every repetition's position
  fitted (`plate_fem.fit_positions`) at the calibration's E, nu, D_s: chi^2 / dof and rms residual per band;
- the same after calibration's own nu stage (`plate_nu.fit`: ln E, nu, D_s and the positions, `--rounds`):
  fitted E, nu, D_s and chi^2 / dof (the projected residual, as CAL.json `plate.nu_fit`);
- the AIC DToA rms (Eq. 16) of the four cases at their declared positions, at the calibration's E and at the
  nu stage's E;
- `--held-out N` other usable cases (spread over the plate, none of the calibration's): their repetitions'
  positions fitted at the support's nu-stage (E, nu, D_s) from the four drops; chi^2 / dof and rms per band.

chi^2 uses the rig-noise spread of the group delays (`plate_nu.noise_sigma`), the same for every support;
dof = observables - 2 x repetitions (the fitted positions). A group-delay window suspect re-measures the rig's
group delays and their noise sigma under its window.

The compact table at the end adds the twin's own shift: its group delays at the reference suspect's fitted
positions (the first suspect with the same window) minus the reference's, rms per band: between meshes that is
the numerical dispersion, with the rig left out.
"""

from __future__ import annotations

import argparse
import json
import time
from contextlib import contextmanager
from importlib import resources

import numpy as np

from impactsense.calibration import drops as drops_mod, fem, group_delay, plate, plate_fem, plate_nu
from impactsense.calibration.pipeline import CalibrateOptions, measured_core_config, sim_core_config, sim_features
from impactsense.data import load_session, rig_from_dict


def bundled_calibration() -> str:
    return str(resources.files("impactsense") / "data" / "twin" / "calibration.json")


BOOL_FIELDS = ("disc_mass", "disc_stiffness", "disc_inertia_scaling", "subcycle")
RIG_FIELDS = ("plate_x_mm", "plate_y_mm", "sensor_diameter_mm")
GD_FIELDS = ("RISE_US", "LEAD_US", "TAPER_US", "ANCHOR_FLAT_US", "ANCHOR_OFFSET_US")
SENSE_FIELDS = ("diameter_mm",)


def parse_suspect(spec: str) -> tuple[dict, dict, dict]:
    """A suspect spec -> (SimParams fields, rig.json fields, group-delay window settings).

    spec: a support name, or elastic_rim:STIFFNESS[:DAMPING] (N/m and N s/m per m), optionally followed by
    @FIELD=VALUE overrides: a SimParams field (simply_supported@disc_mass=0, @element_mm=1.03, @thickness_mm=4.0),
    rig.FIELD (@rig.sensor_diameter_mm=16, @rig.plate_x_mm=321: the twin's geometry only, the measured side is
    unchanged) or gd.FIELD (the group-delay window of `calibration/group_delay.py`, measured and twin alike:
    @gd.TAPER_US=300, @gd.flat=500/250/250 the bands' flat parts in us) or sense.diameter_mm (the twin's discs
    sense over a circle of that diameter, their mass and stiffness stay the rig's disc: `sensing_diameter`; carried
    in the third dict as "sense_diameter_mm")."""
    spec, *extra = spec.split("@")
    name, *vals = spec.split(":")
    sim, rig, gd = {"support": name}, {}, {}
    if name == "elastic_rim":
        sim["rim_stiffness_n_m2"] = float(vals[0]) if vals else 0.0
        if len(vals) > 1:
            sim["rim_damping_n_s_m2"] = float(vals[1])
    for kv in extra:
        key, val = kv.split("=")
        if key.startswith("rig."):
            if key[4:] not in RIG_FIELDS:
                raise SystemExit(f"suspect {spec!r}: {key} is not one of rig.{RIG_FIELDS}")
            rig[key[4:]] = float(val)
        elif key == "gd.flat":
            gd["flat"] = tuple(float(v) for v in val.split("/"))
            if len(gd["flat"]) != len(group_delay.BANDS):
                raise SystemExit(f"suspect {spec!r}: gd.flat needs {len(group_delay.BANDS)} values")
        elif key.startswith("sense."):
            if key[6:] not in SENSE_FIELDS:
                raise SystemExit(f"suspect {spec!r}: {key} is not one of sense.{SENSE_FIELDS}")
            gd["sense_" + key[6:]] = float(val)
        elif key.startswith("gd."):
            if key[3:] not in GD_FIELDS:
                raise SystemExit(f"suspect {spec!r}: {key} is not one of gd.{GD_FIELDS} or gd.flat")
            gd[key[3:]] = float(val)
        else:
            sim[key] = bool(int(val)) if key in BOOL_FIELDS else float(val)
    return sim, rig, gd


def support_overrides(spec: str) -> dict:
    """SimParams fields of a suspect spec (`parse_suspect`)."""
    return parse_suspect(spec)[0]


@contextmanager
def gd_window(settings: dict):
    """`calibration/group_delay.py`'s window constants (and the bands' flat parts) set for the block."""
    saved = {k: getattr(group_delay, k) for k in (*GD_FIELDS, "BANDS")}
    try:
        for k, v in settings.items():
            if k == "flat":
                group_delay.BANDS = tuple((lo, hi, f) for (lo, hi, _), f in zip(saved["BANDS"], v))
            else:
                setattr(group_delay, k, v)
        yield
    finally:
        for k, v in saved.items():
            setattr(group_delay, k, v)


@contextmanager
def sensing_diameter(diameter_mm):
    """The twin's sensing functionals over a circle of diameter_mm (an electrode smaller or larger than the disc),
    its disc mass and stiffness left on the rig's disc: `simulate.build_model` wrapped for the block (the model
    cache cleared on both sides). The same open-circuit law as `model.build_model`: U = C <beta_x,x + beta_y,y>
    over the circle, gradients at element centres. A diagnostic only: the product has no such field."""
    if diameter_mm is None:
        yield
        return
    from impactsense.sim import model as model_mod, simulate as sim_mod
    original = sim_mod.build_model

    def build(params, rig, **kw):
        m = original(params, rig, **kw)
        p, hx, hy, nx = m.params, m.hx_m, m.hy_m, m.nx
        tp, e11 = p.pzt_thickness_mm * 1e-3, p.pzt_e11_mpa * 1e6
        c_volt = tp * (p.pzt_d31_pc_n * 1e-12) * e11 / ((1 - p.pzt_nu12) * p.pzt_eps33_rel * model_mod.EPS0) \
            * (-p.thickness_mm * 1e-3 / 2)
        sensors, r = [], nx + 1
        for c in m.sensor_xy_m:
            fr = model_mod._disc_fraction((hx, hy, nx, m.ny), c, diameter_mm * 0.5e-3)
            a_disc = sum(fr.values()) * hx * hy
            acc = {}
            for (i, j), f in fr.items():
                wgt = c_volt * f * hx * hy / a_disc
                for node, sx, sy in ((j * r + i, -1, -1), (j * r + i + 1, 1, -1), ((j + 1) * r + i + 1, 1, 1),
                                     ((j + 1) * r + i, -1, 1)):
                    e = acc.setdefault(node, [0.0, 0.0])
                    e[0] += wgt * sx / (2 * hx)
                    e[1] += wgt * sy / (2 * hy)
            nodes = np.array(sorted(acc), dtype=np.int64)
            sensors.append((nodes, np.array([acc[k][0] for k in nodes]), np.array([acc[k][1] for k in nodes])))
        m.sensors = sensors
        return m

    sim_mod.clear_cache()
    sim_mod.build_model = build
    try:
        yield
    finally:
        sim_mod.build_model = original
        sim_mod.clear_cache()


def rig_with(rig, fields: dict):
    """The rig with some rig.json plate/disc fields replaced (the twin's geometry suspects)."""
    if not fields:
        return rig
    raw = json.loads(json.dumps(rig.raw))
    raw.update(fields)
    return rig_from_dict(raw)


def held_out_cases(session, feats, exclude, n) -> list[int]:
    """n usable cases (>= 3 accepted repetitions, >= 40 mm from every sensor), none of `exclude`, evenly spread
    over the plate: a greedy farthest-point pick from the case nearest the plate's centre."""
    rows, _ = drops_mod.case_table(session, feats, min_reps=3)
    ok = [c for c, r in rows.items() if r["usable"] and c not in exclude]
    xy = np.array([[rows[c]["x"], rows[c]["y"]] for c in ok])
    centre = xy.mean(axis=0)
    pick = [int(np.argmin(np.hypot(*(xy - centre).T)))]
    while len(pick) < min(n, len(ok)):
        d = np.min(np.hypot(xy[:, None, 0] - xy[pick][None, :, 0], xy[:, None, 1] - xy[pick][None, :, 1]), axis=1)
        pick.append(int(np.argmax(d)))
    return sorted(ok[i] for i in pick), rows


def targets_for(session, feats, rows, cases):
    return drops_mod._targets(session, feats, rows, cases, {"selection": "bench_support"})


def band_stats(o_sim, per_rep, sigma, n_pos):
    """chi^2 / dof and rms residual per band (us) of measured - twin group delays [R, B, 6]."""
    r = o_sim - per_rep
    ok = np.isfinite(r)
    z = np.where(ok, r / sigma[None, :, None], 0.0)
    dof = int(ok.sum()) - 2 * n_pos
    rms = np.sqrt(np.nanmean(np.where(ok, r, np.nan) ** 2, axis=(0, 2)))
    return float((z ** 2).sum() / max(dof, 1)), rms


def rms_per_band(v):
    """rms over repetitions and pairs of [R, B, 6] (us), per band."""
    return np.sqrt(np.nanmean(np.asarray(v, float) ** 2, axis=(0, 2)))


def channel_delays(resid, sigma):
    """Per band, the four channels' delays d (sum 0) that best explain residuals resid [R, B, 6] of the pairs
    (i, j) as d_i - d_j (least squares, rig-noise weights): [B, 4] us."""
    a = np.zeros((6, 4))
    a[np.arange(6), plate.PAIR_I] = 1.0
    a[np.arange(6), plate.PAIR_J] = -1.0
    out = []
    for b in range(resid.shape[1]):
        r = resid[:, b, :]
        ok = np.isfinite(r)
        rows = np.concatenate([a[ok[k]] for k in range(r.shape[0])])
        d, *_ = np.linalg.lstsq(np.vstack([rows, np.ones((1, 4))]), np.append(r[ok], 0.0), rcond=None)
        out.append(d)
    return np.array(out)


def pair_offsets(d):
    """[B, 6] pair offsets d_i - d_j of channel delays d [B, 4]."""
    return d[:, plate.PAIR_I] - d[:, plate.PAIR_J]


def shifted_rig(rig, shift_mm):
    """The rig with its sensor centres moved by shift_mm [4, 2] (x, y per channel)."""
    raw = json.loads(json.dumps(rig.raw))
    for sensor in raw["sensors"]:
        dx, dy = shift_mm[int(sensor["channel"])]
        sensor["x_mm"] = float(sensor["x_mm"]) + float(dx)
        sensor["y_mm"] = float(sensor["y_mm"]) + float(dy)
    return rig_from_dict(raw)


def fit_sensor_shift(obs_rig, per_rep, sigma, rig, d_mm=1.0):
    """Sensor centre shifts [4, 2] mm (Gauss-Newton, two steps, FEM differences of d_mm) that best explain
    per_rep [R, B, 6]; obs_rig(rig) -> the twin's group delays at fixed drop positions."""
    shift = np.zeros((4, 2))
    w = 1.0 / sigma[None, :, None]
    for _ in range(2):
        o0 = obs_rig(shifted_rig(rig, shift))
        r0 = ((per_rep - o0) * w).ravel()
        cols = []
        for k in range(8):
            s2 = shift.copy()
            s2.flat[k] += d_mm
            cols.append(((obs_rig(shifted_rig(rig, s2)) - o0) * w).ravel() / d_mm)
        j = np.stack(cols, 1)
        ok = np.isfinite(r0) & np.isfinite(j).all(1)
        step, *_ = np.linalg.lstsq(j[ok], r0[ok], rcond=None)
        shift += np.clip(step.reshape(4, 2), -3.0, 3.0)
    return shift


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--calibration", default=bundled_calibration(), help="CAL.json (default: the bundled twin's)")
    ap.add_argument("--data", default="bundled")
    ap.add_argument("--supports", default="simply_supported,free,clamped",
                    help="comma-separated: free, simply_supported, clamped, elastic_rim:K[:C] (N/m, N s/m per m)")
    ap.add_argument("--held-out", type=int, default=16, help="other cases checked (0: none)")
    ap.add_argument("--rounds", type=int, default=1, help="nu-stage rounds (0: skip the E, nu, D_s fit)")
    ap.add_argument("--max-nfev", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--per-band-e", action="store_true",
                    help="also: E that best fits each band alone (positions held where they fit at the calibration's "
                         "E), a dispersion check: a modulus rising with frequency (viscoelastic PMMA) shows as E "
                         "growing from band to band")
    ap.add_argument("--per-band-ds", action="store_true",
                    help="also: D_s that best fits each band alone (positions where they fit at the calibration's "
                         "D_s), then every repetition's position refitted with each band's group delays from a twin "
                         "at that band's D_s, and the held-out cases scored the same way: a frequency-dependent "
                         "damping (PMMA's loss factor, not the twin's mass-proportional D_s) shows as D_s changing "
                         "from band to band and a lower held-out chi2/dof")
    ap.add_argument("--channel-delays", action="store_true",
                    help="also: per-channel, per-band delays (3 a band) fitted on the calibration drops at the "
                         "calibration's E, nu, D_s, and the held-out cases scored with them")
    ap.add_argument("--sensor-positions", action="store_true",
                    help="also: the four discs' centres fitted on the calibration drops (8 parameters), and the "
                         "held-out cases scored with them")
    ap.add_argument("--json", default=None, help="write the figures here too")
    a = ap.parse_args(argv)

    cal = json.loads(open(a.calibration).read())
    flat = {k: v if isinstance(v, str) else float(v) for k, v in cal["fitted"].items()}
    session = load_session(a.data)
    rig = session.rig
    cfg = measured_core_config(rig, CalibrateOptions())
    cfg_sim = sim_core_config(rig, CalibrateOptions())
    feats = drops_mod.extract(session, cfg)
    cal_cases = [int(c) for c in cal["exclude_case_ids"]]
    rows, _ = drops_mod.case_table(session, feats)
    tgt = targets_for(session, feats, rows, cal_cases)
    noise = (float(cal["noise_added_to_simulations"]["counts_rms"]), 4, 0)
    names = group_delay.names()
    ks = list(range(len(names)))
    n_rep = [len(r) for r in tgt.recording_ids]
    x, y, h = (np.repeat(np.asarray(v, float), n_rep) for v in (tgt.x_mm, tgt.y_mm, tgt.height_mm))
    held_cases = []
    if a.held_out > 0:
        held_cases, rows3 = held_out_cases(session, feats, set(cal_cases), a.held_out)
        t_h = targets_for(session, feats, rows3, held_cases)
        nr = [len(r) for r in t_h.recording_ids]
        xyh_h = [np.repeat(np.asarray(v, float), nr) for v in (t_h.x_mm, t_h.y_mm, t_h.height_mm)]
    base_sim = fem.fem_simulator(a.workers)
    measured_cache = {}

    def measured(gd):
        """(per_rep, n_samp, sigma, held) under the group-delay window gd (set by the caller): the measured group
        delays of the calibration drops and of the held-out cases, and the rig-noise sigma (default mesh and
        support at the calibration's parameters: the same for every suspect of one window)."""
        key = json.dumps(gd, sort_keys=True)
        if key not in measured_cache:
            gd_c, n_c = plate_nu.measured_group_delays(session, tgt, feats, cfg)
            sig = plate_nu.noise_sigma(base_sim(flat, rig, x, y, h), cfg_sim, n_c, noise[0], noise[1])
            hl = []
            if held_cases:
                gd_h, n_h = plate_nu.measured_group_delays(session, t_h, feats, cfg)
                hl = [t_h, gd_h, n_h, *xyh_h]
            measured_cache[key] = (gd_c, n_c, sig, hl)
        return measured_cache[key]

    per_rep, n_samp, sigma, held = measured({})
    print(f"calibration {a.calibration}: E {flat['e_pa'] / 1e6:.0f} MPa, nu {flat['nu']:.3f}, "
          f"D_s {flat['damping_per_s']:.0f} 1/s; cases {cal_cases} ({per_rep.shape[0]} repetitions); "
          f"sigma {np.round(sigma, 2).tolist()} us" + (f"; held out: {len(held[0].case_ids)} cases "
                                                        f"({held[1].shape[0]} repetitions)" if held else ""))

    out = {}
    refs = {}      # per group-delay window: the first suspect's fitted positions and twin group delays there
    for sup in a.supports.split(","):
        sim_over, rig_over, gd = parse_suspect(sup)
        sense = gd.pop("sense_diameter_mm", None)
        with gd_window(gd), sensing_diameter(sense):
            out[sup] = run_suspect(a, sup, sim_over, rig_with(rig, rig_over), gd, measured(gd), refs, flat, x, y, h,
                                   tgt, cfg_sim, noise, names, ks)
        print(f"  {sup}: done in {out[sup]['seconds']:.0f} s", flush=True)
    report(a, out, names)


def run_suspect(a, sup, sim_over, rig, gd, meas, refs, flat, x, y, h, tgt, cfg_sim, noise, names, ks) -> dict:
    """One suspect's figures (see the module docstring)."""
    per_rep, n_samp, sigma, held = meas
    t0 = time.perf_counter()
    simulate = fem.fem_simulator(a.workers, **sim_over)

    def obs(p, xx, yy, hh, n=n_samp):
        return plate_nu.twin_group_delays(simulate(p, rig, xx, yy, hh), cfg_sim, n, *noise)

    def aic_rms(p):
        f = sim_features(simulate(p, rig, tgt.x_mm, tgt.y_mm, tgt.height_mm), cfg_sim, *noise)
        return float(np.sqrt(plate.delay_misfit(f["dtoa_us"], tgt.dtoa_us) / tgt.dtoa_us.size))

    # the window's own scale: the rig-noise sigma and the spread (rms) of the measured group delays per band, so
    # that residuals under different windows compare (a short window pulls the four centroids together)
    row = {"aic_rms_us_cal": aic_rms(flat), "sigma_us": sigma, "meas_rms_us_cal": rms_per_band(per_rep)}
    if held:
        row["meas_rms_us_held"] = rms_per_band(held[1])
    xf, yf = plate_fem.fit_positions(lambda xx, yy, hh: obs(flat, xx, yy, hh), per_rep, sigma, x, y, h, ks)
    o_cal = obs(flat, xf, yf, h)
    row["chi2_dof_cal"], row["rms_us_cal"] = band_stats(o_cal, per_rep, sigma, len(x))
    if a.sensor_positions:
        # the discs' centres (rig.json gives round numbers): fitted on the calibration drops at their fitted
        # positions, positions refitted with the moved discs, then the held-out cases scored with them
        def obs_at(rig_, xx, yy, hh, n=n_samp):
            return plate_nu.twin_group_delays(simulate(flat, rig_, xx, yy, hh), cfg_sim, n, *noise)
        shift = fit_sensor_shift(lambda rig_: obs_at(rig_, xf, yf, h), per_rep, sigma, rig)
        rig_s = shifted_rig(rig, shift)
        xs, ys = plate_fem.fit_positions(lambda xx, yy, hh: obs_at(rig_s, xx, yy, hh), per_rep, sigma, x, y, h, ks)
        row["sensor_shift_mm"] = shift.tolist()
        row["chi2_dof_sensors"], row["rms_us_sensors"] = band_stats(obs_at(rig_s, xs, ys, h), per_rep, sigma,
                                                                    len(x) + 4)
        if held:
            t_h, gd_h, n_h, xh, yh, hh = held
            f_hs = lambda xx, yy, hh_: obs_at(rig_s, xx, yy, hh_, n_h)  # noqa: E731
            xhs, yhs = plate_fem.fit_positions(f_hs, gd_h, sigma, xh, yh, hh, ks)
            row["chi2_dof_held_sensors"], row["rms_us_held_sensors"] = band_stats(f_hs(xhs, yhs, hh), gd_h,
                                                                                  sigma, len(xh))
    if a.channel_delays:
        # a per-channel, per-band delay the twin lacks (e.g. the input network's phase at low frequency):
        # fitted on the calibration drops, positions refitted with it, then checked on the held-out cases
        d = channel_delays(per_rep - o_cal, sigma)
        off = pair_offsets(d)[None]
        for _ in range(2):
            xd, yd = plate_fem.fit_positions(lambda xx, yy, hh: obs(flat, xx, yy, hh) + off, per_rep, sigma,
                                             x, y, h, ks)
            o_d = obs(flat, xd, yd, h)
            d = channel_delays(per_rep - o_d, sigma)
            off = pair_offsets(d)[None]
        row["channel_delays_us"] = d.tolist()
        row["chi2_dof_chdelay"], row["rms_us_chdelay"] = band_stats(o_d + off, per_rep, sigma, len(x) + 4.5)
    if a.per_band_e:
        factors = np.array([0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15])
        chi = []
        for f in factors:
            r = obs(dict(flat, e_pa=flat["e_pa"] * f), xf, yf, h) - per_rep
            chi.append(np.nansum((r / sigma[None, :, None]) ** 2, axis=(0, 2)))
        chi = np.array(chi)                                               # [factors, bands]
        best = []
        for b in range(chi.shape[1]):
            i = int(np.clip(np.argmin(chi[:, b]), 1, len(factors) - 2))
            c = np.polyfit(factors[i - 1:i + 2], chi[i - 1:i + 2, b], 2)
            best.append(float(-c[1] / (2 * c[0]) * flat["e_pa"] / 1e6) if c[0] > 0 else float("nan"))
        row["E_per_band_mpa"] = best
        row["chi2_dof_per_band_at_best"] = (chi.min(axis=0) / (per_rep[:, 0].size - 2 * len(x) / 3)).tolist()
    if a.per_band_ds:
        factors = np.array([0.9, 0.95, 1.0, 1.05, 1.1])
        ds0 = flat["damping_per_s"]
        chi = np.array([np.nansum(((obs(dict(flat, damping_per_s=ds0 * f), xf, yf, h) - per_rep)
                                   / sigma[None, :, None]) ** 2, axis=(0, 2)) for f in factors])
        ds_b = []
        for b in range(chi.shape[1]):
            i = int(np.clip(np.argmin(chi[:, b]), 1, len(factors) - 2))
            c = np.polyfit(factors[i - 1:i + 2], chi[i - 1:i + 2, b], 2)
            ds_b.append(float(np.clip(-c[1] / (2 * c[0]), 0.7, 1.3) * ds0) if c[0] > 0 else ds0 * factors[i])
        row["ds_per_band"] = ds_b

        def obs_pb(xx, yy, hh, n=n_samp):
            return np.stack([obs(dict(flat, damping_per_s=d), xx, yy, hh, n)[:, b] for b, d in enumerate(ds_b)], 1)
        xb, yb = plate_fem.fit_positions(obs_pb, per_rep, sigma, x, y, h, ks)
        row["chi2_dof_pbds"], row["rms_us_pbds"] = band_stats(obs_pb(xb, yb, h), per_rep, sigma, len(x) + 1.5)
        if held:
            t_h, gd_h, n_h, xh, yh, hh = held
            f_hb = lambda xx, yy, hh_: obs_pb(xx, yy, hh_, n_h)  # noqa: E731
            xhb, yhb = plate_fem.fit_positions(f_hb, gd_h, sigma, xh, yh, hh, ks)
            row["chi2_dof_held_pbds"], row["rms_us_held_pbds"] = band_stats(f_hb(xhb, yhb, hh), gd_h, sigma, len(xh))
    p_fit = flat
    if a.rounds > 0:
        run_obs = lambda e, nu, ds, xx, yy, hh: obs(dict(flat, e_pa=e * 1e6, nu=nu, damping_per_s=ds), xx, yy, hh)  # noqa: E731
        fit = plate_nu.fit(run_obs, per_rep, sigma, names, x, y, h,
                           (flat["e_pa"] / 1e6, flat["nu"], flat["damping_per_s"]), rounds=a.rounds,
                           max_nfev=a.max_nfev, e_bounds=(1500.0, 9000.0), ds_bounds=(100.0, 1500.0))
        p_fit = dict(flat, e_pa=fit.e_mpa * 1e6, nu=fit.nu, damping_per_s=fit.damping_per_s)
        row.update(E_mpa=fit.e_mpa, nu=fit.nu, damping_per_s=fit.damping_per_s, chi2_dof_nu_stage=fit.chi2_dof,
                   aic_rms_us_fit=aic_rms(p_fit))
        row["chi2_dof_fit"], row["rms_us_fit"] = band_stats(obs(p_fit, fit.x_mm, fit.y_mm, h), per_rep, sigma,
                                                            len(x))
    if held:
        t_h, gd_h, n_h, xh, yh, hh = held
        f_h = lambda xx, yy, hh_: obs(p_fit, xx, yy, hh_, n_h)  # noqa: E731
        xhf, yhf = plate_fem.fit_positions(f_h, gd_h, sigma, xh, yh, hh, ks)
        row["chi2_dof_held"], row["rms_us_held"] = band_stats(f_h(xhf, yhf, hh), gd_h, sigma, len(xh))
        if a.channel_delays:
            off = pair_offsets(np.array(row["channel_delays_us"]))[None]
            f_hd = lambda xx, yy, hh_: obs(flat, xx, yy, hh_, n_h) + off  # noqa: E731
            xhd, yhd = plate_fem.fit_positions(f_hd, gd_h, sigma, xh, yh, hh, ks)
            row["chi2_dof_held_chdelay"], row["rms_us_held_chdelay"] = band_stats(f_hd(xhd, yhd, hh), gd_h,
                                                                                  sigma, len(xh))
        row["held_position_shift_rms_mm"] = float(np.sqrt(np.mean((xhf - xh) ** 2 + (yhf - yh) ** 2)))
    # the twin's own movement: its group delays at the reference suspect's positions (the first suspect of this
    # window), e.g. between meshes (numerical dispersion) or disc diameters, without the rig in it
    key = json.dumps(gd, sort_keys=True)
    if key not in refs:
        refs[key] = dict(sup=sup, xy=(xf, yf), o=o_cal)
        if held:
            refs[key].update(xy_h=(xhf, yhf), o_h=obs(flat, xhf, yhf, hh, n_h))
    else:
        ref = refs[key]
        d = obs(flat, *ref["xy"], h) - ref["o"]
        row["twin_shift_ref"] = ref["sup"]
        row["twin_shift_rms_us_cal"] = np.sqrt(np.nanmean(d ** 2, axis=(0, 2)))
        if held and "o_h" in ref:
            d = obs(flat, *ref["xy_h"], hh, n_h) - ref["o_h"]
            row["twin_shift_rms_us_held"] = np.sqrt(np.nanmean(d ** 2, axis=(0, 2)))
    row["seconds"] = time.perf_counter() - t0
    return row


def report(a, out, names):
    bands = [n.replace("group delay ", "") for n in names]
    print("\nsupport | chi2/dof at CAL (E, nu, D_s), positions fitted | rms us per band " + " / ".join(bands)
          + " | nu stage: E MPa, nu, D_s 1/s | chi2/dof (nu stage, projected) | chi2/dof, rms per band after "
          "| AIC DToA rms us at CAL E / fitted E | held-out cases: chi2/dof, rms per band")
    for sup, r in out.items():
        fit_s = (f"{r['E_mpa']:.0f}, {r['nu']:.3f}, {r['damping_per_s']:.0f} | {r['chi2_dof_nu_stage']:.1f} | "
                 f"{r['chi2_dof_fit']:.1f}, {' / '.join(f'{v:.1f}' for v in r['rms_us_fit'])} | "
                 f"{r['aic_rms_us_cal']:.1f} / {r['aic_rms_us_fit']:.1f}") if "E_mpa" in r else \
            f"- | - | - | {r['aic_rms_us_cal']:.1f} / -"
        held_s = (f"{r['chi2_dof_held']:.1f}, {' / '.join(f'{v:.1f}' for v in r['rms_us_held'])}"
                  if "chi2_dof_held" in r else "-")
        print(f"{sup} | {r['chi2_dof_cal']:.1f} | {' / '.join(f'{v:.1f}' for v in r['rms_us_cal'])} | {fit_s} | {held_s}")
    print("\ncompact: suspect | calibration cases chi2/dof, rms us per band | held-out cases chi2/dof, rms us per "
          "band (the measured group delays' own rms) | the twin's own shift from the reference suspect at fixed "
          "positions, rms us per band, calibration / held-out drops | s (" + " / ".join(bands) + "; rig-noise sigma "
          "per window in the suspect's row)")

    def us(v):
        return " / ".join(f"{x:.1f}" for x in v)
    for sup, r in out.items():
        held_s = (f"{r['chi2_dof_held']:.0f} | {us(r['rms_us_held'])} ({us(r['meas_rms_us_held'])})"
                  if "chi2_dof_held" in r else "- | -")
        shift = (f"{us(r['twin_shift_rms_us_cal'])}; {us(r.get('twin_shift_rms_us_held', []))} "
                 f"(from {r['twin_shift_ref']})" if "twin_shift_ref" in r else "reference")
        print(f"{sup} | {r['chi2_dof_cal']:.0f} | {us(r['rms_us_cal'])} ({us(r['meas_rms_us_cal'])}) | {held_s} | "
              f"{shift} | {r['seconds']:.0f}; sigma {us(r['sigma_us'])}")
    if a.sensor_positions:
        print("\ndisc centres fitted on the calibration drops: chi2/dof, rms per band; shifts (dx, dy) mm per "
              "channel; held-out cases without -> with them")
        for sup, r in out.items():
            sh = "; ".join(f"({v[0]:+.1f}, {v[1]:+.1f})" for v in r["sensor_shift_mm"])
            held_s = (f" | held out {r['chi2_dof_held']:.0f} -> {r['chi2_dof_held_sensors']:.0f} "
                      f"({' / '.join(f'{v:.1f}' for v in r['rms_us_held_sensors'])} us)"
                      if "chi2_dof_held_sensors" in r else "")
            print(f"{sup}: {r['chi2_dof_cal']:.0f} -> {r['chi2_dof_sensors']:.0f} "
                  f"({' / '.join(f'{v:.1f}' for v in r['rms_us_sensors'])} us); shifts {sh}{held_s}")
    if a.channel_delays:
        print("\nper-channel band delays fitted on the calibration drops (calibration's E, nu, D_s): chi2/dof, rms "
              "per band; channel delays us (channels 0..3) per band; held-out cases without -> with them")
        for sup, r in out.items():
            d = "; ".join(" ".join(f"{v:+.1f}" for v in band) for band in r["channel_delays_us"])
            held_s = (f" | held out {r['chi2_dof_held']:.0f} -> {r['chi2_dof_held_chdelay']:.0f} "
                      f"({' / '.join(f'{v:.1f}' for v in r['rms_us_held_chdelay'])} us)"
                      if "chi2_dof_held_chdelay" in r else "")
            print(f"{sup}: {r['chi2_dof_cal']:.0f} -> {r['chi2_dof_chdelay']:.0f} "
                  f"({' / '.join(f'{v:.1f}' for v in r['rms_us_chdelay'])} us); delays {d}{held_s}")
    if a.per_band_ds:
        print("\nD_s fitted to each band alone (1/s), " + " / ".join(bands) + "; chi2/dof, rms per band with each band's "
              "twin at its D_s (positions refitted); held-out cases without -> with them")
        for sup, r in out.items():
            held_s = (f" | held out {r['chi2_dof_held']:.0f} -> {r['chi2_dof_held_pbds']:.0f} "
                      f"({' / '.join(f'{v:.1f}' for v in r['rms_us_held_pbds'])} us)"
                      if "chi2_dof_held_pbds" in r else "")
            print(f"{sup}: D_s " + " / ".join(f"{v:.0f}" for v in r["ds_per_band"]) + f"; {r['chi2_dof_cal']:.0f} -> "
                  f"{r['chi2_dof_pbds']:.0f} ({' / '.join(f'{v:.1f}' for v in r['rms_us_pbds'])} us){held_s}")
    if a.per_band_e:
        print("\nE fitted to each band alone (MPa), " + " / ".join(bands) + ":")
        for sup, r in out.items():
            print(f"{sup}: " + " / ".join(f"{v:.0f}" for v in r["E_per_band_mpa"]))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


if __name__ == "__main__":
    main()
