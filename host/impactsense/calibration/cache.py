"""The calibration's stage caches: JSON results next to CAL.json, each under the key of the inputs that
determine it (an interrupted run resumes; a finished one is not recomputed), and the stage clock."""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..outputs import write_file
from .fem import MODEL_FIELDS


def key(*parts) -> str:
    """A short hash of the JSON of `parts` (numbers, dicts, lists; anything else by its str)."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def model_key(params: dict) -> tuple:
    """Parts for a cache key: the MODEL_FIELDS present in params, as (name, value) pairs."""
    return tuple((k, params[k]) for k in MODEL_FIELDS if k in params)


def jsonable(o):
    """json.dumps default: numpy arrays and scalars as Python lists and numbers."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.bool_):
        return bool(o)
    raise TypeError(type(o))


def as_json(obj):
    """obj as it reads back from JSON (numpy values as Python's)."""
    return json.loads(json.dumps(obj, default=jsonable))


def write_json(path: Path, obj: dict) -> None:
    """Write obj as indented JSON, atomically (outputs.write_file)."""
    write_file(path, json.dumps(obj, indent=1, default=jsonable) + "\n")


def read(path: Path, stage_key: str):
    """The JSON at path if it was written under stage_key, else None."""
    if path.exists():
        try:
            obj = json.loads(path.read_text())
            if obj.get("key") == stage_key:
                return obj
        except (OSError, ValueError):
            pass
    return None


def cached(path: Path, stage_key: str, compute) -> dict:
    """compute() once; its JSON result kept at path under stage_key."""
    hit = read(path, stage_key)
    if hit is not None:
        hit.pop("key")
        return hit
    out = as_json(compute())
    write_json(path, {"key": stage_key, **out})
    return out


@dataclass
class StageClock:
    """Wall seconds per stage name, in the order the stages ran, and CPU seconds (user + sys of this process's
    threads and of its finished child processes, `cpu_seconds`): on a shared machine the wall clock counts the
    other processes' load, the CPU time does not."""

    seconds: dict = field(default_factory=dict)
    cpu: dict = field(default_factory=dict)

    def run(self, name, fn, *a, **k):
        t, c = time.perf_counter(), cpu_seconds()
        res = fn(*a, **k)
        self.seconds[name] = round(time.perf_counter() - t, 3)
        self.cpu[name] = round(cpu_seconds() - c, 2)
        return res


def cpu_seconds() -> float:
    """User + system CPU seconds of this process (all its threads) and its reaped child processes."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def record_compute_times(path: Path, seconds: dict) -> dict:
    """The time each stage took when it was last computed (a stage read from its cache takes ~0 s this run):
    merged into the JSON at path and returned with their sum."""
    compute = {}
    if path.exists():
        try:
            compute = json.loads(path.read_text())
        except ValueError:
            compute = {}
    for stage, sec in seconds.items():
        if stage != "total" and (sec > 0.5 or stage not in compute):
            compute[stage] = sec
    compute.pop("total", None)
    write_json(path, compute)
    return {**compute, "sum": round(sum(compute.values()), 3)}
