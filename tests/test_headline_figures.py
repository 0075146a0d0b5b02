"""The README's headline figures, asserted: `impactsense demo` run as the README runs it prints the README's
table, and each figure sits inside a bound taken from its spread over seeded case splits (mean and worst
split, `benchmarks/bench_splits.py`), tight enough that a 1.3x regression fails.

How the bounds are set (measured on 10 case splits of session-1, 100 trees, the bundled twin; split 0 is the
demo's; docs/findings.md "What one split's figure is worth"):
- twin's matched position, whole plate: split 0 1.20 mm; splits mean 1.27, worst 1.51. Split 0 is held at
  <= 1.55 mm: any split passes it, and 1.3 x 1.20 = 1.56 fails. Inner region 1.23 (worst 1.43): <= 1.50.
  The forests' position 2.05 (worst 2.50): <= 2.55.
- energy class: split 0 0.987 (2 of 155 wrong); splits 0.906-1.00. One split cannot tell 1.3x of two errors
  from the split's draw, so split 0 is held at >= 0.98 (<= 3 wrong) and the mean over splits (slow test
  below, >= 0.966 against 0.972 measured) catches 1.3x.
- session-2 with the session-1 model: 2.27 mm (splits 2.19-2.29), bound 2.60 mm (1.3x is 2.95); class 0.98
  (3 of 160 wrong) held at >= 0.975 (<= 4 wrong).
- the shipped board model on session-2 (firmware app, emulated board): the README's figure, bound 1.15x.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()

# README table row -> (the demo's section, the demo's row label)
DEMO_ROWS = {
    "seed paper, measured-trained, whole plate": ("session-1", "seed paper, measured-trained, whole plate"),
    "seed paper, measured-trained, inner region": ("session-1", "seed paper, measured-trained, inner region"),
    "impactsense, twin's matched position, whole plate": ("session-1", "impactsense, twin's matched position, whole plate"),
    "impactsense, twin's matched position, inner region": ("session-1", "impactsense, twin's matched position, inner region"),
    "impactsense, forests' position (the twin's start), whole plate": (
        "session-1", "impactsense, forests' position (the twin's start), whole plate"),
    "impactsense, forests' position, inner region": ("session-1", "impactsense, forests' position, inner region"),
    "impactsense, physics localiser only, whole plate": ("session-1", "impactsense, physics localiser only, whole plate"),
    "session-2 (later day), session-1 model, whole plate": ("session-2", "impactsense, whole plate"),
    "session-2, session-1 model, forests' position": ("session-2", "impactsense, forests' position, whole plate"),
}


def readme_table() -> dict:
    """The table under "What `impactsense demo` prints": row label -> [R2, RMSE, MAE, class] as printed."""
    section = README.split("## What `impactsense demo` prints", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip().strip("*") for c in line.strip().strip("|").split("|")]
        if len(cells) == 5 and re.fullmatch(r"[\d.]+", cells[1]):
            rows[cells[0]] = cells[1:]
    return rows


def demo_tables(stdout: str) -> dict:
    """The demo's printed tables: (section, row label) -> [R2, RMSE, MAE, class] as printed."""
    out, section = {}, None
    for line in stdout.splitlines():
        if line.startswith("session-1, held-out"):
            section = "session-1"
        elif line.startswith("session-2"):
            section = "session-2"
        m = re.match(r"^(\S.*?)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+|-)\s*$", line)
        if m and section:
            out[(section, m.group(1))] = list(m.groups()[1:])
    return out


def same_printed(a: str, b: str) -> bool:
    """Equal as printed, within one unit of the last printed digit (a last-bit difference of a float sum on
    another machine may round the other way); '-' only equals '-'."""
    if "-" in (a, b):
        return a == b
    places = max(len(x.split(".")[1]) if "." in x else 0 for x in (a, b))
    return abs(float(a) - float(b)) <= 10 ** -places + 1e-12


