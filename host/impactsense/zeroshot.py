"""Zero-shot: models trained only on the calibrated twin's virtual drops, tested on measured drops.

The seed's central claim (docs/method.md, Tables 7-9). The flow:
  calibrate on four measured drops (CAL.json) -> simulate N virtual drops -> train on them (all) ->
  evaluate on the measured test split, which excludes the calibration drops; the measured-trained model is
  trained on the rest of the same session with the same split, so both rows see the same test drops.

Only the four calibration drops ever inform the sim-trained model about the rig: besides the plate, PZT and
damping parameters, the per-channel timing offsets and gains (the `channel_delay` and `sensor_gain` effects of the diagnosis:
the rig's electronics and bonds, which the plate model cannot know) are fitted as measured minus simulated
ToA, and measured over simulated energy, on those drops; so is the twin's error in the picks' group velocity
(the part of measured minus simulated ToA that grows with the path length: a few per cent between the twin's
picks and the rig's, docs/findings.md; uncorrected, that scale error of the physics position is one the
sim-trained forests cannot undo); so are the band picks' delays and speed, the same way (fit_band_on_calibration_drops), and on a plate with elliptical wavefronts the localiser's travel models themselves, as far as the four drops determine them (map_travel_refit: a MAP with the twin's constants as the prior; the twin's anisotropy is the weakest part of it); and so is the twin's spectral tilt: the measured
minus simulated arrival energies and difference energies (log10, summed over sensors) of those drops, by
which the virtual drops' energy features are shifted before the energy classifier is trained (the twin's
mesh and sensor model lose some of the highest frequencies: a constant offset per feature, while the features' growth with the drop height matches the rig's).

The reported uncertainty (uncertainty_mm, a calibrated 1-sigma radial error: twin.calibrated_uncertainty)
keeps the shape a + b spread and the misfit inflation fitted on the virtual drops' out-of-fold errors, but
measured drops err further than simulated ones (the twin is not the rig): with the virtual drops' constants
alone u covers ~0.45 of the measured test split's errors at 1x (target 0.63; rms(r / u) ~1.4). Its scale
comes from the calibration drops (uncertainty_on_calibration_drops): the maximum-likelihood factor
k = sqrt(mean (r / u)^2) by which a and b are multiplied, read with each calibration position held out in
turn (the twin refitted on the others: reads wide, three positions' table is poorer than the final four's)
and in sample (reads narrow), k their geometric mean.

The board samples 4 x 50 kHz with the SAADC's scan delays, so `impactsense export` makes the model again for
it (board_model), the same way: trained on the board's captures of the virtual drops, then all of the above
(fit_on_calibration_drops) on the board's captures of the calibration drops and of their simulated twins.
The model card's `zero_shot` record (the calibration file and its hash, the calibration drops, the measured
session and its test split) is what it is rebuilt from and scored on.
"""

from __future__ import annotations

import hashlib
import json
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from .calibration_drops import (calibration_rows, fit_band_on_calibration_drops, fit_channels_on_calibration_drops,
                                fit_energy_offsets, map_travel_refit)
from .data import Session, load_session, read_json, write_session
from .errors import ConfigError, DataError
from .height_class import class_cut
from .models import ENERGY_FEATURES, TWIN_CLASSIFIER, columns, fit_energy_classifier, impact_energy_j, twin_estimate
from .outputs import MANIFEST, adopt, write_file
from .pipeline import featurize
from .seed import SEED_ROWS
from .sim import SimParams, simulate_drops
from .sim.doe import DEFAULT_HEIGHTS_MM, measured_heights, virtual_drops
from .signal import SignalConfig
from .sitemap import (BUNDLED, SITE_MAP_CPU_S, SiteMap, build_site_map, describe_cost, every_for_budget,
                      twin_features)
from .split import case_split
from .travel import wants_metric
from .twin import fit_twin
from .workflow import evaluate, train


def cached_twin_site_map(params, out: Path, name: str = "site-map.npz"):
    """The twin's site map when one is cached (the bundled twin's, or out/name made with these params), else None.
    The map's drops are noise-free (sitemap.build_site_map), so a twin that differs only in its record noise
    (noise_counts_rms, the rig's logger's) has the same map."""
    def same_twin(site) -> bool:   # parameters added since the map was made take their defaults
        try:
            made = SimParams.from_dict(dict(site.source.get("sim_params") or {}))
            return made.replace(noise_counts_rms=params.noise_counts_rms) == params
        except Exception:
            return False

    for path in (BUNDLED, out / name):   # the bundled twin's map, when this is the bundled twin
        if path.is_file():
            site = SiteMap.load(path)
            if same_twin(site):
                return site
    return None


