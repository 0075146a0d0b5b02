"""`impactsense calibrate`: recovery of known parameters, bad input, caching, and its building blocks."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import qmc

from impactsense import cli
from impactsense.calibration import _standin, arrival, bands, drops, fem, pipeline, plate, screening, surrogates
from impactsense.data import load_session, write_session
from impactsense.errors import ConfigError, DataError

SESSION1 = Path(__file__).resolve().parents[1] / "host/impactsense/data/session-1"


@pytest.fixture(scope="module")
def rig():
    return load_session(SESSION1).rig


def _cases(n_cases, seed=1):
    u = qmc.Sobol(3, seed=seed).random(32)[:n_cases]
    # keep off the centre lines (Eq. 35 needs a clear nearest sensor) and >= 45 mm from the sensors
    side = np.where(u[:, 0] < 0.5, 0, 1)
    x = np.where(side == 0, 50 + u[:, 0] * 2 * 80, 190 + (u[:, 0] - 0.5) * 2 * 80)
    y = 50 + u[:, 1] * 217
    h = 100 + np.round(u[:, 2] * 20) * 5
    return x, y, h


def _session(tmp_path, rig, simulate, truth, *, n_cases=16, reps=3, jitter_mm=1.0, seed=3, mirror_x=False,
             name="sess"):
    """Drops made by `simulate` with `truth`, noise and position jitter; declared at the nominal positions."""
    x, y, h = _cases(n_cases)
    X, Y, H = (np.repeat(v, reps) for v in (x, y, h))
    rng = np.random.default_rng(seed)
    jx, jy = X + rng.normal(0, jitter_mm, X.size), Y + rng.normal(0, jitter_mm, Y.size)
    adc = simulate(truth, rig, jx, jy, H)
    decl_x = rig.plate_x_mm - X if mirror_x else X
    path = tmp_path / name
    write_session(path, rig, decl_x, Y, H, adc, case_id=np.repeat(np.arange(n_cases), reps),
                  repetition=np.tile(np.arange(reps), n_cases))
    return path


def fem_calibration_drops(tmp_path, rig, truth, *, reps, element_mm=5.0, tol_us=0.0, noise=(1.5, 4, 0)):
    """Four cases the project's FEM made with `truth` (12 ms records, rig noise, 1 mm position jitter, the
    coarse mesh), as a calibration stage sees them (`problem.DropsAndTwin`: the twin is the FEM simulator on
    the same mesh, `noise` the rig noise put on its records). `tol_us` is Eq. 35's tolerance for choosing the
    four cases."""
    from impactsense.calibration.problem import DropsAndTwin
    from impactsense.sim import SimParams, simulate_drops

    mesh = {"element_mm": element_mm}

    def noisy(p, rig_, x, y, h):
        return simulate_drops(SimParams.from_rig(rig_, **p, **mesh, duration_ms=12.0), rig_, x, y, h, noise=True,
                              seed=5, progress=False)

    session = load_session(_session(tmp_path, rig, noisy, truth, n_cases=4, reps=reps))
    cfg = pipeline.measured_core_config(rig, pipeline.CalibrateOptions())
    feats = drops.extract(session, cfg)
    targets = drops.select_drops(session, feats, [0, 1, 2, 3], tol_us=tol_us)
    return DropsAndTwin(session, targets, feats, cfg, pipeline.sim_core_config(rig, pipeline.CalibrateOptions()),
                        fem.fem_simulator(2, **mesh), noise)


def _standin_noisy(truth, rig, x, y, h):
    return _standin.standin_simulate(truth, rig, x, y, h, noise=True, seed=11)


def _standin_clean(p, rig, x, y, h):
    return _standin.standin_simulate(p, rig, x, y, h)


TRUTH_E, TRUTH_NU, TRUTH_DS = 3400.0, 0.35, 650.0
SECOND_TRUTH = (4500.0, 0.33, 800.0)


def _truth(rig, e_mpa=TRUTH_E, nu=TRUTH_NU, d_s=TRUTH_DS):
    t = fem.base_params(rig, e_mpa, nu)
    t["damping_per_s"] = d_s
    return t


def _small_opts(**kw):
    base = dict(budget=32, e_min_mpa=2000.0, e_max_mpa=5000.0, e_step_mpa=50.0, nu_step=0.01,
                surrogate_trials=3, progress=False, workers=2)
    base.update(kw)
    return pipeline.CalibrateOptions(**base)


# ------------------------------------------------------------------------------------------------------------
# recovery


def test_recovers_known_parameters_standin_same_model(tmp_path, rig):
    """Drops from the private stand-in (fast model + image-source edges + damping + gain), noise and 1 mm
    position jitter: the pipeline's stages, caches, figures and keys, and E within 3 %, the bending stiffness
    E / (1 - nu^2) within 4 %. D_s is not asserted here: the stand-in has one order of edge images, so no
    reverberant field after ~3 ms, and the envelope decay D_s is taken from is the FEM's (the FEM tests)."""
    data = _session(tmp_path, rig, _standin_noisy, _truth(rig))
    out = tmp_path / "cal" / "CAL.json"
    # the nu stage skipped (nu_rounds 0): the stand-in is slow to simulate (~45 s for one round), and the stage
    # is tested on the FEM below (recovery and resume)
    cal = pipeline.calibrate(data, out, _small_opts(budget=48, nu_rounds=0), simulate=_standin_clean)
    pl = cal["plate"]
    assert abs(pl["E_mpa"] / TRUTH_E - 1) < 0.03, pl
    stiff = pl["E_mpa"] / (1 - pl["nu"] ** 2)
    assert abs(stiff / (TRUTH_E / (1 - TRUTH_NU ** 2)) - 1) < 0.04, pl
    # what CAL.json must carry
    saved = json.loads(out.read_text())
    assert saved["sim_params"]["damping_per_s"] == pytest.approx(cal["fitted"]["damping_per_s"])
    assert saved["sim_params"]["e_pa"] == pytest.approx(pl["E_mpa"] * 1e6)
    assert len(saved["exclude_case_ids"]) == 4 and len(saved["exclude_recording_ids"]) >= 8
    assert saved["fitted"]["damping_per_s"] == pytest.approx(saved["plate"]["nu_fit"]["used"]["damping_per_s"])
    assert saved["fitted"]["nu"] == pytest.approx(saved["plate"]["nu_fit"]["used"]["nu"])
    # a skipped nu stage claims nothing: the grid's nu and the decay's D_s are kept
    assert not saved["plate"]["nu_fit"]["identified"] and saved["plate"]["nu"] == saved["plate"]["nu_grid"]
    assert saved["fitted"]["damping_per_s"] == pytest.approx(saved["damping_from_decay"]["damping_per_s"])
    # the stand-in's records hold a passing wave and its first echoes, no ringing field: its bands' "decay" rises
    # with frequency only as the dispersive wave leaves (a negative intercept), so the twin gets no loss factor
    assert not saved["twin_loss"]["kept"] and saved["sim_params"].get("loss_factor", 0.0) == 0.0
    for stage in ("drops", "plate_grid", "plate_fem", "damping", "plate_nu", "plate_fem_refit", "design_fem",
                  "surrogates", "screening", "optimise",
                  "fem_confirm", "total"):
        assert stage in saved["wall_time_s"]
    r2 = saved["pzt_damping"]["surrogate_r2_test"]
    assert set(r2) == {"sensor_energies_log10", "residual_ratios"}
    assert max(r2["sensor_energies_log10"][k]["r2_test"] for k in surrogates.MODELS) > 0.8
    # screening: main effects and interactions of every factor for both outputs (the physics of the
    # screening itself is tested on a known response in test_welch_screening_finds_...)
    for rows in saved["pzt_damping"]["screening"].values():
        assert len(rows) == 20 and {"term", "effect", "t", "p", "significant"} <= set(rows[0])
    assert (tmp_path / "cal" / "CAL.fig9-plate-loss.png").stat().st_size > 10_000
    assert (tmp_path / "cal" / "CAL.fig10-screening.png").stat().st_size > 10_000
    # resumable: a second run reads every stage from the caches and gives the same answer
    cal2 = pipeline.calibrate(data, out, _small_opts(budget=48, nu_rounds=0), simulate=_standin_clean)
    assert cal2["fitted"] == cal["fitted"]
    assert cal2["wall_time_s"]["design_fem"] < 0.5 * max(cal["wall_time_s"]["design_fem"], 0.2)
    # ... and still reports what each stage cost when it was computed
    assert cal2["stage_compute_time_s"]["design_fem"] == cal["stage_compute_time_s"]["design_fem"] > 0
    assert cal2["stage_compute_time_s"]["sum"] >= cal2["stage_compute_time_s"]["design_fem"]
    # --no-design: the plate stages from the same caches, no design stage; the twin keeps the seed's PZT block
    # and takes the plate stages' D_s (the decay's, nu not claimed)
    nod = pipeline.calibrate(data, out, _small_opts(budget=48, nu_rounds=0, design=False), simulate=_standin_clean)
    assert "design_fem" not in nod["wall_time_s"] and "skipped" in nod["pzt_damping"]
    assert nod["plate"]["E_mpa"] == cal["plate"]["E_mpa"]
    assert nod["sim_params"]["damping_per_s"] == pytest.approx(saved["damping_from_decay"]["damping_per_s"])
    assert all(nod["sim_params"][k] == pytest.approx(v) for k, v in fem.SEED_PZT.items() if k != "damping_per_s")
    # another twin (a support chosen by hand) is not served from those caches: the plate FEM, damping and
    # design stages run again (the stand-in ignores the support, so the answer may repeat, but not the reads)
    runs = []  # the twins the stand-in is asked to simulate (its support), in call order

    def counting(p, *args):
        runs.append(p["support"])
        return _standin_clean(p, *args)

    cal3 = pipeline.calibrate(data, out, _small_opts(budget=48, nu_rounds=0, support="clamped"),
                              simulate=counting)
    assert cal3["sim_params"]["support"] == "clamped"
    # every stage that simulates runs again on the clamped twin: the design alone is 48 runs (a wall-time
    # comparison fails on a loaded machine, and two runs' CPU times can coincide to the millisecond; a count
    # of the simulations asked for does neither)
    assert len(runs) >= 48 and set(runs) == {"clamped"}, (len(runs), set(runs))


