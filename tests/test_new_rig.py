"""A rig the project has not seen: another logger (16-bit ADC), another layout, words for the material, and the
board model shipped for the bundled rig. Each test makes its tiny rig here from the bundled drops."""

import json
from dataclasses import replace

import numpy as np
import pytest

from impactsense.data import load_session, rig_from_dict, write_session
from impactsense.errors import ConfigError, DataError
from impactsense.materials import material_for_rig
from impactsense.pipeline import featurize
from impactsense.signal import SignalConfig

ROWS = np.arange(0, 771, 13)   # 60 drops over the plate


def sixteen_bit(session, rows=ROWS):
    """The drops as a 16-bit logger of the same front end reads them: counts about the bias x 16 (its noise too)."""
    raw = dict(session.rig.to_dict(), adc_bits=16, bias_counts=32768)
    s = session.subset(rows)
    adc16 = ((s.adc.astype(np.int32) - session.rig.bias_counts) * 16 + 32768).astype(np.uint16)
    return raw, s, adc16


def test_a_16_bit_logger_gives_the_12_bit_picks_and_energies_x256(session1):
    raw, s, adc16 = sixteen_bit(session1)
    rig16 = rig_from_dict(raw)
    f12 = featurize(s.adc, SignalConfig.for_rig(session1.rig))
    f16 = featurize(adc16, SignalConfig.for_rig(rig16))
    # the re-centred samples keep the full resolution: no channel reads as clipped that did not at 12 bits (the
    # bottom rail maps to 0; the top, 4095, to 65520, under the 16-bit rail), the same drops are usable
    assert not (f16.clipped & ~f12.clipped).any() and np.array_equal(f16.usable, f12.usable)
    ok = f12.usable
    # the count-valued defaults (onset threshold, dead channel) are scaled to the same volts: the same picks but
    # for the finer quantisation (a crossing may move by a sample where the signal grazes the threshold)
    thr12 = SignalConfig.for_rig(session1.rig).onset_threshold_counts
    assert SignalConfig.for_rig(rig16).onset_threshold_counts == 16 * thr12
    dt = np.abs(f16.toa_us[ok] - f12.toa_us[ok])
    assert np.median(dt) < 0.2 and np.mean(dt < 2.0) > 0.95, np.percentile(dt, [50, 90, 100])
    ratio = f16.energy[ok] / f12.energy[ok]
    assert np.median(ratio) == pytest.approx(256.0, rel=0.02)


def test_a_16_bit_session_trains_and_is_scored_as_its_own_rig(tmp_path, session1):
    import impactsense as isn

    raw, s, adc16 = sixteen_bit(session1, np.arange(0, 771, 8))
    path = write_session(tmp_path / "s16", raw, s.x_mm, s.y_mm, s.height_mm, adc16, s.case_id, s.repetition)
    s16 = load_session(path)
    model = isn.train(s16, out=tmp_path / "m", site_map="none", trees=20)
    rep = isn.evaluate(model, s16)
    # the bundled rig's drops at 16 bits localise like the 12-bit ones (forests + physics: a few mm)
    assert rep["n"] > 15 and rep["all"]["mae_mm"] < 8.0, rep["all"]


def test_sim_counts_for_the_core_are_recentred_on_a_16_bit_logger(session1):
    from impactsense.sim import SimParams, to_adc

    rig16 = rig_from_dict(sixteen_bit(session1)[0])
    volts = np.zeros((1, 4, 3000))
    volts[0, :, 500:] = 1.0
    params = SimParams.from_rig(rig16)
    counts = to_adc(volts, params, rig16, clip=False)
    want = params.circuit_gain * 2 ** 16 / rig16.vref   # counts of 1 V at the disc
    assert counts.dtype == np.int16 and abs(int(counts[0, 0, 0])) == 0
    assert counts[0, 0, 1000] == pytest.approx(want, abs=1)


def test_emulate_refuses_board_models_of_another_rig(tmp_path, session1):
    from impactsense.commands.emulate import _require_models_rig
    from impactsense.export import firmware_models, shipped_board_model

    path = shipped_board_model()
    if path is None:
        pytest.skip("no shipped board model in this install")
    _, signal = firmware_models(path)
    _require_models_rig(signal, session1, path)          # the bundled rig: its own model
    raw = session1.rig.to_dict()
    raw["sensors"] = [dict(s, x_mm=s["x_mm"] + (20 if k == 1 else 0)) for k, s in enumerate(raw["sensors"])]
    s = session1.subset(np.arange(3))
    other = load_session(write_session(tmp_path / "o", raw, s.x_mm, s.y_mm, s.height_mm, s.adc))
    with pytest.raises(ConfigError, match="another rig"):
        _require_models_rig(signal, other, path)