def build_twin_site_map(params, session: Session, progress: bool = True, cpu_budget_s: float | None = SITE_MAP_CPU_S):
    """The twin's site map of the session's rig (what twin_site_map builds when none is cached): every grid
    point simulated when its estimated CPU time is within cpu_budget_s, else fewer (`sitemap.every_for_budget`;
    printed when progress)."""
    cost = every_for_budget(params, session.rig, cpu_budget_s)
    if progress:
        print(f"the twin's site map: {describe_cost(cost)}", flush=True)
    return build_site_map(params, session.rig, SignalConfig.for_rig(session.rig), progress=progress, solver="auto",
                          every=cost["every"], edge_band_mm=cost["edge_band_mm"])


def twin_site_map(params, session: Session, out: Path, progress: bool = True, name: str = "site-map.npz",
                  built=None):
    """The calibrated twin's site map, cached in out/name (rebuilt when the twin changed). built: the map
    build_twin_site_map made already for these params and session (simulate-dataset makes it beside the
    virtual drops), cached instead of building it again."""
    site = cached_twin_site_map(params, out, name)
    if site is not None:
        return site
    path = out / name
    site = built if built is not None else build_twin_site_map(params, session, progress)
    site.save(path)
    if (out / MANIFEST).is_file():      # a cache in a folder the tool wrote (a virtual session): still the tool's
        adopt(out, [path.name])
    return site


def fit_twin_on_calibration_drops(model, session: Session, rows: np.ndarray, site) -> None:
    """The rig's offsets and weights of the twin's fingerprint from the calibration drops only; the slopes
    (d feature / d log10 height) and the uncertainty's constants stay the virtual drops'. Four positions
    cannot tell 16 offsets and four variances well (twin.fit_twin): the offsets are a channel + kind table
    (the rig's channel gains, the twin's spectral tilt), and the weights keep the virtual drops' shape (how
    much each kind of energy varies from site to site, which the twin knows) with one scale from the
    calibration drops' residuals (what it gains over the many-drop estimator, measured with
    `python3 benchmarks/bench_zeroshot_class.py`: docs/findings.md, "Numbers from the code's docstrings").
    Rescaled weights keep their shape, so the fit is the same when model.twin_fit is already one of these."""
    meas = featurize(session.adc[rows], model.signal)
    feats, usable = twin_features(meas)
    old = model.twin_fit
    fit = fit_twin(feats, usable, site, session.xy_mm[rows], session.height_mm[rows], slope=np.asarray(old.slope),
                   weight_shape=np.asarray(old.weight), additive_offsets=True)
    model.twin_fit = replace(fit, **{k: getattr(old, k) for k in UNCERTAINTY_FIELDS})


UNCERTAINTY_FIELDS = ("uncertainty_offset_mm", "uncertainty_scale", "uncertainty_misfit_ref")


def adapt_to_rig(model, session: Session, rows: np.ndarray, cal_sim: np.ndarray, virtual_signal: SignalConfig,
                 site) -> tuple[list[float], list[float], float]:
    """The sim-trained model made to read the rig, from the calibration drops `rows` (cal_sim their
    simulated twins, virtual_signal the localiser fitted on the virtual drops): channel delays, gains and
    the rig's group velocity, the band picks' delays and velocity (fit_band_on_calibration_drops), on a plate
    with elliptical wavefronts the travel models read from the calibration drops as far as they determine
    them (map_travel_refit: the virtual drops' constants as the prior; its record in model.card), and with a
    site map the twin's offsets and weights. The delays the capture
    itself puts on the channels (the board's SAADC scan, model.signal.capture_delay_us) are in both the
    measured and the simulated drops and stay as they are. Returns (the rig's delays, gains, velocity)."""
    delays, gains, velocity = fit_channels_on_calibration_drops(session, rows, cal_sim, virtual_signal)
    model.signal.velocity_mm_per_us = velocity
    model.signal.rig_delay_us = [float(d) for d in delays]
    model.signal.channel_gain = gains
    band = fit_band_on_calibration_drops(session, rows, cal_sim, virtual_signal, gains)
    if band is not None:
        model.signal.band_delay_us, model.signal.band_velocity_mm_per_us = band
    if wants_metric(session.rig):   # as far as the four drops determine it: a MAP with the twin's as prior
        model.signal, refit = map_travel_refit(session, rows, model.signal, virtual_signal)
        model.card["travel_refit_on_calibration_drops"] = refit
    if site is not None:
        fit_twin_on_calibration_drops(model, session, rows, site)
    return delays, gains, velocity