def _fem_recovery(tmp_path, rig, element_mm, budget, n_cases, truth=(TRUTH_E, TRUTH_NU, TRUTH_DS), rerun=False):
    """Drops the project's FEM made with known E, nu, D_s (12 ms records: the envelope decays inside them, as
    on the rig's 50 ms captures) plus the simulator's 1.5-count noise and 1 mm position jitter, calibrated with
    the same FEM. With `rerun`, calibrated twice (the second from the caches): returns both results."""
    over = {} if element_mm is None else {"element_mm": element_mm}
    sim_fn = fem.fem_simulator(workers=2, **over)

    def noisy(truth, rig_, x, y, h):
        from impactsense.sim import SimParams, simulate_drops
        p = SimParams.from_rig(rig_, **truth, **over, duration_ms=12.0)
        return simulate_drops(p, rig_, x, y, h, noise=True, seed=5, progress=False)

    data = _session(tmp_path, rig, noisy, _truth(rig, *truth), n_cases=n_cases, reps=3)
    cal = pipeline.calibrate(data, tmp_path / "fem" / "CAL.json", _small_opts(budget=budget), simulate=sim_fn)
    if not rerun:
        return cal
    return cal, pipeline.calibrate(data, tmp_path / "fem" / "CAL.json", _small_opts(budget=budget), simulate=sim_fn)


