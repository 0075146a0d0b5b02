"""What a command would take on two idle cores, measured on a shared machine (issue 20's cold chain).

`traced_run(cmd, log)` runs the command and samples its process tree every `period` seconds (Linux /proc):
each thread's user + system CPU ticks and whether it is runnable (state R). Between two samples the tree did
dCPU of work with d threads wanting a core (runnable at either sample, or gaining CPU in between); on `cores`
idle cores that slice takes dCPU / min(d, cores). Summed over the run this is the idle wall estimate: the
machine's other load stretches the slices but does not change how many of the command's threads want a core,
so the estimate depends on the command's own parallelism, not on the load (a thread waiting for Python's GIL
sleeps, state S, and is not counted). The ratio CPU / estimate is the cores the command keeps busy (<= cores).
"""

from __future__ import annotations

import os
import resource
import subprocess
import time
from pathlib import Path

TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def _stat_fields(path: str):
    """(state, ppid, utime + stime ticks) from a /proc stat file, or None when it is gone."""
    try:
        with open(path) as fh:
            s = fh.read()
    except OSError:
        return None
    rest = s[s.rfind(")") + 2:].split()
    return rest[0], int(rest[1]), int(rest[11]) + int(rest[12])


def _tree(root: int) -> list[int]:
    """root and its descendant processes (each thread's /proc children list: reading every process of the
    machine instead cost ~2 ms a sample, ~4 % of a core at 20 samples a second, taken from the command traced)."""
    out, todo = [], [root]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            tids = os.listdir(f"/proc/{p}/task")
        except OSError:
            continue
        for tid in tids:
            try:
                with open(f"/proc/{p}/task/{tid}/children") as fh:
                    todo.extend(int(c) for c in fh.read().split())
            except OSError:
                pass
    return out


def _sample(root: int) -> dict:
    """{(pid, tid): (runnable, ticks)} over root's tree."""
    out = {}
    for pid in _tree(root):
        try:
            tids = os.listdir(f"/proc/{pid}/task")
        except OSError:
            continue
        for tid in tids:
            f = _stat_fields(f"/proc/{pid}/task/{tid}/stat")
            if f:
                out[(pid, int(tid))] = (f[0] == "R", f[2])
    return out


def _children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def idle_wall(samples: list[dict], cores: int = 2, series: list | None = None) -> tuple[float, float]:
    """(CPU s seen, idle wall estimate s) from successive samples (module doc); `series` (a list) gets each
    slice's (CPU s, threads wanting a core, threads runnable at its two ends averaged)."""
    cpu = est = 0.0
    for a, b in zip(samples, samples[1:]):
        d_cpu, wanting = 0, 0
        for k, (run_b, t_b) in b.items():
            t_a = a[k][1] if k in a else 0
            gained = t_b - t_a
            d_cpu += gained
            if gained > 0 or run_b or (k in a and a[k][0]):
                wanting += 1
        for k, (run_a, t_a) in a.items():      # gone before the second sample: its last CPU is not seen
            if k not in b and run_a:
                wanting += 1
        if series is not None:
            series.append((d_cpu * TICK_S, wanting, runnable_between(a, b)))
        if d_cpu:
            cpu += d_cpu * TICK_S
            est += d_cpu * TICK_S / min(max(wanting, 1), cores)
    return cpu, est


def runnable_between(a: dict, b: dict) -> float:
    """Threads runnable (state R) at the two samples, averaged: the threads that wanted a core at once. A thread
    waiting for Python's GIL sleeps, so two threads taking turns at the GIL count once here, where `idle_wall`'s
    `wanting` (runnable or gaining CPU in the slice) counts both."""
    return 0.5 * (sum(r for r, _ in a.values()) + sum(r for r, _ in b.values()))


def runnable_wall(series: list, cores: int = 2) -> float:
    """The idle wall estimate with each slice's demand the threads runnable at its ends (`runnable_between`,
    at least 1 when the slice did work): GIL-bound threads side by side count as the one core they use."""
    return sum(c / min(max(r, 1.0), cores) for c, _, r in series if c)


def traced_run(cmd: list[str], log: Path, env: dict | None = None, period: float = 0.05,
               cores: int = 2, series_path: Path | None = None) -> dict:
    """Runs `cmd` (output appended to `log`) under the sampler: wall s, CPU s seen by the sampler, the idle wall
    estimate on `cores` cores and the busy-cores ratio; series_path: each slice's (wall s since the start, CPU s,
    threads wanting a core) as text (cpu_s: user + sys of the command and its workers, by
    rusage). RuntimeError naming the log when it fails."""
    t0, c0 = time.perf_counter(), _children_cpu_s()
    samples, stamps = [], []
    with open(log, "a") as fh:
        fh.write("$ " + " ".join(cmd) + "\n")
        fh.flush()
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env)
        while proc.poll() is None:
            samples.append(_sample(proc.pid))
            stamps.append(time.perf_counter() - t0)
            time.sleep(period)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}); see {log}")
    series: list = []
    cpu, est = idle_wall(samples, cores, series)
    if series_path is not None:
        Path(series_path).write_text("".join(f"{t:.3f} {c:.2f} {n} {r:.1f}\n"
                                             for t, (c, n, r) in zip(stamps[1:], series)))
    return {"wall_s": wall, "cpu_s": _children_cpu_s() - c0, "traced_cpu_s": cpu, "idle_wall_estimate_s": est,
            "busy_cores": cpu / est if est else 0.0, "runnable_wall_estimate_s": runnable_wall(series, cores)}