def uncertainty_on_calibration_drops(model, session: Session, rows: np.ndarray, site) -> dict:
    """The factor k on the reported uncertainty from the calibration drops: k = sqrt(mean (r / u)^2), the
    maximum-likelihood scale of a Rayleigh error with E r^2 = (k u)^2, r the drops' radial errors and u the
    model's uncertainties (its virtual drops' constants), read two ways that bracket a new drop's:
    - held out: each position in turn, the twin's offsets and weights fitted on the other positions' drops
      (fit_twin_on_calibration_drops). Three positions' table is a poorer fit than the final model's four
      (the held-out position lies outside it), so this reads wide;
    - in sample: the model's own twin fit (all four positions), which saw the drops, so this reads narrow.
    k is their geometric mean (docs/findings.md, "The zero-shot uncertainty's scale: a bracket"). The
    forests are the virtual drops' throughout (they never saw a measured drop); the channel delays, gains
    and group velocity are the model's, from all four positions, as the final model's are: refitted from
    three they cost a held-out position more than the fourth position costs the final model
    (docs/findings.md, "Numbers from the code's docstrings"). Returns factor, factor_held_out,
    factor_in_sample, n (held-out drops with an estimate), positions and rms_error_mm (of those drops)."""
    xy = session.xy_mm[rows]
    groups = np.unique(np.round(xy, 1), axis=0, return_inverse=True)[1].ravel()
    if groups.max() < 1:
        raise DataError("calibration drops", None, "the uncertainty's scale needs calibration drops at >= 2 "
                        "positions (each is held out in turn)")
    features = model.featurize(session.adc[rows])
    err, u = np.full(len(rows), np.nan), np.full(len(rows), np.nan)
    for g in np.unique(groups):
        held = groups == g
        fold = replace(model)
        fit_twin_on_calibration_drops(fold, session, rows[~held], site)
        p = fold.predict(features.take(np.flatnonzero(held)))
        err[held] = np.linalg.norm(p["xy_mm"] - xy[held], axis=1)
        u[held] = p["uncertainty_mm"]
    ok = np.isfinite(err) & np.isfinite(u) & (u > 0)
    if ok.sum() < 4:
        raise DataError("calibration drops", None, f"only {int(ok.sum())} held-out calibration drops have a "
                        "twin estimate (need >= 4 to scale the uncertainty)")
    held_out = float(np.sqrt(np.mean((err[ok] / u[ok]) ** 2)))
    p = model.predict(features)
    r_in = np.linalg.norm(p["xy_mm"] - xy, axis=1)
    u_in = p["uncertainty_mm"]
    ok_in = np.isfinite(r_in) & np.isfinite(u_in) & (u_in > 0)
    in_sample = float(np.sqrt(np.mean((r_in[ok_in] / u_in[ok_in]) ** 2))) if ok_in.sum() >= 4 else held_out
    return {"factor": float(np.sqrt(held_out * in_sample)), "factor_held_out": held_out,
            "factor_in_sample": in_sample, "n": int(ok.sum()), "positions": int(groups.max()) + 1,
            "rms_error_mm": float(np.sqrt(np.mean(err[ok] ** 2)))}