def _assert_recovered(cal, stiff_tol, ds_tol, nu_tol=0.015, e_tol=0.03, truth=(TRUTH_E, TRUTH_NU, TRUTH_DS)):
    """What four drops identify: E, nu and D_s, from every repetition's band group delays with each repetition's
    position fitted (`plate_nu`): nu within `nu_tol`, E within `e_tol`, the bending stiffness E / (1 - nu^2)
    within `stiff_tol`, D_s within `ds_tol`."""
    TRUTH_E, TRUTH_NU, TRUTH_DS = truth           # noqa: N806
    pl, dd = cal["plate"], cal["damping_from_decay"]
    nf = pl["nu_fit"]
    truth_stiff = TRUTH_E / (1 - TRUTH_NU ** 2)
    assert nf["identified"], nf
    assert abs(pl["nu"] - TRUTH_NU) < nu_tol, nf
    assert pl["nu"] == nf["nu"] == cal["fitted"]["nu"]
    assert abs(pl["E_mpa"] / TRUTH_E - 1) < e_tol, pl
    assert pl["E_mpa"] == pytest.approx(nf["E_mpa"], abs=0.1)
    # Eq. 16's E at that nu (AIC DToA in 10 us steps: a few %)
    assert abs(pl["E_aic_mpa"] / TRUTH_E - 1) < 0.05, pl
    assert abs(pl["stiffness_E_over_1_minus_nu2_mpa"] / truth_stiff - 1) < stiff_tol, pl
    assert pl["E_mpa"] == pytest.approx(pl["stiffness_E_over_1_minus_nu2_mpa"] * (1 - pl["nu"] ** 2))
    # the twin explains the group delays at the fit (noise-only errors), and the stated sd covers the error
    assert nf["chi2_dof"] < 2.0, nf
    assert abs(nf["nu"] - TRUTH_NU) < 4 * nf["sd"]["nu"] + 0.005, nf
    # the positions moved by about the 1 mm jitter (rms of a 2-D normal with 1 mm per axis: 1.41 mm)
    assert 0.5 < nf["position_shift_rms_mm"] < 2.5, nf
    # D_s: the group-delay fit's (used) and the envelope decay's
    assert abs(nf["damping_per_s"] / TRUTH_DS - 1) < ds_tol, nf
    assert cal["fitted"]["damping_per_s"] == pytest.approx(nf["damping_per_s"])
    # the envelope decay's D_s (the prior); the twin's decay moves by 1/2 of a D_s change (theory: exactly 1/2)
    assert abs(dd["damping_per_s"] / TRUTH_DS - 1) < max(ds_tol, 0.03), dd
    assert dd["slope_decay_per_damping"] == pytest.approx(0.5, abs=0.05)
    assert abs(dd["estimate_per_s"] - TRUTH_DS) < 4 * dd["se_per_s"] + 5.0, dd
    # the energies are matched by the PZT block at that D_s: relative energy misfit below 5 %
    assert cal["pzt_damping"]["f2_rel"] < 0.05


