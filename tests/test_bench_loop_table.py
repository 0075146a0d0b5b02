"""bench_loop's verdict: a twin-trained after is held to the twin's own unchanged MAE (the same kind of model),
a measured-trained after to the measured reference's. Rows as bench_loop.json holds them; nothing simulated."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_loop  # noqa: E402


def _mae(v):
    return {"mae_mm": v}


def _rows(twin_after=None, measured_after=4.0):
    delay = {"effect": "channel_delay", "sensor": 2, "params": {"delay_us": 5.0}, "significant": True,
             "param_ci95": {}}
    same = [{"session": f"same-{k}", "truth": None, "named": [], "effects": [], "before": _mae(4.0),
             "after": _mae(4.0), "twin_unchanged": _mae(3.0)} for k in (1, 2)]
    row = {"session": "delay", "truth": {"effect": "channel_delay", "sensor": 2, "params": {"delay_us": 5.0}},
           "named": [("channel_delay", 2)], "effects": [delay], "before": _mae(6.0),
           "measured": _mae(measured_after), "after": _mae(measured_after)}
    if twin_after is not None:
        row["twin"] = row["after"] = _mae(twin_after)
    return {"rows": same + [row], "D_s": 100.0}


def test_a_twin_after_is_held_to_the_twin_with_no_effect_on_the_unchanged_sessions(capsys):
    # 4.5 mm is within 1.2 x the measured controls' 4.0 but not within 1.2 x the twin's own 3.0
    assert bench_loop.table(_rows(twin_after=4.5)) == 1
    assert "1.50 (twin)" in capsys.readouterr().out
    assert bench_loop.table(_rows(twin_after=3.5)) == 0


def test_a_measured_after_keeps_the_measured_yardstick():
    assert bench_loop.table(_rows(measured_after=4.7)) == 0     # 4.7 <= 1.2 x 4.0
    assert bench_loop.table(_rows(measured_after=4.9)) == 1


def test_the_issue_table_gives_the_ratio_to_the_same_drops_without_the_change(capsys):
    """loop_sessions --controls: a changed session's own drops recorded without its change (same seed, kind none);
    the issue table's own-drops column divides the kept after by the reference model's MAE on them."""
    import loop_sessions
    specs = loop_sessions.spec_list(5, [])
    controls = loop_sessions.control_specs(specs)
    changed = [s for s in specs if s.get("truth")]
    assert [c["control_of"] for c in controls] == [s["name"] for s in changed]
    assert all(c["kind"] == "none" and c["seed"] == s["seed"] for c, s in zip(controls, changed))
    assert [c["control_of"] for c in loop_sessions.control_specs(specs, {"move-10", "same-1"})] == ["move-10"]
    out = _rows(measured_after=4.8)
    out["rows"][-1]["own_unchanged"] = _mae(4.0)   # one_changed's: without_change's, else the control's
    bench_loop.table(out)
    assert "| 4.00, 1.20 |" in capsys.readouterr().out


def test_a_narrow_interval_is_printed_with_the_digits_that_tell_its_ends_apart():
    """A hum of 21.03 counts with the interval [21.024, 21.045] was printed '21 [21, 21]' (3 significant
    digits): it read as zero wide. The ends get the digits they need; a real zero-wide one stays so."""
    e = {"param_ci95": {"hum_counts": [21.0243, 21.0445], "delay_us": [-6.31, -5.12], "white": [0.0, 0.0]}}
    assert bench_loop._ci(e, "hum_counts", fmt="{:.3g}") == " [21.02, 21.04]"
    assert bench_loop._ci(e, "delay_us") == " [-6.3, -5.1]"                  # wide enough as it was
    assert bench_loop._ci(e, "white", fmt="{:.3g}") == " [0, 0]"
    assert bench_loop._ci(e, "other") == ""


def test_the_sessions_a_run_makes_use_its_worker_count_and_the_generators_options():
    # `bench_loop.py --workers 1` made its missing sessions with the generator's default of 2 workers
    args = bench_loop.parse(["--seed", "16", "--workers", "1", "--sessions", "/tmp/s", "--only", "delay",
                             "--controls", "--calibration", "rig"])
    gen = bench_loop.generator_args(args)
    assert gen.workers == 1 and gen.seed == 16 and gen.out == "/tmp/s"
    assert gen.only == "ref,delay" and gen.controls and gen.calibration == "rig"
    assert bench_loop.generator_args(bench_loop.parse(["--workers", "3"])).workers == 3


def test_a_session_with_nothing_named_reports_the_reference_model_kept_not_a_retrained_one(capsys):
    """A move under the evidence bar: nothing named, nothing retrained, the after is the reference model's MAE.
    The issue table said '(measured)' for it (a measured-trained model that was never trained); it says the
    reference is kept, with the measured yardstick, also for rows stored before `after_kind` was."""
    out = _rows()
    move = {"session": "move-131", "named": [], "effects": [], "before": _mae(5.0), "after": _mae(5.0),
            "truth": {"effect": "sensor_position", "sensor": 0, "params": {"dx_mm": -4.5, "dy_mm": 5.1}}}
    out["rows"].append(move)
    assert bench_loop.after_kind(move) == "reference"
    assert bench_loop.after_kind(out["rows"][2]) == "measured"
    assert bench_loop.table(out) == 1                         # not named: a miss, and 5.0 > 1.2 x 4.0
    text = capsys.readouterr().out
    line = next(ln for ln in text.splitlines() if ln.startswith("| move-131 | none | 5.00 |"))
    assert "(reference: nothing named, nothing retrained)" in line and "(measured)" not in line
    assert "**1.25**" in line                                 # against the reference model's unchanged mean 4.0


def test_a_moved_disc_whose_measured_model_was_kept_is_held_to_the_measured_yardstick(capsys):
    """retrain's training choice kept the measured drops (the twin's model placed the session worse): the after is
    measured-trained, judged against the reference model's unchanged mean, and the issue table says so."""
    out = _rows(measured_after=4.7)
    row = out["rows"][-1]
    row["twin"] = _mae(5.5)
    row["after_kind"] = "measured"
    row["training_choice"] = {"chosen": "measured"}
    assert bench_loop.table(out) == 0                         # 4.7 <= 1.2 x 4.0 (the twin's 3.0 not the yardstick)
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("| delay | channel_delay[2] | 6.00"))
    assert "4.70 -> 4.70 (measured)" in line and "1.18 -> **1.18**" in line


def test_the_twin_span_option_sets_the_loops_twin_and_leaves_the_sessions_generator_alone(tmp_path):
    from impactsense.sim import SimParams

    args = bench_loop.parse(["--twin-span-ms", "25.3", "--sessions", str(tmp_path)])
    assert bench_loop.generator_args(args).duration_ms == bench_loop.generator_args(
        bench_loop.parse(["--sessions", str(tmp_path)])).duration_ms   # the sessions' cache key unchanged
    assert bench_loop.loop_twin(SimParams(duration_ms=10.0), args).duration_ms == 25.3
    assert bench_loop.loop_twin(SimParams(duration_ms=10.0), bench_loop.parse([])).duration_ms == 10.0