def class_boundary_in_the_sessions_gap(model, heights_mm, ball_mass_g: float, virtual: Session | None,
                                       virtual_signal: SignalConfig, fit) -> float | None:
    """The twin's classifier trained again on the virtual drops (their twin height estimates with the twin
    `fit` fitted on them) with its boundary in the calibrated session's gap between drop heights around the
    model's threshold (height_class.class_cut), not at the threshold: a session dropped from a few heights has
    one of them on its 75th percentile, and the virtual drops' 5 mm steps put the classifier's boundary just
    under that height, where every drop from it is a coin toss. The virtual drops whose heights fall inside the
    session's gap are left out of the classifier's training (else the stumps cut between the nearest virtual
    heights either side of the boundary, e.g. 230 | 235 mm, not in the middle of the session's 230 | 240 mm gap).
    The drops' labels (m g h >= the threshold) are unchanged. heights_mm: the calibrated session's drop heights.
    Returns the boundary (J), None when the session's heights leave no gap there (or no virtual drops are given)."""
    h = np.asarray(heights_mm, float)
    h = h[np.isfinite(h) & (h > 0)]
    if h.size == 0 or fit is None or virtual is None:
        return None
    threshold = float(model.energy_threshold_j)
    e = impact_energy_j(h, ball_mass_g)
    try:
        boundary = float(np.exp(class_cut(e, threshold)))
    except DataError:
        return None
    e_virtual = impact_energy_j(np.asarray(virtual.height_mm, float), virtual.rig.ball_mass_g)
    below, above = e[e < threshold].max(), e[e >= threshold].min()
    if not ((e_virtual > below) & (e_virtual < above)).any():
        return None   # no virtual drop falls in the session's gap: its boundary is the virtual drops' already
    vf = featurize(virtual.adc, virtual_signal)
    use = np.flatnonzero(vf.usable)
    feats, usable = twin_features(vf.take(use))
    est = np.asarray(twin_estimate(model.site_map, fit, feats, usable, vf.phys_xy_mm[use])["log10_height_mm"], float)
    e_use = impact_energy_j(np.asarray(virtual.height_mm, float)[use], virtual.rig.ball_mass_g)
    # the virtual drops inside the session's gap are left out: the session has none there, and the twin's finer
    # height steps would put the stumps' cut between the nearest virtual heights either side of the boundary
    # (e.g. 230 | 235 mm, 1 % above the session's 230 mm drops) instead of the middle of the session's gap (230 | 240)
    ok = np.isfinite(est) & ~((e_use > below) & (e_use < above))
    label = (e_use[ok] >= boundary).astype(int)
    if np.unique(label).size < 2:
        return None
    model.forest_energy = TWIN_CLASSIFIER.classifier().fit(est[ok, None], label)
    return boundary


def fit_on_calibration_drops(model, session: Session, rows: np.ndarray, cal_sim: np.ndarray, site,
                             virtual: Session | None, class_heights_mm=None) -> dict:
    """Everything the calibration drops teach the sim-trained `model` (fitted on the virtual drops, its signal
    their localiser), in place: the rig's channel delays and gains and group velocity (adapt_to_rig), with
    a site map the twin's offsets and weights and the uncertainty's scale (uncertainty_on_calibration_drops),
    without one the energy classifier trained again on the virtual drops' features shifted by the twin's
    spectral tilt (fit_energy_offsets). session.adc[rows] and cal_sim are the calibration drops and their
    simulated twins, and virtual.adc the virtual drops, as the model's signal reads them: the rig's
    recordings, or the board's captures (adapt_to_rig). Returns the model card's record
    of these fits and, under "_virtual_twin", the twin fit before the uncertainty's scale."""
    virtual_signal = SignalConfig.from_dict(model.signal.to_dict())
    fitted_on_virtual = model.twin_fit
    delays, gains, velocity = adapt_to_rig(model, session, rows, cal_sim, virtual_signal, site)
    offsets, scale, virtual_twin, boundary = {}, None, None, None
    if site is not None:
        heights = session.height_mm if class_heights_mm is None else class_heights_mm
        boundary = class_boundary_in_the_sessions_gap(model, heights, session.rig.ball_mass_g, virtual,
                                                      virtual_signal, fitted_on_virtual)
        scale = uncertainty_on_calibration_drops(model, session, rows, site)
        virtual_twin = model.twin_fit
        k = scale["factor"]
        model.twin_fit = replace(virtual_twin, uncertainty_offset_mm=k * virtual_twin.uncertainty_offset_mm,
                                 uncertainty_scale=k * virtual_twin.uncertainty_scale)
    else:
        # the energy classifier learns on virtual features as the rig sees them
        offsets = fit_energy_offsets(session, rows, cal_sim, model.signal, virtual_signal)
        vf = featurize(virtual.adc, virtual_signal)
        use = vf.usable
        X = vf.vector[use][:, columns(ENERGY_FEATURES)].astype(float)
        for k, name in enumerate(ENERGY_FEATURES):
            X[:, k] += offsets.get(name, 0.0)
        model.forest_energy, model.energy_threshold_j = fit_energy_classifier(
            X, impact_energy_j(virtual.height_mm[use], virtual.rig.ball_mass_g))
        model.energy_class_features = list(ENERGY_FEATURES)
    return {"channel_delay_from_calibration_drops_us": delays, "channel_gain_from_calibration_drops": gains,
            "velocity_mm_per_us_virtual_drops": virtual_signal.velocity_mm_per_us,
            "velocity_mm_per_us_from_calibration_drops": velocity,
            **({"band_delay_from_calibration_drops_us": model.signal.band_delay_us,
                "band_velocity_mm_per_us_from_calibration_drops": model.signal.band_velocity_mm_per_us}
               if model.signal.band_velocity_mm_per_us > 0 else {}),
            "travel_refit_on_calibration_drops": model.card.pop("travel_refit_on_calibration_drops", None),
            "energy_feature_offsets_from_calibration_drops": offsets,
            "energy_class_boundary_j": boundary,
            "uncertainty_factor_from_calibration_drops": scale, "_virtual_twin": virtual_twin}