@pytest.mark.skipif(not fem.available(), reason="FEM simulator not built")
def test_recovers_known_parameters_fem_coarse_same_model(tmp_path, rig):
    """CI variant: 5 mm mesh, the smallest design (24 runs): nu within 0.015, E and E / (1 - nu^2) within 3 %,
    D_s within 5 %. Calibrated again, the nu stage is read from its cache (same answer, ~0 s)."""
    cal, cal2 = _fem_recovery(tmp_path, rig, 5.0, pipeline.MIN_BUDGET, 8, rerun=True)
    _assert_recovered(cal, 0.03, 0.05)
    assert cal2["plate"]["nu_fit"] == cal["plate"]["nu_fit"] and cal2["fitted"] == cal["fitted"]
    assert cal2["wall_time_s"]["plate_nu"] < 0.5 < cal["wall_time_s"]["plate_nu"]
    assert cal2["stage_compute_time_s"]["plate_nu"] == cal["stage_compute_time_s"]["plate_nu"]


@pytest.mark.slow
@pytest.mark.skipif(not fem.available(), reason="FEM simulator not built")
def test_recovers_second_truth_fem_coarse_same_model(tmp_path, rig):
    """A second plate and damping (E 4500 MPa, nu 0.33, D_s 800 1/s), the same tolerances: the nu stage is not
    tuned to one truth. Slow (~30 s): the default suite keeps the first truth's recovery and resume."""
    _assert_recovered(_fem_recovery(tmp_path, rig, 5.0, pipeline.MIN_BUDGET, 8, SECOND_TRUTH), 0.03, 0.05,
                      truth=SECOND_TRUTH)


@pytest.mark.slow
@pytest.mark.skipif(not fem.available(), reason="FEM simulator not built")
@pytest.mark.parametrize("truth", [(3400.0, 0.31, 650.0), (3400.0, 0.39, 650.0), (4500.0, 0.33, 650.0),
                                   (3000.0, 0.37, 950.0)])
def test_recovers_known_parameters_fem_coarse_more_truths_same_model(tmp_path, rig, truth):
    """The nu study's other truths (docs/findings.md) and a softer, more damped plate, 5 mm mesh."""
    _assert_recovered(_fem_recovery(tmp_path, rig, 5.0, pipeline.MIN_BUDGET, 8, truth), 0.03, 0.05, truth=truth)


@pytest.mark.slow
@pytest.mark.skipif(not fem.available(), reason="FEM simulator not built")
def test_recovers_known_parameters_fem_same_model(tmp_path, rig):
    """The default (Eq. 1) mesh, budget 32, twelve cases: nu within 0.015, E and E / (1 - nu^2) within 3 %, D_s
    within 2 %."""
    _assert_recovered(_fem_recovery(tmp_path, rig, None, 32, 12), 0.03, 0.02)


# ------------------------------------------------------------------------------------------------------------
# bad input: clear errors, nothing written


def _nothing_written(folder):
    return not folder.exists() or not any(folder.iterdir())


def test_the_twin_records_carry_the_rigs_noise_not_the_seeds(tmp_path, rig):
    """The twin's noise (sim_params noise_counts_rms, put on the virtual drops and their calibration twins) is
    the rig's logger's, as calibrate's own simulations use it: the seed's 1.5 counts is the bundled 12-bit
    logger's. A 10-bit logger's ~0.4 counts against the twin's 1.5 made the twin's drops ~4x noisier relative
    to their peaks once the twin's gain matched the rig's (docs/findings.md, "Session 20: brasszs"). Here a
    quiet logger (0.4 counts of white noise on the stand-in's records, then rounded to counts): the twin's noise
    is the records' pre-trigger sd (the core's estimate against numpy's, within 15 %)."""
    quiet = 0.4

    def logger(truth, rig_, x, y, h):
        adc = _standin.standin_simulate(truth, rig_, x, y, h).astype(float)
        adc += np.random.default_rng(4).normal(0.0, quiet, adc.shape)
        return np.clip(np.rint(adc), 0, rig_.adc_max).astype(np.uint16)

    data = _session(tmp_path, rig, logger, _truth(rig), n_cases=8, reps=2)
    # a coarse plate grid: only the noise is asserted here
    opts = _small_opts(fem=False, e_step_mpa=500.0, nu_step=0.05)
    cal = pipeline.calibrate(data, tmp_path / "cal" / "CAL.json", opts, simulate=_standin_clean)
    pre = load_session(data).adc[:, :, :64].astype(float)
    measured = float(np.median(pre.std(axis=2)))
    assert measured < 0.6                        # a quiet logger: the seed's 1.5 counts would be 3x too much
    twin = cal["sim_params"]["noise_counts_rms"]
    assert twin == pytest.approx(measured, rel=0.15), (twin, measured)
    written = json.loads((tmp_path / "cal" / "CAL.json").read_text())
    assert written["sim_params"]["noise_counts_rms"] == twin
    # the twin's span likewise (calibration.span): what the calibration drops ring for, one field every command reads
    ts = written["twin_span"]
    assert written["sim_params"]["duration_ms"] == ts["duration_ms"] >= ts["default_ms"]
    assert ts["measured_n2_ms"] > 0 and ts["bound"] in ("default", "measured", "record", "cost")


