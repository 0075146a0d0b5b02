"""Per-event cost of the firmware on the Cortex-M4F, in instructions, under qemu (mps2-an386).

Runs firmware/test/qemu/run.sh with `-icount shift=4` (every guest instruction advances virtual time by
16 ns); the test image reads SysTick around each stage and around a calibration loop of exactly 200,000
instructions, so instructions = ticks x 200,000 / calibration ticks (resolution ~2.5 instructions).
Also prints the flash each model form takes (arm-none-eabi-size). Targets: <= 64,000 instructions an event
(the slowest drop of the run) and the slowest buffer without an event <= 20 % of a buffer period; exits 1
on a miss.

    python benchmarks/bench_firmware_cost.py [--data SESSION] [--model-dir shipped|fixture|MODEL_DIR [--trees N]
                                             | --export OUT] [--drops 6 | --rows A:B | --all]
                                             [--site-map auto|none|FILE] [--site-map-step MM] [--profile]

--model-dir shipped (the default) times the shipped board models, models/: the board model they were
exported from is made again by the README's command (`impactsense train bundled --test-fraction 0` and
`impactsense export --trees N`, N from models/export.json; a few minutes the first time, cached in
build/bench-cache/shipped-<tables hash>/; delete it to make it again), and every fixture's exported C
(impactsense_forest_tables.c, impactsense_models.h) is checked to equal models/'s line for line but the
model card's comment (exit 2 when it does not: re-export models/ as the README says). --model-dir fixture trains the bench's own board-rate forests (--trees per
localisation forest, 12 by default) with the energy class on the twin's site map as the board sees it
(--site-map auto: the bundled twin's; the board's 5 mm map takes a few minutes the first time and is cached
in build/bench-cache/). --model-dir MODEL_DIR exports that board model instead (e.g. OUT/board-model from
`impactsense export`); --export OUT takes OUT/board-model with the trees that export chose (its
export.json). --data SESSION replays that session's drops (default: the bundled session-1; e.g.
bundled:session-2) through the image: with a model trained on that rig (--export OUT of `impactsense
export`), the cost on another rig; drops the board does not report once or the model cannot read are left
out and listed. --all times every drop, 100 to a test image (the image's 4 MB flash holds the recordings
as data); --rows A:B one fixture of those rows (the app starts cold on the first). --profile adds the
instructions each function executes (where the features' cost goes; the image runs every stage of each
drop, and its checks, so shares are of the whole run). With --export OUT it prints export's estimate
(OUT/export.json, board.cost) against what qemu measured: the signal (the event less its models, timed per drop)
and the models.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGET = 64000
IDLE_TARGET = 0.20  # of a 256-frame buffer period at 4 x 50 kHz, 64 MHz
BUFFER_CYCLES = 256 / 50000 * 64e6  # 327,680 (one instruction a cycle: flash wait states come on top)


def run(build: Path, extra: list[str], qemu_log: Path | None = None) -> tuple[dict, dict, str]:
    qemu = "-icount shift=4" + (f" -d in_asm,exec,nochain -D {qemu_log}" if qemu_log else "")
    env = dict(os.environ, QEMU_EXTRA=qemu, PYTHON=sys.executable)
    p = subprocess.run([str(ROOT / "firmware/test/qemu/run.sh"), str(build), *extra], env=env,
                       capture_output=True, text=True, timeout=1200)
    if p.returncode != 0:
        sys.exit(f"qemu test image failed ({p.returncode}):\n{p.stdout}\n{p.stderr}")
    out = p.stdout + p.stderr
    ticks = {m.group(1): int(m.group(2)) for m in re.finditer(r"^TICKS (\S+) (\d+)$", out, re.M)}
    per_drop: dict[str, list[int]] = {}   # TICKS_DROP: ticks; DROP: counts
    for m in re.finditer(r"^(TICKS_)?DROP (\S+) (\d+)$", out, re.M):
        per_drop.setdefault(("ticks:" if m.group(1) else "") + m.group(2), []).append(int(m.group(3)))
    return ticks, per_drop, p.stdout


def profile(log: Path, elf: Path, top: int = 25) -> None:
    """Instructions executed per function over the whole test image (every stage of every drop, the
    checks included), from qemu's translation-block log: each block's instructions (in_asm) times its
    executions (exec, unchained). Calls: executions of the function's first instruction."""
    import bisect
    from collections import Counter

    blocks: dict[str, list[int]] = {}
    counts: Counter = Counter()
    pending = None
    with open(log, errors="replace") as f:
        for line in f:
            if line.startswith("IN:"):
                pending = []
            elif line.startswith("0x") and pending is not None:
                pending.append(int(line[:10], 16))
            elif line.startswith("Trace"):
                host = line.split()[2]
                if pending is not None:
                    blocks[host], pending = pending, None
                for a in blocks.get(host, ()):
                    counts[a] += 1
    nm = subprocess.run(["arm-none-eabi-nm", "-C", "-S", "--defined-only", str(elf)], capture_output=True,
                        text=True).stdout
    funcs = sorted((int(p[0], 16) & ~1, int(p[1], 16), p[3]) for p in (l.split(None, 3) for l in nm.splitlines())
                   if len(p) == 4 and p[2] in "tTwW")
    starts = [f[0] for f in funcs]
    per: Counter = Counter()
    calls: Counter = Counter()
    for a, c in counts.items():
        i = bisect.bisect_right(starts, a) - 1
        if i >= 0 and a < funcs[i][0] + funcs[i][1]:
            per[funcs[i][2]] += c
            if a == funcs[i][0]:
                calls[funcs[i][2]] = c
    total = sum(counts.values())
    print(f"profile: {total:,} instructions executed by the image; per function (calls, per call):")
    for name, c in per.most_common(top):
        k = calls.get(name, 0)
        print(f"{c:>12,} {100 * c / total:5.1f}% {k:>7,} {c // k if k else 0:>8,}  {name[:90]}")