@pytest.mark.parametrize("n", [3, 5])
def test_layouts_of_other_than_four_sensors_are_a_clear_error(session1, n):
    raw = session1.rig.to_dict()
    sensors = [{"name": f"S{k + 1}", "channel": k, "x_mm": 40.0 + 50 * k, "y_mm": 40.0} for k in range(n)]
    with pytest.raises(DataError, match="exactly 4 sensors"):
        rig_from_dict({**raw, "sensors": sensors})
    with pytest.raises(DataError, match="exactly 4 sensors"):
        rig_from_dict({**raw, "sensors": sensors, "channels": n})


@pytest.mark.parametrize("text, name", [("E-glass/epoxy laminate", "GFRP laminate"),
                                        ("FR-4 board", "woven GFRP (FR-4 / G-10)"),
                                        ("woven glass-epoxy panel", "woven GFRP (FR-4 / G-10)")])
def test_glass_fibre_laminates_are_not_read_as_glass(session1, text, name):
    mat = material_for_rig(rig_from_dict({**session1.rig.to_dict(), "plate_material": text}))
    assert mat.name == name and mat.orthotropic


def test_material_axes_deg_is_read_as_the_fibre_angle(session1):
    raw = {**session1.rig.to_dict(), "plate_material": "GFRP laminate", "material_axes_deg": 35}
    assert material_for_rig(rig_from_dict(raw)).axis_deg == 35.0
    with pytest.raises(DataError, match="material_axes"):
        material_for_rig(rig_from_dict({**raw, "material_axes_deg": "x"}))


def test_rig_json_round_trip_keeps_the_16_bit_logger(tmp_path, session1):
    raw, s, adc16 = sixteen_bit(session1, np.arange(4))
    path = write_session(tmp_path / "s", raw, s.x_mm, s.y_mm, s.height_mm, adc16)
    back = json.loads((path / "rig.json").read_text())
    assert back["adc_bits"] == 16 and load_session(path).adc.max() > 32767


def test_virtual_drops_span_the_calibrated_sessions_heights(session1):
    from impactsense.sim.doe import DEFAULT_HEIGHTS_MM, measured_heights, virtual_drops

    assert measured_heights(session1) == DEFAULT_HEIGHTS_MM == (100.0, 200.0)   # the bundled set is unchanged
    s = session1.subset(np.arange(6))
    s.height_mm = np.array([52.0, 60, 80, 120, 250, 298])
    lo, hi = measured_heights(s)
    assert (lo, hi) == (50.0, 300.0)
    h = virtual_drops(session1.rig, 400, 0, heights_mm=(lo, hi))[2]
    assert h.min() == 50.0 and h.max() == 300.0 and np.all(h % 5 == 0)
    # the class boundary (75th percentile of m g h) of a virtual set now lies where the session's drops are
    assert 200.0 < np.percentile(h, 75) < 270.0
    s.height_mm[:] = np.nan
    assert measured_heights(s) == DEFAULT_HEIGHTS_MM


def test_short_records_reach_the_board_and_the_diagnosis(tmp_path, session1):
    """A logger whose records are shorter than the bundled 50 ms (a fast logger, a short capture): the
    emulated board still captures every drop, and the diagnosis' hum lock-in has a tail to work on."""
    from impactsense.board.capture import board_captures
    from impactsense.residuals import signal_features

    rows = np.array([0, 40, 80, 120])
    s = session1.subset(rows)
    short = s.adc[:, :, :1800]                                  # 18 ms at 100 kHz: under the board's 2 windows
    raw = dict(session1.rig.to_dict(), samples=1800)
    sh = load_session(write_session(tmp_path / "short", raw, s.x_mm, s.y_mm, s.height_mm, short))
    caps, got, _ = board_captures(sh)
    assert sorted(got.tolist()) == [0, 1, 2, 3]
    onset = featurize(short, SignalConfig.for_rig(sh.rig)).raw["toa_aic"]
    logc, decay, hum = signal_features(short, onset, sh.rig.fs_hz, float(sh.rig.bias_counts))
    assert np.isfinite(hum).all() and np.isfinite(logc).all()