def test_fewer_than_four_usable_drops(tmp_path, rig):
    data = _session(tmp_path, rig, _standin_noisy, _truth(rig), n_cases=3)
    out = tmp_path / "o" / "CAL.json"
    with pytest.raises(DataError, match=r"only [0-3] usable drop case\(s\) \(need 4\)"):
        pipeline.calibrate(data, out, _small_opts(), simulate=_standin_clean)
    assert _nothing_written(tmp_path / "o")


def test_all_rejected_by_eq35(tmp_path, rig, capsys):
    data = _session(tmp_path, rig, _standin_noisy, _truth(rig), n_cases=8, mirror_x=True)
    out = tmp_path / "o" / "CAL.json"
    code = cli.main(["calibrate", str(data), "--out", str(out), "--quiet"])
    assert code == 2
    err = capsys.readouterr().err
    assert "Eq. 35" in err and "rejected" in err
    assert _nothing_written(tmp_path / "o")


def test_budget_too_small(tmp_path, capsys):
    out = tmp_path / "o" / "CAL.json"
    assert cli.main(["calibrate", "bundled", "--out", str(out), "--budget", "10", "--quiet"]) == 2
    assert "too small" in capsys.readouterr().err
    assert _nothing_written(tmp_path / "o")
    with pytest.raises(ConfigError, match="too small"):
        pipeline.CalibrateOptions(budget=pipeline.MIN_BUDGET - 1).validate()


def test_bad_drops_option(tmp_path, rig, capsys):
    out = tmp_path / "o" / "CAL.json"
    assert cli.main(["calibrate", "bundled", "--out", str(out), "--drops", "1,2,3", "--quiet"]) == 2
    assert "four different case ids" in capsys.readouterr().err
    data = _session(tmp_path, rig, _standin_noisy, _truth(rig), n_cases=6)
    with pytest.raises(DataError, match="case 99 is not in the session"):
        pipeline.calibrate(data, out, _small_opts(drops=[0, 1, 2, 99]), simulate=_standin_clean)
    assert _nothing_written(tmp_path / "o")


# ------------------------------------------------------------------------------------------------------------
# building blocks


def test_auto_drops_on_session1_are_spread_accepted_and_repeatable():
    s = load_session(SESSION1)
    feats = drops.extract(s)
    t = drops.select_drops(s, feats)
    assert len(set(t.case_ids)) == 4
    quadrants = {(x < s.rig.plate_x_mm / 2, y < s.rig.plate_y_mm / 2) for x, y in zip(t.x_mm, t.y_mm)}
    assert len(quadrants) == 4
    ok = drops.arrival_order_accepted(s, feats, 0.0, 0.0)
    for recs in t.recording_ids:
        assert len(recs) >= 2 and ok[recs].all()
    rows, _ = drops.case_table(s, feats)
    spreads = np.array([r["spread_us"] for r in rows.values() if r["usable"]])
    assert np.all(t.dtoa_spread_us <= np.percentile(spreads, 50))   # among the more repeatable half


def test_fast_model_arrival_speed_matches_group_velocity(rig):
    """The synthetic signal's energy peak travels at the A0 group velocity of its dominant frequency."""
    from impactsense.sim import dispersion
    e, nu = 3.5e9, 0.35
    r_mm = np.array([60.0, 260.0])
    setup = arrival.ArrivalSetup(r_m=np.repeat(r_mm[:, None], 4, axis=1) * 1e-3,
                                 height_m=np.array([0.15, 0.15]), disc_radius_m=1e-4, thickness_m=4.2e-3,
                                 density_kg_m3=1157.0, ball_radius_m=4.75e-3, ball_mass_kg=3.53e-3,
                                 fs_hz=1e6, n_fft=8192, highpass_hz=1000.0)
    u = arrival.synth_unit(setup, [e], [nu])[0][:, 0]                      # [2, S]
    # narrow-band around 8 kHz: envelope peak time difference = dr / cg(8 kHz)
    from scipy.signal import butter, hilbert, sosfiltfilt
    sos = butter(4, [7000, 9000], btype="band", fs=1e6, output="sos")
    env = np.abs(hilbert(sosfiltfilt(sos, u, axis=-1), axis=-1))
    dt_s = (np.argmax(env[1]) - np.argmax(env[0])) / 1e6
    cg = dispersion.a0_group_velocity(8000.0, e, nu, 1157.0, 4.2e-3)
    assert (r_mm[1] - r_mm[0]) * 1e-3 / dt_s == pytest.approx(cg, rel=0.05)


