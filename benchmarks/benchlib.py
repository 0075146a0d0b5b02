"""Helpers the benchmark scripts share (imported from their folder: `python3 benchmarks/NAME.py` puts it on
sys.path)."""

from __future__ import annotations

import json
import resource
import subprocess
import time
from pathlib import Path


def children_cpu_s(include_self: bool = False) -> float:
    """User + system CPU seconds of the finished child processes (the machine's load does not inflate it);
    with include_self, this process's own (all its threads) too."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    own = resource.getrusage(resource.RUSAGE_SELF) if include_self else None
    return r.ru_utime + r.ru_stime + (own.ru_utime + own.ru_stime if own else 0.0)


def run_logged(cmd: list[str], log: Path, env: dict | None = None) -> tuple[float, float]:
    """Runs one command (in `env`, default this process's environment), its output appended to `log`: (wall s,
    CPU s of it and its workers). RuntimeError naming the log when it fails."""
    t0, c0 = time.perf_counter(), children_cpu_s()
    with open(log, "a") as fh:
        fh.write("$ " + " ".join(cmd) + "\n")
        fh.flush()
        res = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({res.returncode}); see {log}")
    return time.perf_counter() - t0, children_cpu_s() - c0


def misses_exit_code(misses: list[str]) -> int:
    """Prints the missed targets, one a line: 1 when one was missed, else 0 ("all targets met")."""
    if misses:
        print("MISSED TARGETS:\n  " + "\n  ".join(misses))
        return 1
    print("all targets met")
    return 0


def targets_exit_code(misses: list[str], no_targets: bool, t0: float) -> int:
    """Prints the run's time (since time.time() t0) and the missed targets: 1 when one was missed (0 with
    --no-targets, the misses still counted), else 0."""
    print(f"({time.time() - t0:.0f} s)")
    if misses and no_targets:
        print(f"{len(misses)} targets missed (--no-targets)")
        return 0
    return misses_exit_code(misses)


def distinct_sessions(paths, what: str = "measured"):
    """The session folders of `paths` whose data differ (by the session's fingerprint), in order; a folder with
    the same data as one before it (e.g. a copy of the bundled session) is skipped with a line saying so."""
    from impactsense.data import load_session

    seen = set()
    for path in paths:
        digest = load_session(path).fingerprint()
        if digest in seen:
            print(f"{path}: skipped, the same data as a session already {what}")
            continue
        seen.add(digest)
        yield path


def write_json(path, result) -> None:
    """Writes a benchmark's result dict to `path` (its --json option) when one is given."""
    if path:
        with open(path, "w") as fh:
            json.dump(result, fh, indent=1)


def rig_study_args(description: str, argv=None):
    """The arguments every per-rig study takes: --rigs-dir, --seeds, --json, --skip-bundled."""
    import argparse

    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--rigs-dir", default=None)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--json", default=None)
    ap.add_argument("--skip-bundled", action="store_true", help="only the other rigs")
    return ap.parse_args(argv)


def rig_study_sessions(args):
    """The bundled session (unless --skip-bundled) and each rig folder under --rigs-dir, the same data once."""
    from bench_rigs import rig_folders

    folders, why = rig_folders(args.rigs_dir)
    if why:
        print(f"other rigs skipped: {why}")
    return distinct_sessions([*([] if args.skip_bundled else ["bundled"]), *map(str, folders)])


def chain_model_rows(data: str, model_path: str):
    """(session, model, the rows that are not the chain's calibration drops) of a zero-shot chain's model, or
    None (after saying so) when the model's card names no calibration."""
    import numpy as np

    from impactsense.data import load_session
    from impactsense.models import ImpactModel
    from impactsense.zeroshot import calibration_rows

    session, model = load_session(data), ImpactModel.load(model_path)
    cal_path = model.card.get("calibration")
    if not cal_path:
        print(f"{model_path}: not a chain's model (its card names no calibration)")
        return None
    calibration = calibration_rows(session, json.loads(Path(cal_path).read_text()))
    return session, model, np.setdiff1d(np.arange(len(session)), calibration), calibration


def sized_bond(sessions: str, name: str, seed: int):
    """(reference, the bond session, diagnose's details, its effects with the bond sized on the recordings
    (loop.fit_bond), the weak channel or -1). Prints and gives channel -1 when no bond was sized."""
    from impactsense.data import load_session
    from impactsense.diagnose import diagnose
    from impactsense.loop import fit_bond, weak_channel

    ref, sess = load_session(Path(sessions) / "ref"), load_session(Path(sessions) / name)
    _, det = diagnose(ref, sess, same=False)
    accepted = fit_bond(ref, sess, det["accepted"], seed)
    channel = weak_channel(accepted)
    if channel < 0:
        print(f"{name}: no bond sized (effects {[(c.effect, c.sensor) for c in accepted]})")
    return ref, sess, det, accepted, channel