def test_demo_prints_the_readme_table(demo_run):
    """README command 1's output: every row of the README's table is what the demo prints on this commit."""
    _, stdout = demo_run
    readme, printed = readme_table(), demo_tables(stdout)
    assert set(readme) == set(DEMO_ROWS), sorted(readme)
    for label, key in DEMO_ROWS.items():
        assert key in printed, (key, stdout)
        got = printed[key]
        assert all(same_printed(r, g) for r, g in zip(readme[label], got)), (label, readme[label], got)
    # and the files the README says it writes
    out, _ = demo_run
    for name in ("model/model_card.json", "evaluate-session-1.json", "evaluate-session-2.json"):
        assert (out / name).is_file(), name
    assert any((out / "plots").glob("*.png"))


@pytest.fixture(scope="module")
def demo_reports(demo_run):
    out, _ = demo_run
    return tuple(json.loads((out / f"evaluate-session-{k}.json").read_text()) for k in (1, 2))


def test_twin_position_and_class_on_the_demo_split(demo_reports):
    """Split 0's held-out 155 drops: the twin's matched position <= 1.55 mm (README 1.20; the worst of 10
    splits 1.51), inner region <= 1.50 mm (1.23; worst 1.43), the forests' position <= 2.55 mm (2.05; worst
    2.50) and the twin >= 1.5x better than the forests it starts from; class >= 0.98 (0.987)."""
    held, _ = demo_reports
    assert held["n"] == held["predicted"] == 155 and held["position_source"] == "twin"
    assert held["all"]["mae_mm"] <= 1.55, held["all"]
    assert held["inner"]["mae_mm"] <= 1.50, held["inner"]
    assert held["forest"]["all"]["mae_mm"] <= 2.55, held["forest"]["all"]
    assert held["all"]["mae_mm"] * 1.5 <= held["forest"]["all"]["mae_mm"]
    assert held["energy_class_accuracy"] >= 0.98
    # not by answering one class: the held-out split has both classes and the high class is the minority
    assert 0.1 < held["high_energy_fraction"] < 0.5


def test_session2_with_the_session1_model(demo_reports):
    """Session-2 (a later day, all 160 drops, channel 3 reads 7.4 us early unknown to the model): MAE
    <= 2.60 mm (README 2.27; 1.3x is 2.95), class >= 0.975 (0.98), the twin still beats the forests."""
    _, later = demo_reports
    assert later["n"] == later["predicted"] == 160
    assert later["all"]["mae_mm"] <= 2.60, later["all"]
    assert later["energy_class_accuracy"] >= 0.975
    assert later["all"]["mae_mm"] < later["forest"]["all"]["mae_mm"]


def test_shipped_board_model_on_session2_is_the_readme_figure():
    """The shipped tables (models/) in the firmware app, emulated board, session-2's 160 drops: the README's
    figure (section "Firmware") as printed, and a bound 1.15x above it on MAE, class >= the README's - 0.02."""
    from impactsense.board.scores import board_accuracy
    from impactsense.data import load_session
    from impactsense.export import firmware_models

    m = re.search(r"reports all 160 drops with MAE\s+\*\*([\d.]+) mm\*\* and energy class accuracy \*\*([\d.]+)\*\*",
                  README)
    assert m, "the README's board figure on session-2"
    readme_mae, readme_class = float(m.group(1)), float(m.group(2))
    shipped = json.loads((ROOT / "models" / "export.json").read_text())
    models, signal = firmware_models(ROOT / "models")
    acc = board_accuracy(load_session("bundled:session-2"), models, signal, float(shipped["energy_threshold_j"]),
                         50000)
    assert acc["reported"] == acc["n"] == 160
    assert round(acc["all"]["mae_mm"], 2) == readme_mae and round(acc["energy_class_accuracy"], 2) == readme_class
    assert acc["all"]["mae_mm"] <= 1.15 * readme_mae and acc["energy_class_accuracy"] >= readme_class - 0.02


@pytest.mark.slow
def test_headline_figures_over_ten_case_splits():
    """Mean and worst split of every headline figure over 10 seeded splits inside bench_splits.LIMITS
    (about 1.15x the measured mean and worst MAE, 1.16-1.23x the error rate of a class: a 1.3x regression
    misses). ~2-3 min."""
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    import bench_splits

    summary = bench_splits.summarise([bench_splits.split_figures(seed) for seed in range(10)])
    assert all(r["ok"] for r in summary.values()), {k: (v["mean"], v["worst"]) for k, v in summary.items()}
    assert np.isfinite([r["mean"] for r in summary.values()]).all()