def test_delay_misfit_is_zero_for_perfect_match_and_penalises_missing_picks():
    d = np.arange(24.0).reshape(4, 6)
    assert plate.delay_misfit(d, d) == 0
    bad = d.copy()
    bad[0, 0] = np.nan
    assert plate.delay_misfit(bad, d) == pytest.approx(1e6)


def test_svd_polynomial_recovers_a_quadratic():
    rng = np.random.default_rng(0)
    x = rng.uniform(size=(60, 3))
    y = 1 + 2 * x[:, 0] - 3 * x[:, 1] * x[:, 2] + 0.5 * x[:, 2] ** 2
    m = surrogates.SVDPolynomial(degree=2, tol=1e-10, standardise=True).fit(x, y)
    xt = rng.uniform(size=(20, 3))
    yt = 1 + 2 * xt[:, 0] - 3 * xt[:, 1] * xt[:, 2] + 0.5 * xt[:, 2] ** 2
    assert np.max(np.abs(m.predict(xt) - yt)) < 1e-8


def test_welch_screening_finds_the_active_factor_and_interaction():
    rng = np.random.default_rng(1)
    x = qmc.Sobol(4, seed=2).random(64)
    y = 2.0 * x[:, 1] + 3.0 * (x[:, 2] - 0.5) * (x[:, 3] - 0.5) * 4 + rng.normal(0, 0.1, 64)
    rows = screening.welch_screen(x, y, ["a", "b", "c", "d"])
    sig = {r["term"] for r in rows if r["significant"]}
    assert "b" in sig and "c x d" in sig
    assert "a" not in sig


def test_decay_rate_of_a_known_exponential_envelope_under_noise():
    """A reverberant-like record (40 random modes, 1-20 kHz) decaying as exp(-lambda t), 1.5 counts of noise:
    the noise-corrected block-power slope returns lambda within 3 %, over the blocks the SNR window keeps."""
    from impactsense.calibration import damping
    rng = np.random.default_rng(4)
    fs, n, onset, bias = 100_000.0, 5000, 300, 2048.0
    t = (np.arange(n) - onset) / fs
    f = rng.uniform(1e3, 20e3, 40)
    ph = rng.uniform(0, 2 * np.pi, 40)
    cfg = pipeline.sim_core_config(load_session(SESSION1).rig, pipeline.CalibrateOptions())
    for lam in (250.0, 500.0):
        wave = np.sin(2 * np.pi * f[:, None] * t[None] + ph[:, None]).sum(axis=0) * 60.0
        x = np.where(t >= 0, wave * np.exp(-lam * np.clip(t, 0, None)), 0.0)
        rec = np.stack([x] * 4)[None] + rng.normal(0, 1.5, (1, 4, n)) + bias
        adc = np.clip(np.rint(rec), 0, 4095).astype(np.uint16)
        power = damping.block_power(adc, cfg, bias)
        mask = damping.window_mask(power, np.full((1, 4), 1.5))
        assert mask.sum(axis=-1).min() >= damping.MIN_BLOCKS
        assert np.allclose(damping.decay_rates(power, mask), lam, rtol=0.03)


def test_band_arrivals_follow_a_delayed_low_band_burst_and_remove_channel_delays():
    """A 3 kHz Hann-windowed burst preceded by a weak 20 kHz front (the AIC onset), delayed by known amounts per
    channel: band arrival differences equal the delays to < 0.5 us, and a channel read early by d us (d < 0)
    and declared so is put back in place."""
    fs, n = 100_000.0, 3000
    t = np.arange(n) / fs
    delays_us = np.array([0.0, 137.0, 263.5, 401.2])
    rec = np.zeros((1, 4, n))
    for c, d in enumerate(delays_us):
        tau = t - 5e-3 - d * 1e-6
        burst = np.where((tau > 0) & (tau < 1e-3), np.sin(np.pi * tau / 1e-3) ** 2 * np.sin(2 * np.pi * 3000 * tau), 0)
        front = np.where((tau > 0) & (tau < 2e-4), np.sin(2 * np.pi * 20000 * tau), 0)
        rec[0, c] = 2048 + 600 * burst + 30 * front
    toa = 5000.0 + delays_us[None]
    got = bands.band_arrivals(rec, toa, fs)
    diff = bands.pair_differences(got, plate.PAIR_I, plate.PAIR_J)[0]
    want = delays_us[plate.PAIR_I] - delays_us[plate.PAIR_J]
    assert np.allclose(diff, want[None], atol=0.5)
    # channel 2 sampled 6 us early: its record is shifted, the core's ToA already corrected
    early = rec.copy()
    early[0, 2] = np.interp(t + 6e-6, t, rec[0, 2])
    got2 = bands.band_arrivals(early, toa, fs, channel_delay_us=[0.0, 0.0, -6.0, 0.0])
    assert np.allclose(got2, got, atol=0.3)