SHIPPED = ROOT / "models"


MODEL_SOURCES = ("impactsense_forest_tables.c", "impactsense_models.h")  # what the board's default env builds


def same_models(a: Path, b: Path) -> bool:
    """Two export folders' generated C (node tables, site map, configs) and header equal line for line but
    their first line, the comment naming the model card (whose hash changes with each training run)."""
    return all((a / f).read_text().splitlines()[1:] == (b / f).read_text().splitlines()[1:] for f in MODEL_SOURCES)


def shipped_board_model(cache_root: Path) -> tuple[Path, int, int]:
    """(the board model models/ was exported from, its localisation and energy trees), made again by the
    README's command and cached; exits 2 when its export is not models/."""
    tables = SHIPPED / "forest_tables.npz"
    if not tables.is_file():
        sys.exit(f"{tables}: no shipped board models (run `impactsense export`, README)")
    done = json.loads((SHIPPED / "export.json").read_text())["trees"]
    trees, energy_trees = int(done["x"]), int(done["energy"])
    # keyed on the tables and on what writes the C (the core's config struct, the exporter): a cache made
    # before a config field was added is not this core's export
    writers = (tables, ROOT / "firmware" / "lib" / "impactcore" / "src" / "impactcore.h",
               ROOT / "host" / "impactsense" / "export_c.py")
    key = hashlib.sha256(b"".join(p.read_bytes() for p in writers)).hexdigest()[:16]
    cache = cache_root / f"shipped-{key}"
    board = cache / "out" / "board-model"
    if not (board / "model_card.json").is_file():
        print(f"making the shipped board model again (once, cached in {cache}): impactsense train bundled "
              f"--test-fraction 0 --out M && impactsense export M --out OUT --trees {trees}", flush=True)
        shutil.rmtree(cache, ignore_errors=True)
        cli = "import sys; from impactsense.cli import main; sys.exit(main(sys.argv[1:]))"
        for argv in (["train", "bundled", "--test-fraction", "0", "--out", str(cache / "model")],
                     ["export", str(cache / "model"), "--out", str(cache / "out"), "--trees", str(trees)]):
            p = subprocess.run([sys.executable, "-c", cli, *argv], capture_output=True, text=True)
            if p.returncode != 0:
                print(f"impactsense {' '.join(argv)} failed ({p.returncode}):\n{p.stdout}\n{p.stderr}", file=sys.stderr)
                raise SystemExit(2)
    if not same_models(cache / "out", SHIPPED):
        print(f"{tables} is not what `impactsense train bundled --test-fraction 0` + `export --trees {trees}` "
              f"gives with this core: re-export models/ (README), or pass --model-dir", file=sys.stderr)
        raise SystemExit(2)
    return board, trees, energy_trees