# zero-shot over case splits (slow test below): bound on the mean and on the worst of ZERO_SHOT_SEEDS
ZERO_SHOT_SEEDS = (0, 1, 2, 3)
ZERO_SHOT_LIMITS = {   # figure -> (bound on the mean, bound on the worst split); see the test's docstring
    "mae_mm": (1.73, 1.84),
    "inner_mae_mm": (1.71, 1.76),
    "class_error": (0.0234, 0.0624),
}


def readme_zero_shot_figures() -> dict:
    """The README's zero-shot sentence on `impactsense demo --zero-shot --calibration <bundled>` (section "The
    closed loop, in numbers"): figure -> the number as printed there."""
    text = " ".join(README.split())
    m = re.search(r"`impactsense demo --zero-shot --calibration host/impactsense/data/twin/calibration\.json` on "
                  r"session-1's test split \((\d+) drops, calibration drops excluded\): sim-trained MAE \*\*([\d.]+) "
                  r"mm\*\* whole plate \(R2 ([\d.]+)\), \*\*([\d.]+) mm\*\* inner region, class accuracy "
                  r"\*\*([\d.]+)\*\*; measured-trained on the same split ([\d.]+) / ([\d.]+) mm, (\d+(?:\.\d+)?)", text)
    u = re.search(r"On the measured test split ([\d.]+) of the errors lie within 1x and ([\d.]+) within 2x, "
                  r"rms\(error / u\) ([\d.]+) \(([\d.]+) / ([\d.]+) with the virtual drops' constants alone; the "
                  r"measured-trained model ([\d.]+) / ([\d.]+)\)", text)
    assert m and u, "the README's zero-shot figures (section 'The closed loop, in numbers')"
    keys = ("n", "sim_mae", "sim_r2", "sim_inner", "sim_class", "measured_mae", "measured_inner", "measured_class")
    ukeys = ("sim_1x", "sim_2x", "sim_rms", "virtual_1x", "virtual_2x", "measured_1x", "measured_2x")
    return dict(zip(keys, m.groups())) | dict(zip(ukeys, u.groups()))


def printed_zero_shot_figures(stdout: str) -> dict:
    """The same figures from what `impactsense demo --zero-shot` prints (zeroshot.zero_shot_table)."""
    rows = {}
    for line in stdout.splitlines():
        m = re.match(r"^impactsense, (sim|measured)-trained, (whole plate|inner region)\s+([\d.]+)\s+([\d.]+)\s+"
                     r"([\d.]+)\s+([\d.]+)\s*$", line)
        if m:
            rows[(m.group(1), m.group(2))] = m.groups()[2:]
        m = re.match(r"^\s+(sim-trained|sim-trained, virtual drops' scale alone|measured-trained)\s+([\d.]+) / "
                     r"([\d.]+)\s+rho\s+\S+\s+rms\(error / u\) ([\d.]+)\s*$", line)
        if m:
            rows[m.group(1)] = m.groups()[1:]
    n = re.search(r"measured test split: (\d+) drops", stdout)
    assert n and len(rows) == 7, stdout
    sim, sim_in = rows[("sim", "whole plate")], rows[("sim", "inner region")]
    meas, meas_in = rows[("measured", "whole plate")], rows[("measured", "inner region")]
    return {"n": n.group(1), "sim_mae": sim[2], "sim_r2": sim[0], "sim_inner": sim_in[2], "sim_class": sim[3],
            "measured_mae": meas[2], "measured_inner": meas_in[2], "measured_class": meas[3],
            "sim_1x": rows["sim-trained"][0], "sim_2x": rows["sim-trained"][1], "sim_rms": rows["sim-trained"][2],
            "virtual_1x": rows["sim-trained, virtual drops' scale alone"][0],
            "virtual_2x": rows["sim-trained, virtual drops' scale alone"][1],
            "measured_1x": rows["measured-trained"][0], "measured_2x": rows["measured-trained"][1]}