def _linear_drops(rng, n_drops=4, k=3, reps=5, noise_us=0.7, jitter_mm=1.0):
    """Observables that move linearly with each drop's position (random d obs / d position, ~2-5 us/mm like
    the FEM's), repetitions jittered by `jitter_mm` and read with `noise_us` of independent pick noise."""
    from impactsense.calibration import plate_fem
    j_pos = rng.normal(0, 3.0, (n_drops, k, 6, 2))
    base = rng.normal(0, 50.0, (n_drops, k, 6))
    per_rep = [base[d] + np.einsum("kpc,rc->rkp", j_pos[d], rng.normal(0, jitter_mm, (reps, 2)))
               + rng.normal(0, noise_us, (reps, k, 6)) for d in range(n_drops)]
    meas = plate_fem.PlateTargets(dtoa=np.stack([o.mean(axis=0) for o in per_rep]), sigma=np.ones(k),
                                  names=tuple(f"o{i}" for i in range(k)), per_rep=per_rep)
    return base, j_pos, meas


def test_position_free_chi2_ignores_where_each_drop_landed_but_not_the_plate():
    """A drop that landed 1 mm off its declared place moves all its observables along its two position columns:
    the position-free chi^2 does not see it (linear model: exactly), the plain chi^2 does; a change that is not
    a position shift (a plate change) stays visible."""
    from impactsense.calibration import plate_fem
    rng = np.random.default_rng(2)
    base, j_pos, meas = _linear_drops(rng, noise_us=0.0)
    meas.sigma = np.full(3, 0.5)
    shift = rng.normal(0, 1.0, (4, 2))
    moved = base + np.einsum("dkpc,dc->dkp", j_pos, shift)
    meas.dtoa = moved
    assert plate_fem.chi2(base, meas) > 100
    assert plate_fem.chi2_position_free(base, meas, j_pos) < 1e-9
    plate_change = rng.normal(0, 1.0, base.shape)
    # 2 of each drop's 18 directions are removed: most of the change's chi^2 (16/18 on average) remains
    assert plate_fem.chi2_position_free(base + plate_change, meas, j_pos) > 0.6 * np.sum((plate_change / 0.5) ** 2)


def test_position_free_sigma_is_the_pick_noise_not_the_position_scatter():
    """Repetitions scattered by 1 mm (3 us/mm) and read with 0.7 us of pick noise: the plain spread is several
    us, the position-free standard error is 0.7 / sqrt(reps) within 20 %."""
    from impactsense.calibration import plate_fem
    rng = np.random.default_rng(3)
    _, j_pos, meas = _linear_drops(rng, n_drops=12, reps=5, noise_us=0.7)
    spread = np.sqrt(np.mean([np.var(o, axis=0, ddof=1).mean() for o in meas.per_rep]))
    assert spread > 3.0
    sig = plate_fem.position_free_sigma(meas, j_pos)
    assert np.allclose(sig, max(0.7 / np.sqrt(5), plate_fem.SIGMA_FLOOR_US), rtol=0.2), sig


def test_fisher_sd_nu_with_position_free_is_never_better_than_with_positions_known():
    """Profiling nuisance directions out can only remove information: sd(nu) with positions free >= with them
    known; a nu direction that is a pure position shift carries no information (infinite sd)."""
    from impactsense.calibration import plate_fem
    rng = np.random.default_rng(4)
    _, j_pos, meas = _linear_drops(rng)
    j_e, j_nu = rng.normal(0, 30, j_pos.shape[:3]), rng.normal(0, 30, j_pos.shape[:3])
    ks = [0, 1, 2]
    assert plate_fem.fisher_sd_nu(j_e, j_nu, meas, ks, j_pos) >= plate_fem.fisher_sd_nu(j_e, j_nu, meas, ks)
    j_nu_shift = np.einsum("dkpc,dc->dkp", j_pos, rng.normal(0, 1, (4, 2)))
    assert plate_fem.fisher_sd_nu(j_e, j_nu_shift, meas, ks, j_pos) > 1e3