def obj_size(build: Path, name: str) -> int:
    out = subprocess.run(["arm-none-eabi-size", str(build / "obj" / name)], capture_output=True, text=True).stdout
    return int(out.splitlines()[1].split()[0])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="session folder whose drops are replayed (default: the bundled session)")
    ap.add_argument("--model-dir", default="shipped",
                    help="shipped (models/, the default), fixture (the bench's own forests) or a board MODEL_DIR")
    ap.add_argument("--export", help="an `impactsense export` folder: its board-model with the trees it exported "
                                     "(instead of --model-dir / --trees)")
    ap.add_argument("--energy-trees", type=int, help="the energy forest's trees (default: all)")
    ap.add_argument("--trees", type=int, default=None,
                    help="localisation trees exported (shipped: models/export.json's; otherwise 12)")
    ap.add_argument("--drops", type=int, default=6,
                    help="drops in the fixture, evenly spaced (each one's whole event is timed)")
    ap.add_argument("--all", action="store_true",
                    help="every drop of the session, in fixtures of --chunk rows (the test image holds ~100 drops)")
    ap.add_argument("--chunk", type=int, default=100)
    ap.add_argument("--rows", help="the session's rows A:B in one fixture instead of --drops (e.g. to --profile "
                                   "the slowest)")
    ap.add_argument("--site-map", default="auto", help="twin site map source: auto, none or a file")
    ap.add_argument("--site-map-step", type=float, default=None, help="board map grid step (default: the map's)")
    ap.add_argument("--json")
    ap.add_argument("--profile", action="store_true",
                    help="also count the instructions each function executes (qemu -d exec; one fixture, "
                         "not with --all; a log of ~100 MB for 6 drops)")
    args = ap.parse_args()
    if args.profile and args.all:
        ap.error("--profile takes one fixture (--drops N), not --all")
    if not shutil.which("arm-none-eabi-gcc") or not shutil.which("qemu-system-arm"):
        print("needs arm-none-eabi-gcc and qemu-system-arm (scripts/setup-debian.sh)")
        return 2
    cache_root = ROOT / "build" / "bench-cache"
    cache_root.mkdir(parents=True, exist_ok=True)
    shipped = args.model_dir == "shipped" and not args.export
    if args.export:
        done = json.loads((Path(args.export) / "export.json").read_text())
        args.model_dir = str(Path(args.export) / "board-model")
        args.trees, args.energy_trees = int(done["trees"]["x"]), int(done["trees"]["energy"])
    elif shipped:
        board, shipped_trees, shipped_energy = shipped_board_model(cache_root)
        if args.trees not in (None, shipped_trees):
            ap.error(f"--trees {args.trees}: the shipped models have {shipped_trees} (models/export.json)")
        args.model_dir, args.trees, args.energy_trees = str(board), shipped_trees, shipped_energy
    model_dir = None if args.model_dir == "fixture" else args.model_dir
    extra = ["--trees", str(args.trees if args.trees is not None else 12)]
    extra += ["--energy-trees", str(args.energy_trees)] if args.energy_trees else []
    extra += ["--model-dir", model_dir] if model_dir else []
    extra += ["--data", args.data] if args.data else []
    cache = cache_root / f"board-site-map-{args.site_map_step or 'default'}.npz"
    extra += ["--site-map", args.site_map, "--site-map-cache", str(cache)]
    extra += ["--site-map-step", str(args.site_map_step)] if args.site_map_step else []
    if args.all:
        from impactsense.data import load_session
        n = len(load_session(args.data) if args.data else load_session())
        fixtures = [["--rows", f"{a}:{min(a + args.chunk, n)}"] for a in range(0, n, args.chunk)]
    elif args.rows:
        fixtures = [["--rows", args.rows]]
    else:
        fixtures = [["--drops", str(args.drops)]]
    per_drop: dict[str, list[int]] = {}
    rows: list[int] = []
    skipped: list[int] = []  # --all: drops the board does not report or the models cannot read (no full event)
    event_max = 0
    app_max = {"app_event_max": 0, "app_idle_buffer_max": 0}
    for k, which in enumerate(fixtures):
        with tempfile.TemporaryDirectory() as tmp:
            build = Path(tmp)
            log = build / "qemu-exec.log" if args.profile else None
            ticks, per_drop_ticks, stdout = run(build, extra + which, log)
            if shipped and not same_models(build / "models", SHIPPED):
                print(f"the test image's exported models are not {SHIPPED}'s", file=sys.stderr)
                return 2
            dwt = {m.group(1): int(m.group(2)) for m in re.finditer(r"^DWT (\S+) (\d+)$", stdout, re.M)}
            if log:
                profile(log, build / "test.elf")
            per = 200000 / ticks.pop("calib_200000_instructions")
            ins = {k: round(v * per) for k, v in ticks.items() if k != "empty"}
            for key, vs in per_drop_ticks.items():
                name = key[len("ticks:"):] if key.startswith("ticks:") else key
                per_drop.setdefault(name, []).extend([round(v * per) for v in vs] if key.startswith("ticks:") else vs)
            event_max = max(event_max, ins["event_max_over_drops"])
            for key in app_max:
                app_max[key] = max(app_max[key], ins.get(key, 0))
            sizes = {"models_tables": obj_size(build, "impactsense_forest_tables.o"),
                     "models_m2cgen": obj_size(build, "impactsense_models_m2c.o")}
            export = json.loads((build / "models/export.json").read_text())
            fixture = json.loads((build / "fixture.json").read_text())
            rows += fixture["rows"]
            skipped += fixture.get("skipped_rows", [])
        if len(fixtures) > 1:
            print(f"fixture {k + 1}/{len(fixtures)} (rows {which[1]}): slowest event {ins['event_max_over_drops']:,}",
                  flush=True)
    ins["event_max_over_drops"] = event_max  # the stages above: the last fixture's last capture
    ins.update(app_max)
    print(f"per-event instructions on the Cortex-M4F (qemu -icount), {export['trees']} trees, "
          f"{export['nodes']} nodes")
    print(f"{'stage':<22}{'instructions':>14}{'of 64k':>9}{'flash bytes':>13}")
    for k in ("features", "process_event", "models_tables", "models_m2cgen", "event_total", "event_max_over_drops"):
        print(f"{k:<22}{ins[k]:>14,}{ins[k] / TARGET:>9.2f}{sizes.get(k, 0) or '':>13}")
    ev, fe = np.array(per_drop["event"]), np.array(per_drop["features"])
    print(f"per drop ({len(ev)} drops of {Path(args.data).name if args.data else 'the bundled session'}, rows {rows[0]}..{rows[-1]}"
          f"{'' if args.all else ' evenly spaced'}): whole event "
          f"min {ev.min():,} median {int(np.median(ev)):,} p95 {int(np.percentile(ev, 95)):,} max {ev.max():,}; "
          f"features min {fe.min():,} max {fe.max():,}; the rest (localiser, Eq. 35, vector, models, "
          f"encoding) max {(ev - fe).max():,}; over {TARGET:,}: {(ev > TARGET).sum()} drops")
    if skipped:
        print(f"  not timed: {len(skipped)} drops without a report the models make (rows {skipped[:12]}"
              f"{' ...' if len(skipped) > 12 else ''})")
    if "twin" in per_drop:
        tw, pts = np.array(per_drop["twin"]), np.array(per_drop["twin_points"])
        print(f"  twin fingerprint (twin_features + twin_estimate at the reported position): min {tw.min():,} "
              f"median {int(np.median(tw)):,} max {tw.max():,} instructions; grid points visited "
              f"{pts.min()}..{pts.max()} (site map {export['twin']['grid'][:2]} points, "
              f"{export['table_bytes']['twin']:,} bytes)")
    if len(per_drop.get("left_out", ())) == len(ev):   # the models' check: the channel they left out (4: none)
        lo = np.array(per_drop["left_out"])
        out, kept = ev[lo < 4], ev[lo == 4]
        print(f"  the models left a channel out (twin_match / the three-sensor path) on {out.size} of {len(ev)} drops"
              + (f" ({', '.join(f'channel {c}: {(lo == c).sum()}' for c in range(4) if (lo == c).any())}), whole "
                 f"event median {int(np.median(out)):,} max {out.max():,}" if out.size else "")
              + (f"; the others median {int(np.median(kept)):,} max {kept.max():,}" if kept.size else ""))
    if len(ev) <= 12:
        print("  whole event per drop: " + " / ".join(f"{v:,}" for v in ev))
    worst = np.argsort(ev)[::-1][:3]
    print("  slowest: " + ", ".join(f"row {rows[i]} {ev[i]:,} (features {fe[i]:,}, localiser "
                                      f"{per_drop['localiser_iterations'][i]} iterations)" for i in worst))
    if "models" in per_drop and len(per_drop["models"]) == len(ev):
        # board.cost's parts: the features and report (BASE_INSTRUCTIONS, base_instructions), the localiser, the models
        lo, mo = np.array(per_drop["localiser"]), np.array(per_drop["models"])
        base = ev - lo - mo + max(0, ins["app_event_max"] - event_max)   # the app's own accounting on top
        print(f"  by board.cost's parts: features and report (the event less the localiser and the models; the app's "
              f"accounting on top) max {base.max():,}, localiser max {lo.max():,} "
              f"({max(per_drop['localiser_evaluations'])} evaluations), models max {mo.max():,}")
        est = json.loads((Path(args.export) / "export.json").read_text()).get("event_instructions_estimate") \
            if args.export else None
        if est:   # board.cost fits its base with the localiser's bound (their slowest drops differ): compared together
            signal = (ev - mo + max(0, ins["app_event_max"] - event_max)).max()
            parts = {"the signal (features, report, localiser)": (est["total"] - est["models"], signal),
                     "models": (est["models"], mo.max())}
            print(f"  export's estimate {est['total']:,} against the slowest event {ins['app_event_max']:,}: "
                  f"{'bounds it' if est['total'] >= ins['app_event_max'] else 'UNDER'}; per part (estimate / "
                  f"measured max): " + ", ".join(f"{k} {e:,} / {m:,}{'' if e >= m else ' UNDER'}"
                                                 for k, (e, m) in parts.items()))
    print(f"event_total = process_event (features + physics localiser + Eq. 35 + feature vector) + table models + encoding; "
          f"target {TARGET:,}: {'met' if ins['event_total'] <= TARGET else 'NOT met'} on the last capture, "
          f"{'met' if ins['event_max_over_drops'] <= TARGET else 'NOT met'} on the slowest of {len(ev)} drops")
    idle = ins["app_idle_buffer_max"] / BUFFER_CYCLES
    print(f"the app's own accounting (the status frame's code path; SysTick stands in for the DWT counter qemu "
          f"does not model): slowest event {ins['app_event_max']:,}, slowest buffer without an event "
          f"{ins['app_idle_buffer_max']:,} instructions = {100 * idle:.1f} % of a 5.12 ms buffer at 64 MHz "
          f"(target <= {100 * IDLE_TARGET:.0f} %: {'met' if idle <= IDLE_TARGET else 'NOT met'})")
    if dwt.get("calib_200000_instructions", 0) > 0:
        cpi = dwt["calib_200000_instructions"] / 200000
        print(f"DWT CYCCNT (the board's counter, as the status frame reads it): the last capture's event "
              f"{dwt['event_total']:,} cycles ({cpi:.2f} cycles an instruction on the calibration loop)")
    else:
        print("DWT CYCCNT: not modelled by qemu's mps2-an386 (reads 0 after DEMCR.TRCENA and DWT_CTRL.CYCCNTENA); "
              "the figures are instruction counts (the board's status frame reports cycles: flash wait states "
              "come on top)")
    if args.json:
        Path(args.json).write_text(json.dumps({"instructions": ins, "flash_bytes": sizes, "export": export,
                                               "per_drop": per_drop, "rows": rows, "dwt": dwt,
                                               "model_dir": "shipped" if shipped else args.model_dir,
                                               "data": args.data or "bundled"}, indent=1))
    worst = max(event_max, ins["app_event_max"])
    event_ok, idle_ok = worst <= TARGET, idle <= IDLE_TARGET
    print(f"RESULT slowest event {worst:,} instructions (target <= {TARGET:,}: {'met' if event_ok else 'MISSED'}); "
          f"idle buffer {100 * idle:.1f} % (target <= {100 * IDLE_TARGET:.0f} %: {'met' if idle_ok else 'MISSED'})")
    return 0 if event_ok and idle_ok else 1


if __name__ == "__main__":
    sys.exit(main())