@pytest.fixture(scope="module")
def zero_shot_demo(tmp_path_factory):
    """`impactsense demo --zero-shot --calibration host/impactsense/data/twin/calibration.json --out DIR` as the
    README runs it (seed 0, 490 virtual drops, the demo's measured half too): (DIR, its stdout). Slow tests only."""
    import subprocess
    import sys

    from impactsense.sitemap import BUNDLED

    out = tmp_path_factory.mktemp("zero-shot-demo") / "demo"
    p = subprocess.run([sys.executable, "-m", "impactsense.cli", "demo", "--zero-shot", "--calibration",
                        str(BUNDLED.parent / "calibration.json"), "--out", str(out)], capture_output=True, text=True,
                       timeout=3000)
    assert p.returncode == 0, p.stdout + p.stderr
    return out, p.stdout


@pytest.mark.slow
def test_zero_shot_figures_over_four_case_splits(zero_shot_demo, tmp_path):
    """The sim-trained model from the shipped calibration, made as `impactsense demo --zero-shot --calibration
    host/impactsense/data/twin/calibration.json` makes it (zeroshot.run_zero_shot: 490 virtual drops, the four
    calibration cases; no calibration is run), on seeds 0-3 (each seeds the virtual set and the case split; the
    calibration drops are never tested). Seed 0 is that README command itself, run end to end (the demo's
    measured half too), and what it prints is the README's zero-shot sentence (figures as printed, one unit of
    the last digit). Measured (docs/findings.md "The suite's time and what it proves"), on df26977:
    MAE 1.54 / 1.42 / 1.60 / 1.46 mm (mean 1.51, worst 1.60), inner 1.42 / 1.46 / 1.53 / 1.53 (1.49, 1.53), class
    0.987 / 0.987 / 1.000 / 0.948 (2, 2, 0 and 9 drops wrong: error mean 0.0195, worst 0.052; seed 3 misses
    issue 4's 0.95, as bench_zeroshot_class.py says); on f9766bc (bench_zeroshot_class) MAE 1.54 / 1.41 / 1.58 /
    1.43, inner 1.42 / 1.45 / 1.51 / 1.47, class 0.981 / 0.994 / 1.000 / 0.942 (error mean 0.021, worst 0.058).
    Bounds: 1.15x the MAE's mean and worst, 1.2x the class's
    error rate (mean <= 15 of 630 drops wrong, worst <= 10 of 173): a 1.3x regression of any misses. 4 min
    on 2 cores at load ~11, 10 min at ~20 (a seed's 490 virtual drops take most of it)."""
    from impactsense.data import load_session
    from impactsense.sitemap import BUNDLED
    from impactsense.zeroshot import run_zero_shot

    session = load_session("bundled:session-1")
    calibration = BUNDLED.parent / "calibration.json"
    rows = []
    for seed in ZERO_SHOT_SEEDS:
        if seed == 0:   # the README's command (demo's default seed 0 and 490 virtual drops)
            out, stdout = zero_shot_demo
            printed = printed_zero_shot_figures(stdout)
            r = json.loads((out / "zero-shot" / "zero-shot.json").read_text())
        else:
            r = run_zero_shot(session, calibration, tmp_path / f"seed-{seed}", n_virtual=490, seed=seed,
                              progress=False)
        sim = r["sim_trained"]
        assert not set(r["test_recordings"]) & set(r["calibration_recordings"])
        # not by answering the majority class: the split has both classes, the high class the minority
        assert 0.1 < sim["high_energy_fraction"] < 0.5
        rows.append({"mae_mm": sim["all"]["mae_mm"], "inner_mae_mm": sim["inner"]["mae_mm"],
                     "class_error": 1.0 - sim["energy_class_accuracy"]})
    for key, (mean_bound, worst_bound) in ZERO_SHOT_LIMITS.items():
        got = np.array([row[key] for row in rows])
        assert got.mean() <= mean_bound and got.max() <= worst_bound, (key, got)
    readme = readme_zero_shot_figures()
    differ = {k: (readme[k], printed[k]) for k in readme if not same_printed(readme[k], printed[k])}
    assert not differ, f"README (as printed there, as printed now): {differ}"