def test_sensors_on_one_line_are_a_clear_error(session1):
    raw = session1.rig.to_dict()
    line = [{"name": f"S{k + 1}", "channel": k, "x_mm": 40.0 + 70 * k, "y_mm": 100.0 + 0.5 * k} for k in range(4)]
    with pytest.raises(DataError, match="one line"):
        rig_from_dict({**raw, "sensors": line})
    three_near_an_edge = [dict(s, y_mm=30.0 + 5 * (k % 2)) for k, s in enumerate(line[:3])] + \
        [{"name": "S4", "channel": 3, "x_mm": 150.0, "y_mm": 280.0}]
    assert rig_from_dict({**raw, "sensors": three_near_an_edge}).sensor_xy_mm.shape == (4, 2)


def test_the_band_slowness_line_reads_a_16_bit_logger(session1):
    """The band localiser's slowness line (pipeline.energy_slowness_config) on a 16-bit logger's drops: it read
    the counts without the rig's conversion and crashed training on such a rig; it must give the 12-bit drops'
    line (the same picks; the summed log energy and so its reference 2 log10(16) higher)."""
    from impactsense.pipeline import band_config, energy_slowness_config

    raw, s, adc16 = sixteen_bit(session1, np.arange(0, 771, 4))
    rows = np.arange(len(s))
    s16 = replace(s, rig=rig_from_dict(raw), adc=adc16)
    cfg12, cfg16 = SignalConfig.for_rig(s.rig), SignalConfig.for_rig(s16.rig)
    band12 = band_config(s, rows, cfg12)
    band16 = SignalConfig.from_dict({**cfg16.to_dict(), **{k: v for k, v in band12.to_dict().items()
                                                            if k.startswith("band_") or k == "velocity_mm_per_us"}})
    band16.band_noise_counts = 16 * band12.band_noise_counts  # the floor's noise in the 16-bit logger's counts
    line12, line16 = energy_slowness_config(s, rows, band12), energy_slowness_config(s16, rows, band16)
    assert line12 is not None and line16 is not None
    assert line16.band_velocity_mm_per_us == pytest.approx(line12.band_velocity_mm_per_us, rel=0.02)
    assert line16.band_log_energy_ref - line12.band_log_energy_ref == pytest.approx(2 * np.log10(16), abs=0.05)


def short_pretrigger(session, rows, keep: int, samples: int = 2000):
    """The drops as a logger that keeps only `keep` samples before the first arrival records them: each record
    cut to start `keep` samples before its earliest threshold crossing (found on the full record)."""
    from impactsense import _core
    from impactsense.signal import core_samples

    s = session.subset(rows)
    cfg = SignalConfig.for_rig(session.rig)
    first = np.nanmin(_core.extract_batch(core_samples(s.adc, cfg), cfg.core())["toa_threshold"], axis=1)
    start = np.floor(first).astype(int) - keep
    assert (start >= 0).all()
    adc = np.stack([a[:, b:b + samples] for a, b in zip(s.adc, start)])
    return s, adc, start


def test_a_short_pre_trigger_is_measured_and_the_baseline_fits_before_the_hit(tmp_path, session1):
    """A logger with 40 samples before the hit (the core's default baseline segment is 64, and the onset is
    sought from its end): the session's quiet start is measured, the segment shortened, and the picks are the
    full records' (shifted by the cut) instead of all landing at the segment's end."""
    s, adc, start = short_pretrigger(session1, ROWS, keep=40)
    path = write_session(tmp_path / "short", dict(session1.rig.to_dict(), samples=adc.shape[2]), s.x_mm, s.y_mm,
                         s.height_mm, adc, s.case_id, s.repetition)
    short = load_session(path)
    assert 36 <= short.rig.pretrigger_samples <= 44
    cfg = SignalConfig.for_rig(short.rig)
    assert cfg.baseline_samples < 40
    full = featurize(s.adc, SignalConfig.for_rig(session1.rig))
    cut = featurize(adc, cfg)
    ok = full.usable & cut.usable
    assert ok.mean() > 0.9
    shift_us = start[ok, None] * 1e6 / session1.rig.fs_hz
    dt = np.abs(cut.toa_us[ok] + shift_us - full.toa_us[ok])
    assert np.median(dt) < 0.5 and np.mean(dt < 3.0) > 0.9, np.percentile(dt, [50, 90])
    # the default segment would have put every earliest pick at its end (64 samples = 640 us at 100 kHz)
    stale = featurize(adc, SignalConfig.for_rig(session1.rig))
    assert np.median(np.abs(stale.toa_us[ok] + shift_us - full.toa_us[ok])) > 5.0
    # the twin's records start as the rig's, so a virtual set and its site map are featurized alike
    from impactsense.sim import SimParams

    assert SimParams.from_rig(short.rig).pretrigger_samples == short.rig.pretrigger_samples
    # a long pre-trigger (the bundled rig's) keeps the default segment and the simulator's pre-trigger
    assert SignalConfig.for_rig(session1.rig).baseline_samples == 64
    assert SimParams.from_rig(session1.rig).pretrigger_samples == SimParams().pretrigger_samples