def uncertainty_figures(session: Session, model, rows: np.ndarray) -> dict | None:
    """How the reported uncertainty u covers the radial errors r on `rows`: the fraction within 1x and 2x
    (0.63 and 0.98 for a calibrated 1-sigma of a 2-D Gaussian error), Spearman of u against r and
    rms(r / u). None for a model without a position uncertainty (no site map)."""
    p = model.predict(model.featurize(session.adc[rows]))
    err = np.linalg.norm(p["xy_mm"] - session.xy_mm[rows], axis=1)
    u = p["uncertainty_mm"]
    ok = np.isfinite(err) & np.isfinite(u) & (u > 0)
    if ok.sum() < 2:
        return None
    e, v = err[ok], u[ok]
    return {"n": int(ok.sum()), "within_1x": float(np.mean(e <= v)), "within_2x": float(np.mean(e <= 2 * v)),
            "spearman": float(spearmanr(v, e).statistic), "rms_error_over_u": float(np.sqrt(np.mean((e / v) ** 2)))}


def virtual_set(params, session: Session, sim_dir: Path, n: int, seed: int, workers: int,
                progress: bool) -> tuple[Session, bool]:
    """The virtual data set, written as a session folder so every tool can read it. Reused only when it was
    simulated with this twin and seed (a set from another twin would be tested under this calibration's
    name); `made_with.json` is written last, so an interrupted run leaves no set that counts as made.
    Returns (the set, whether it came from the cache)."""
    heights = measured_heights(session)
    made_with = {"sim_params": params.to_dict(), "seed": seed, "layout": "sim.doe.virtual_drops"}
    if heights != DEFAULT_HEIGHTS_MM:   # (the bundled rig's cached sets keep their stamp)
        made_with["heights_mm"] = list(heights)
    stamp = sim_dir / "made_with.json"
    try:
        cached = (sim_dir / "recordings.npz").is_file() and json.loads(stamp.read_text()) == made_with
    except (OSError, ValueError):
        cached = False
    if not cached:
        stamp.unlink(missing_ok=True)
        x, y, h = virtual_drops(session.rig, n, seed, heights_mm=heights)
        rng = np.random.default_rng(seed)
        adc = simulate_drops(params, session.rig, x, y, h, noise=True, seed=int(rng.integers(1 << 31)),
                             workers=workers, progress=progress)
        write_session(sim_dir, session.rig, x, y, h, adc, extra_files={stamp.name: json.dumps(made_with, indent=1)})
    return load_session(sim_dir), cached


def read_calibration(cal_path: str | Path) -> dict:
    """CAL.json as a dict, or a DataError naming the file and field (checked before any work starts)."""
    cal_path = Path(cal_path)
    cal = read_json(cal_path, "calibration file not found (run `impactsense calibrate` first)")
    if "sim_params" not in cal:
        raise DataError(cal_path, "sim_params", "missing key")
    return cal