@pytest.mark.slow
def test_zero_shot_board_figure_is_the_readmes(zero_shot_demo, tmp_path):
    """`impactsense export OUT/zero-shot/model-sim --out DIR` (the README's zero-shot board model: made again at
    4 x 50 kHz from the virtual drops and the calibration drops' fits, scored by the firmware app on the emulated
    board over the measured test split) prints the README's MAE, inner MAE and class (as printed there, one unit
    of the last digit), within 1.15x on MAE and -0.02 on class of it. ~5-10 min (the board's 5 mm site map)."""
    import subprocess
    import sys

    text = " ".join(README.split())
    m = re.search(r"On that split \((\d+) drops\) the emulated board gives MAE \*\*([\d.]+) mm\*\* \(inner ([\d.]+) "
                  r"mm\), class accuracy \*\*([\d.]+)\*\*", text)
    assert m, "the README's zero-shot board figure (section 'The closed loop, in numbers')"
    n, mae, inner, acc = m.groups()
    out, _ = zero_shot_demo
    p = subprocess.run([sys.executable, "-m", "impactsense.cli", "export", str(out / "zero-shot" / "model-sim"),
                        "--out", str(tmp_path / "board")], capture_output=True, text=True, timeout=3000)
    assert p.returncode == 0, p.stdout + p.stderr
    got = re.search(r"the measured test split on the emulated board .*: (\d+)/(\d+) reported, MAE ([\d.]+) mm "
                    r"\(inner ([\d.]+) mm\), mean distance [\d.]+ mm, energy class accuracy ([\d.]+)", p.stdout)
    assert got, p.stdout
    reported, total, got_mae, got_inner, got_acc = got.groups()
    assert reported == total == n, p.stdout
    assert float(got_mae) <= 1.15 * float(mae) and float(got_acc) >= float(acc) - 0.02, p.stdout
    places = len(acc.split(".")[1])   # export prints the class to 3 places, the README to 2
    printed = {"mae": got_mae, "inner": got_inner, "class": f"{float(got_acc):.{places}f}"}
    readme = {"mae": mae, "inner": inner, "class": acc}
    differ = {k: (readme[k], printed[k]) for k in readme if not same_printed(readme[k], printed[k])}
    assert not differ, f"README (as printed there, as printed now): {differ}"


@pytest.mark.slow
def test_cold_zero_shot_demo_is_the_readmes(tmp_path):
    """`impactsense demo --zero-shot` with no calibration given (the README's "cold" run: it calibrates the twin
    anew on the four calibration drops, writes OUT/CAL.json, then trains on 490 virtual drops only) prints the
    README's sim-trained MAE, inner MAE and class for it within 1.15x on the MAEs and -0.02 on the class (the
    bounds of the other README checks here; a fresh calibration lands within the calibration's own spread, so
    the figures are held to a bound, not to the printed digits). 5-10 CPU-min (the calibration's FEM)."""
    import subprocess
    import sys

    text = " ".join(README.split())
    m = re.search(r"A cold `impactsense demo --zero-shot` \(calibrating anew: .*?\) gives \*\*([\d.]+) / ([\d.]+) "
                  r"mm\*\* and class accuracy \*\*([\d.]+)\*\*", text)
    assert m, "the README's cold zero-shot figure (section 'The closed loop, in numbers')"
    mae, inner, acc = (float(g) for g in m.groups())
    out = tmp_path / "demo"
    p = subprocess.run([sys.executable, "-m", "impactsense.cli", "demo", "--zero-shot", "--out", str(out)],
                       capture_output=True, text=True, timeout=3600)
    assert p.returncode == 0, p.stdout + p.stderr
    assert (out / "CAL.json").is_file(), "the cold demo keeps the calibration it made"
    printed = printed_zero_shot_figures(p.stdout)
    assert float(printed["sim_mae"]) <= 1.15 * mae, (printed, mae)
    assert float(printed["sim_inner"]) <= 1.15 * inner, (printed, inner)
    assert float(printed["sim_class"]) >= acc - 0.02, (printed, acc)