def test_a_declared_pre_trigger_is_used_and_checked(session1):
    raw = dict(session1.rig.to_dict(), pretrigger_samples=30)
    assert SignalConfig.for_rig(rig_from_dict(raw)).baseline_samples == 22
    for bad in (0, -3, 1.5, True, session1.rig.samples):
        with pytest.raises(DataError, match="pretrigger_samples"):
            rig_from_dict(dict(raw, pretrigger_samples=bad))


def test_the_board_captures_a_short_pre_trigger_on_the_records_own_level(tmp_path, session1):
    """Records with 40 samples before the hit and their own DC offsets, replayed to the board one after the
    other: the board's 1.9 ms pre-trigger reaches back past them, and without a lead-in it sought the onset on
    the step to the previous record's level. The board's picks are the host's (its scan delays removed)."""
    from impactsense.board.capture import board_captures, continued_for_capture
    from impactsense.faults import FaultSpec, inject

    rows = np.arange(0, 771, 40)
    s, adc, _ = short_pretrigger(session1, rows, keep=40)
    adc = inject(adc, FaultSpec(offset=12.0, seed=2), session1.rig.fs_hz, session1.rig.bias_counts,
                 session1.rig.adc_max)
    raw = dict(session1.rig.to_dict(), samples=adc.shape[2])
    short = load_session(write_session(tmp_path / "short", raw, s.x_mm, s.y_mm, s.height_mm, adc))
    def board_against_host(session):
        caps, got, sig = board_captures(session)
        host = featurize(adc[got], SignalConfig.for_rig(session.rig))
        board = featurize(caps, sig)
        ok = host.usable & board.usable
        assert ok.mean() > 0.8
        return np.abs(np.diff(board.toa_us[ok], axis=1) - np.diff(host.toa_us[ok], axis=1)), sig

    # the board (4 x 50 kHz, scan delays) and the host (100 kHz) differ by ~10 us in DToA on whole bundled records
    d, sig = board_against_host(short)
    assert np.median(d) < 15.0 and np.percentile(d, 90) < 40.0, np.percentile(d, [50, 90])
    # without the lead-in (the session's quiet start unknown) the steps between records pass for onsets
    d_bare, _ = board_against_host(replace(short, rig=replace(short.rig, pretrigger_samples=None)))
    assert np.median(d_bare) > 100.0
    # a long quiet start (the bundled records') is not led in: their board captures are as before
    assert continued_for_capture(session1.adc[:2], session1.rig.fs_hz, 1024, 50000, 64, 96,
                                 session1.rig.pretrigger_samples).shape == session1.adc[:2].shape


def test_a_model_at_the_boards_own_rate_that_the_board_cannot_run_is_trained_again_not_refused():
    """A 50 kHz rig's model that took the posterior mean (or position members): `export` used to skip the board's
    refit (same rate) and then refuse the model, telling the user to do what they had done."""
    from impactsense.export import needs_board_refit

    plain = {"signal": {"fs_hz": 50000.0, "posterior_grid": 0}}
    assert needs_board_refit({"signal": {"fs_hz": 50000.0, "posterior_grid": 15}}, 50000)
    assert needs_board_refit({"position_members": ["a"], "signal": {"fs_hz": 50000.0}}, 50000)
    assert not needs_board_refit(plain, 50000)
    assert needs_board_refit(plain, 25000) and needs_board_refit({"signal": {"fs_hz": 100000.0}}, 50000)
    assert not needs_board_refit({"signal": {"fs_hz": 50000.0, "posterior_grid": 15}}, None)   # --rate native