def _bursts(delays_us, fs=100_000.0, n=1500, t0=5e-3):
    """Four channels of a 3 kHz burst in a Gaussian envelope (sd 250 us), delayed by `delays_us`."""
    t = np.arange(n) / fs
    tau = t[None, :] - t0 - np.asarray(delays_us)[:, None] * 1e-6
    return (2048 + 500 * np.exp(-0.5 * (tau / 2.5e-4) ** 2) * np.sin(2 * np.pi * 3000 * tau))[None], t


def test_group_delays_recover_packet_delays_smoothly_and_remove_channel_delays():
    """Packets delayed by known, non-integer amounts: the group-delay pair differences equal the delays to
    < 1.5 us; moving one channel in 0.1-sample steps moves its pairs by the same 1 us each (a smooth
    observable, unlike a sample-quantised pick) though its onset moves in 10 us steps, and a channel read 6 us
    early and declared so is put back."""
    from impactsense.calibration import group_delay
    fs = 100_000.0
    band = ((2000.0, 5000.0, 2000.0),)              # the packets lie in the window's flat part
    delays = np.array([0.0, 123.4, -50.2, 210.7])
    rec, t = _bursts(delays)
    toa = np.round((4200.0 + delays) / 10) * 10.0         # sample-quantised onsets, as the core's
    toa = toa[None]
    got = group_delay.group_delays(rec, toa, fs, plate.PAIR_I, plate.PAIR_J, bands=band)[0]
    want = delays[plate.PAIR_I] - delays[plate.PAIR_J]
    assert np.allclose(got, want[None], atol=1.5), got
    steps = []
    for k in range(1, 11):
        d = delays.copy()
        d[1] += k * 1.0
        r2, _ = _bursts(d)
        toa2 = np.round((4200.0 + d) / 10)[None] * 10.0
        steps.append(group_delay.group_delays(r2, toa2, fs, plate.PAIR_I, plate.PAIR_J, bands=band)[0])
    moved = np.diff(np.stack([got] + steps), axis=0)            # [10, B, 6]: per 1 us of channel 1
    sign = (np.asarray(plate.PAIR_I) == 1).astype(float) - (np.asarray(plate.PAIR_J) == 1)
    assert np.allclose(moved, sign[None, None, :], atol=0.15), moved
    early = rec.copy()
    early[0, 2] = np.interp(t + 6e-6, t, rec[0, 2])
    got2 = group_delay.group_delays(early, toa, fs, plate.PAIR_I, plate.PAIR_J, channel_delay_us=[0, 0, -6.0, 0],
                                    bands=band)[0]
    assert np.allclose(got2, got, atol=0.3)
    with pytest.raises(ValueError, match="adc must be"):
        group_delay.group_delays(rec[0], toa, fs, plate.PAIR_I, plate.PAIR_J)


@pytest.mark.skipif(not fem.available(), reason="FEM simulator not built")
def test_fit_positions_finds_where_fem_drops_landed_same_model(rig):
    """Issue 4 step (b): each repetition's position fitted non-linearly to its band group delays (FEM
    re-simulated at the trial positions) lands within 0.15 mm of where the FEM drop really was, from declared
    positions 1-1.5 mm off; the edge reflections make these observables non-linear over that millimetre."""
    from impactsense.calibration import plate_fem
    sim_fn = fem.fem_simulator(workers=2, element_mm=5.0)
    truth = dict(fem.base_params(rig, TRUTH_E, TRUTH_NU), damping_per_s=TRUTH_DS)
    cfg_sim = pipeline.sim_core_config(rig, pipeline.CalibrateOptions())

    def at(x, y, h):
        return plate_fem.sim_observables(sim_fn(truth, rig, x, y, h), cfg_sim, group_delays=True)

    x0, y0, h = np.array([70.0, 250.0, 90.0]), np.array([80.0, 70.0, 240.0]), np.array([100.0, 110.0, 120.0])
    xt, yt = x0 + np.array([1.0, -0.8, 0.6]), y0 + np.array([-0.7, 1.1, -1.0])
    obs = at(xt, yt, h)
    names = plate_fem.names(group_delays=True)
    ks = plate_fem.observable_sets(names)["group delays only"]
    sigma = np.full(len(names), 0.5)
    xf, yf = plate_fem.fit_positions(at, obs, sigma, x0, y0, h, ks)
    err = np.hypot(xf - xt, yf - yt)
    assert np.all(err < 0.15), err
    assert plate_fem.chi2(at(xf, yf, h), plate_fem.PlateTargets(obs, sigma, names), ks) < \
        0.05 * plate_fem.chi2(at(x0, y0, h), plate_fem.PlateTargets(obs, sigma, names), ks)