def calibration_twins(params, session: Session, rows: np.ndarray, seed: int, workers: int = 2) -> np.ndarray:
    """The calibration drops `rows` simulated with the twin `params` (noise seeded by `seed`): uint16 [R, 4, n]."""
    return simulate_drops(params, session.rig, session.x_mm[rows], session.y_mm[rows], session.height_mm[rows],
                          noise=True, seed=seed, workers=workers, progress=False)


def zero_shot_card(cal_path: str | Path, session: Session, cal_rows: np.ndarray, test_rows: np.ndarray, seed: int,
                   n_virtual: int) -> dict:
    """The model card's record of a sim-trained model: which calibration taught it the rig (the file, its
    hash, the calibration drops and the measured session) and the measured test split it is scored on;
    enough for `impactsense export` to make it again at the board's rate (board_model). The virtual drops
    are the card's `split`."""
    cal_path = Path(cal_path).resolve()
    return {"calibration": str(cal_path), "zero_shot": {
        "sim_trained": f"trained on {n_virtual} virtual drops of the twin {cal_path} only; the rig's channel "
                       "delays and gains, the twin's group velocity, fingerprint offsets and weights and the "
                       "uncertainty's scale fitted on the calibration drops alone",
        "calibration": str(cal_path), "calibration_sha256": hashlib.sha256(cal_path.read_bytes()).hexdigest(),
        "calibration_recordings": session.recording_id[cal_rows].tolist(),
        "data_path": str(session.path), "data_hash": session.fingerprint(),
        "test_recordings": session.recording_id[test_rows].tolist(),
        "seed": int(seed)}}   # the noise seed of the calibration drops' simulated twins (calibration_twins)