def test_drops_placed_without_a_class_are_counted_apart_not_scored_wrong(tmp_path, session1):
    """A model without a site map (a new rig's default) places a drop with a dead channel by the three-sensor
    physics position; one trained before the three-channel class (height_class.fit_three_channel_classes) cannot
    classify it: evaluate said "class acc 0.00"; it now scores the classified drops and says how many have none
    and why. A model trained now classifies them from the other three channels."""
    import impactsense as isn
    from impactsense.faults import FaultSpec, inject
    from impactsense.workflow import evaluate

    s = session1.subset(np.arange(0, 771, 6))
    model = isn.train(s, site_map="none", trees=10)
    rows = np.asarray(model.card["split"]["test_recordings"])
    rows = np.flatnonzero(np.isin(s.recording_id, rows))
    dead = replace(s, adc=inject(s.adc, FaultSpec(dead_channel=2, seed=1), s.rig.fs_hz, s.rig.bias_counts,
                                 s.rig.adc_max))
    rep = evaluate(dead, model, rows)
    assert rep["predicted"] == len(rows) and rep["classified"] == len(rows) and rep["energy_class_accuracy"] > 0.8
    clean = evaluate(s, model, rows)
    assert clean["classified"] == clean["predicted"] and clean["energy_class_accuracy"] > 0.8
    model.three_channel_class = {}      # a model from before
    rep = evaluate(dead, model, rows)
    assert rep["predicted"] == len(rows) and rep["classified"] == 0 and np.isnan(rep["energy_class_accuracy"])


def test_the_zero_shot_class_boundary_sits_in_the_sessions_gap_between_heights(session1):
    """A session dropped from a few heights (here 110, 150, 190, 200 mm) has one on its classes' threshold
    (the virtual drops' 75th percentile, 175 mm, lies between 150 and 190); the twin's classifier trained on
    virtual drops in 5 mm steps cut just under the threshold, so drops near it were a coin toss. It is now
    trained again with its boundary in the middle of the session's gap (150..190 mm)."""
    import impactsense as isn
    from impactsense.models import impact_energy_j
    from impactsense.zeroshot import class_boundary_in_the_sessions_gap

    virtual = session1.subset(np.arange(0, 771, 5))           # stands in for the virtual drops: 5 mm steps
    model = isn.train(virtual, test_fraction=0.0, trees=10)  # the bundled twin's site map
    assert model.site_map is not None
    coarse = session1.subset(np.flatnonzero(np.isin(session1.height_mm, (110, 150, 190, 200))))
    m = session1.rig.ball_mass_g
    assert impact_energy_j(150, m) < model.energy_threshold_j <= impact_energy_j(190, m)
    boundary = class_boundary_in_the_sessions_gap(model, coarse.height_mm, m, virtual, model.signal, model.twin_fit)
    assert boundary == pytest.approx(np.sqrt(impact_energy_j(150, m) * impact_energy_j(190, m)), rel=1e-6)
    # the refitted classifier on the twin's log10 height: low below the gap's middle, high above it
    h = np.array([150.0, 160.0, 178.0, 190.0])
    assert model.forest_energy.predict(np.log10(h)[:, None]).tolist() == [0, 0, 1, 1]
    # a session in the virtual drops' own steps has no wider gap: the classifier stays as trained
    assert class_boundary_in_the_sessions_gap(model, virtual.height_mm, m, virtual, model.signal, model.twin_fit) is None
    assert class_boundary_in_the_sessions_gap(model, coarse.height_mm, m, None, model.signal, model.twin_fit) is None


def test_the_zero_shot_class_cut_is_the_middle_of_the_sessions_gap_not_of_the_virtual_steps(session1, monkeypatch):
    """With a twin height estimate that is exact, the classifier's cut lies in the middle of the session's gap
    (150 | 190 mm: 168.8 mm), not between the virtual drops' nearest 5 mm steps either side of it (165 | 170 mm:
    167.5): the virtual drops inside the session's gap are left out of its training, so a drop from 168 mm (a
    height the session never holds) is low and one from 170 mm high."""
    import impactsense as isn
    from impactsense import zeroshot
    from impactsense.pipeline import featurize

    virtual = session1.subset(np.arange(0, 771, 5))
    model = isn.train(virtual, test_fraction=0.0, trees=10)
    coarse = session1.subset(np.flatnonzero(np.isin(session1.height_mm, (110, 150, 190, 200))))
    use = np.flatnonzero(featurize(virtual.adc, model.signal).usable)
    exact = np.log10(np.asarray(virtual.height_mm, float)[use])

    def exact_estimate(site, fit, feats, usable, xy):
        assert len(feats) == exact.size
        return {"log10_height_mm": exact}

    monkeypatch.setattr(zeroshot, "twin_estimate", exact_estimate)
    zeroshot.class_boundary_in_the_sessions_gap(model, coarse.height_mm, session1.rig.ball_mass_g, virtual,
                                                model.signal, model.twin_fit)
    assert model.forest_energy.predict(np.log10([150.0, 165.0, 168.0, 170.0, 190.0])[:, None]).tolist() == [0, 0, 0, 1, 1]


def test_demo_on_a_new_rig_trains_the_model_train_trains(tmp_path, session1):
    """`demo --data DATA` on a rig without a site map chooses the energy class as `train DATA` does (the card's
    energy_class_choice), so the demo's figures are the commands'."""
    from impactsense import cli

    s = session1.subset(np.arange(0, 771, 8))
    raw = session1.rig.to_dict()   # sensors declared 1 mm off the bundled rig's: not the bundled twin's rig
    raw["sensors"] = [dict(c, x_mm=c["x_mm"] + 1.0) for c in raw["sensors"]]
    data = write_session(tmp_path / "other", raw, s.x_mm, s.y_mm, s.height_mm, s.adc, s.case_id, s.repetition)
    assert cli.main(["demo", "--data", str(data), "--out", str(tmp_path / "demo")]) == 0
    card = json.loads((tmp_path / "demo" / "model" / "model_card.json").read_text())
    assert "energy_class_choice" in card and "twin" not in card


def test_calibrate_says_when_a_laminate_constant_stops_at_the_materials_bound(tmp_path, session1):
    """A laminate fit that ran to the materials table's range (E1 and G12 at their upper bounds) is named in
    calibrate's summary instead of being printed as a fitted value."""
    from impactsense.commands.calibrate import _at_bounds

    raw = dict(session1.rig.to_dict(), plate_material="GFRP laminate (E-glass/epoxy)")
    (tmp_path / "rig.json").write_text(json.dumps(raw))
    cal = {"data": str(tmp_path)}
    text = _at_bounds(cal, {"E1_mpa": 50000.0, "E2_mpa": 15560.0, "G12_mpa": 8000.0})
    assert "E1 50000 MPa (upper)" in text and "G12 8000 MPa (upper)" in text and "E2" not in text
    assert _at_bounds(cal, {"E1_mpa": 32000.0, "E2_mpa": 11000.0, "G12_mpa": 4200.0}) == ""


def test_retrain_warns_when_its_model_is_worse_than_the_baseline_on_the_session():
    """A debonded channel on a plate whose signal sits near the bond's low-pass was diagnosed as a disc moved
    107 mm with a 1 kHz low-pass, and the retrained model placed the session's drops 3x worse than the
    baseline model, silently. retrain now says so."""
    from types import SimpleNamespace

    from impactsense.commands.retrain import worse_than_baseline

    moved = [SimpleNamespace(effect="sensor_position", sensor=1)]
    rows = {"baseline model": {"mae_mm": 35.6}, "retrained model": {"mae_mm": 112.4}}
    text = worse_than_baseline(rows, moved, "F")
    assert text.startswith("WARNING") and "sensor_position[1]" in text and "112.40" in text
    assert worse_than_baseline({"baseline model": {"mae_mm": 35.6}, "retrained model": {"mae_mm": 20.0}}, moved, "F") is None


def test_info_reports_mains_hum_the_baseline_noise_does_not_see(session1):
    """`info`'s noise rms is the core's baseline segment (a few ms: 50 Hz hum looks like an offset there); its hum
    column reads 50/60 Hz over the quiet start or the tail: a session with 40-count hum says so, a clean one not."""
    from impactsense.commands.info import summarise
    from impactsense.faults import FaultSpec, inject_session

    sub = session1.subset(np.arange(0, len(session1), 40))
    clean = summarise(sub)["channels"]
    hum = summarise(inject_session(sub, FaultSpec(hum=40.0, hum_hz=50.0, seed=1)))["channels"]
    assert all(c["hum_counts"] < 2.0 for c in clean)
    assert all(15.0 < c["hum_counts"] < 45.0 for c in hum)   # 0.5..1 x 40 counts per channel
    assert all(c["noise_rms_counts"] < 5.0 for c in hum)     # what the baseline segment alone reports
    # a lab on 60 Hz mains: the column names the frequency it reads (before: "50/60 Hz", the larger of the two)
    hum60 = summarise(inject_session(sub, FaultSpec(hum=40.0, hum_hz=60.0, seed=1)))["channels"]
    assert all(c["hum_hz"] == 50.0 for c in hum) and all(c["hum_hz"] == 60.0 for c in hum60)
    assert all(15.0 < c["hum_counts"] < 45.0 for c in hum60)