def run_zero_shot(session: Session, cal_path: str | Path, out_dir: str | Path, n_virtual: int = 490,
                  seed: int = 0, test_fraction: float = 0.2, workers: int = 2, progress: bool = True,
                  use_twin: bool = True) -> dict:
    cal_path = Path(cal_path)
    cal = read_calibration(cal_path)
    params = SimParams.from_json(cal_path)
    cal_rows = calibration_rows(session, cal)
    if n_virtual < 2:
        raise ConfigError(f"--virtual needs at least 2 virtual drops, got {n_virtual}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    wall: dict[str, float] = {}

    @contextmanager
    def stage(name):     # wall time of each step
        t = time.perf_counter()
        yield
        wall[name] = round(time.perf_counter() - t, 1)

    sim_dir = out / f"virtual-{n_virtual}"
    with stage("virtual_set"):
        virtual, cached = virtual_set(params, session, sim_dir, n_virtual, seed, workers, progress)
    if cached:
        wall["virtual_set (cached)"] = wall.pop("virtual_set")
    # The twin's site map for the energy class (the twin's fingerprint, twin.py).
    with stage("site_map"):
        site = twin_site_map(params, session, out, progress) if use_twin else None
    # Sim-trained: localiser constants and forests from the virtual drops only ...
    with stage("train_sim"):
        sim_model, _ = train(virtual, None, test_fraction=0.0, seed=seed, site_map=site,
                             rig_drops=(session.adc[cal_rows], session.xy_mm[cal_rows]))
    # ... and everything about the rig from the calibration drops (fit_on_calibration_drops).
    _, test_rows = case_split(session.case_id, test_fraction, seed, cal_rows)
    with stage("fit_on_calibration_drops"):
        cal_sim = calibration_twins(params, session, cal_rows, seed, workers)
        fits = fit_on_calibration_drops(sim_model, session, cal_rows, cal_sim, site, virtual)
    virtual_twin = fits.pop("_virtual_twin")
    sim_model.save(out / "model-sim", extra_card={
        "trained_on": str(sim_dir), **fits,
        **zero_shot_card(cal_path, session, cal_rows, test_rows, seed, len(virtual))})

    # Measured-trained on the same session, same split, calibration drops excluded everywhere.
    with stage("train_measured"):
        meas_model, split = train(session, out / "model-measured", test_fraction, seed, exclude_rows=cal_rows,
                                  site_map=site)
    assert np.array_equal(np.asarray(split["test_recordings"], int), session.recording_id[test_rows])
    assert not np.isin(test_rows, cal_rows).any()
    with stage("evaluate"):
        rep_sim = evaluate(session, sim_model, rows=test_rows)
        rep_meas = evaluate(session, meas_model, rows=test_rows)
        uncertainty = {"sim_trained": uncertainty_figures(session, sim_model, test_rows),
                       "measured_trained": uncertainty_figures(session, meas_model, test_rows)}
        if virtual_twin is not None:
            uncertainty["sim_trained_virtual_constants"] = uncertainty_figures(
                session, replace(sim_model, twin_fit=virtual_twin), test_rows)
            uncertainty["factor_from_calibration_drops"] = fits["uncertainty_factor_from_calibration_drops"]
    result = {
        "calibration": str(cal_path),
        "calibration_recordings": cal_rows.tolist(),
        "virtual_drops": len(virtual),
        "test_recordings": test_rows.tolist(),
        "channel_delay_us_from_calibration_drops": fits["channel_delay_from_calibration_drops_us"],
        "channel_gain_from_calibration_drops": fits["channel_gain_from_calibration_drops"],
        **{k: fits[k] for k in ("velocity_mm_per_us_virtual_drops", "velocity_mm_per_us_from_calibration_drops",
                                "energy_feature_offsets_from_calibration_drops")},
        "sim_trained": {k: v for k, v in rep_sim.items() if not k.startswith("_")},
        "measured_trained": {k: v for k, v in rep_meas.items() if not k.startswith("_")},
        "uncertainty": uncertainty,
        "wall_time_s": wall,
    }
    write_file(out / "zero-shot.json", json.dumps(result, indent=1))
    result["_reports"] = {"sim": rep_sim, "measured": rep_meas}
    return result


def zero_shot_table(result: dict, seed_rows: bool = True) -> str:
    """Our sim- and measured-trained rows, each after the seed paper's (its Tables 7-9 are the bundled rig's:
    seed_rows False on any other session, whose table then holds ours only)."""
    lines = [f"{'':46s} {'R2':>6s} {'RMSE mm':>8s} {'MAE mm':>7s} {'class acc':>9s}"]
    for region, label in (("all", "whole plate"), ("inner", "inner region")):
        for kind, key in (("sim-trained", "sim_trained"), ("measured-trained", "measured_trained")):
            if seed_rows:
                r2, rmse, mae, acc = SEED_ROWS[f"{kind}, {label}"]
                lines.append(f"{'seed, ' + kind + ', ' + label:46s} {r2:6.2f} {rmse:8.1f} {mae:7.1f} {acc:9.2f}")
            m = result[key][region]
            lines.append(f"{'impactsense, ' + kind + ', ' + label:46s} {m['r2']:6.3f} {m['rmse_mm']:8.2f} "
                         f"{m['mae_mm']:7.2f} {result[key]['energy_class_accuracy']:9.2f}")
    lines += uncertainty_lines(result.get("uncertainty") or {})
    if result.get("wall_time_s"):
        lines.append("wall time [s]: " + ", ".join(f"{k} {v:.1f}" for k, v in result["wall_time_s"].items()))
    return "\n".join(lines)


def uncertainty_lines(unc: dict) -> list[str]:
    """The table's rows on the reported uncertainty (uncertainty_figures) on the measured test split."""
    rows = [(label, unc.get(key)) for key, label in (("sim_trained", "sim-trained"),
                                                      ("sim_trained_virtual_constants",
                                                       "sim-trained, virtual drops' scale alone"),
                                                      ("measured_trained", "measured-trained"))]
    rows = [(label, f) for label, f in rows if f]
    if not rows:
        return []
    lines = ["uncertainty_mm (1-sigma radial), measured test split: errors within 1x / 2x (0.63 / 0.98 if calibrated)"]
    lines += [f"  {label:44s} {f['within_1x']:.2f} / {f['within_2x']:.2f}  rho {f['spearman']:+.2f}  "
              f"rms(error / u) {f['rms_error_over_u']:.2f}" for label, f in rows]
    if unc.get("factor_from_calibration_drops"):
        s = unc["factor_from_calibration_drops"]
        lines.append(f"  sim-trained scale x{s['factor']:.2f} from {s['n']} calibration drops: geometric mean of "
                     f"x{s['factor_held_out']:.2f} with each of their {s['positions']} positions held out in turn "
                     f"(rms error {s['rms_error_mm']:.2f} mm) and x{s['factor_in_sample']:.2f} in sample")
    return lines