def test_info_reads_no_hum_from_white_noise_over_a_short_tail():
    """A 200 kHz logger of 8000 samples keeping 5 ms before the hit: info reads the hum over the record's 20 ms
    tail, one mains period, where 50 Hz, 60 Hz, offset and trend are nearly collinear; white noise of 24 counts
    there read as 7-8 counts of 'hum' on a session with none. The column now says '<floor' (what the noise
    alone reads) and a hum of 40 counts is still reported."""
    from types import SimpleNamespace

    from impactsense.commands.info import hum_counts, hum_text
    from impactsense.faults import FaultSpec, inject

    fs, n, bias = 200000, 8000, 32768
    rng = np.random.default_rng(3)
    noise = np.clip(bias + rng.normal(0, 24.0, (40, 4, n)), 0, 65535).astype(np.uint16)
    rig = SimpleNamespace(fs_hz=fs, pretrigger_samples=1000, bias_counts=bias)
    amp, _, floor, _, _ = hum_counts(SimpleNamespace(adc=noise, rig=rig))
    from impactsense.hum import hum_lock_in
    from impactsense.residuals import tail_start
    tail = np.median(hum_lock_in(noise[:, :, tail_start(n, fs):] - float(bias), fs)[0].max(axis=2), axis=0)
    assert np.all(tail > 2.0)                    # what the column printed before (the tail alone)
    assert np.all(amp < floor) and np.all(floor < 18.0)
    assert all(hum_text({"hum_counts": a, "hum_floor_counts": f}).startswith("<") for a, f in zip(amp, floor))
    hummed = inject(noise, FaultSpec(hum=40.0, hum_hz=50.0, seed=1), fs, bias, 65535)
    amp, _, floor, _, _ = hum_counts(SimpleNamespace(adc=hummed, rig=rig))
    assert np.all(amp > floor) and np.all((15.0 < amp) & (amp < 45.0))


def test_records_longer_than_the_core_reads_are_read_over_its_first_samples(tmp_path, session1):
    """A logger keeping more samples than the core's kMaxSamples (e.g. 10000 at 250 kHz): the session loads
    (its quiet start measured), every path into the core reads the records' first CORE_MAX_SAMPLES, and the
    picks and energies are the short records' (the event ends long before); a declared pre-trigger past what the
    core reads is a clear error naming the field."""
    from impactsense.signal import CORE_MAX_SAMPLES

    s = session1.subset(ROWS)
    extra = CORE_MAX_SAMPLES + 1808 - s.adc.shape[2]
    rng = np.random.default_rng(0)
    tail = np.rint(session1.rig.bias_counts + rng.normal(0, 1.5, (*s.adc.shape[:2], extra)))
    long = np.concatenate([s.adc, tail.astype(np.uint16)], axis=2)
    raw = dict(session1.rig.to_dict(), samples=long.shape[2])
    path = write_session(tmp_path / "long", raw, s.x_mm, s.y_mm, s.height_mm, long, s.case_id, s.repetition)
    ls = load_session(path)
    assert ls.rig.pretrigger_samples is not None and ls.adc.shape[2] == 10000
    short = featurize(s.adc, SignalConfig.for_rig(session1.rig))
    f = featurize(ls.adc, SignalConfig.for_rig(ls.rig))
    ok = short.usable & f.usable
    assert ok.mean() > 0.9
    assert np.median(np.abs(f.toa_us[ok] - short.toa_us[ok])) < 0.5
    # the energies over ToA .. n2 gain the extra noise tail's share at most (n2 at 99 % of the cumulative energy)
    assert np.median(f.energy[ok] / short.energy[ok]) == pytest.approx(1.0, abs=0.05)
    with pytest.raises(DataError, match="pretrigger_samples.*first 8192"):
        rig_from_dict(dict(raw, pretrigger_samples=CORE_MAX_SAMPLES + 10))
