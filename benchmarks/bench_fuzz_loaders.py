"""Fuzz the Python loaders (session npz/CSV/rig JSON, model folders, CAL.json) with random corruptions.

Each case corrupts one file of a small valid session or model folder (flipped/inserted/deleted bytes, a cut,
a replaced field, a huge number, deep nesting, an invalid UTF-8 byte, a forest file rewritten with broken
node arrays and its checksum updated) and runs the loader the CLI runs (load_session, ImpactModel.load,
export.load_models, read_json + the --exclude parser) the way the CLI does: an ImpactSenseError is exit 2
(a clear error), success is exit 0 and must give what the file says (as many drops as impacts.csv has rows,
forests whose predictions are finite); anything else (another exception) counts as a traceback. Every case
runs in this process; a crash (segfault) ends the run and the caller sees it.

    python3 benchmarks/bench_fuzz_loaders.py --n 10000      # prints the counts; exit 1 if any traceback

Target: 0 tracebacks over 10,000 cases.
"""

from __future__ import annotations

import argparse
import io
import json
import random
import shutil
import sys
import tempfile
import traceback
from pathlib import Path

import numpy as np


def make_fixtures(root: Path, n_drops: int = 24, trees: int = 3):
    """A small session (the bundled session's first drops) and a model folder trained on it."""
    from impactsense.data import load_session, write_session
    from impactsense.models import ForestSettings
    from impactsense.workflow import train

    s = load_session("bundled:session-1")
    rows = np.arange(n_drops)
    sess = write_session(root / "session", s.rig, s.x_mm[rows], s.y_mm[rows], s.height_mm[rows], s.adc[rows],
                         s.case_id[rows], s.repetition[rows])
    small = load_session(sess)
    train(small, root / "model", 0.25, 0, settings=ForestSettings(n_estimators=trees))
    return sess, root / "model"


def corrupt_bytes(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    kind = rng.choice(["flip", "flip", "cut", "insert", "delete", "zero", "utf8"])
    if not b:
        return bytes(rng.getrandbits(8) for _ in range(8))
    if kind == "flip":
        for _ in range(rng.choice([1, 1, 2, 8, 200])):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
    elif kind == "cut":
        b = b[:rng.randrange(len(b))]
    elif kind == "insert":
        i = rng.randrange(len(b) + 1)
        b[i:i] = bytes(rng.getrandbits(8) for _ in range(rng.randrange(1, 64)))
    elif kind == "delete":
        i = rng.randrange(len(b))
        del b[i:i + rng.randrange(1, 64)]
    elif kind == "zero":
        i = rng.randrange(len(b))
        b[i:i + 256] = bytes(min(256, len(b) - i))
    else:
        b[rng.randrange(len(b))] = 0xFF
    return bytes(b)


def mutate_json(obj, rng: random.Random):
    """A structural mutation of a JSON document: a value replaced by a wrong type, a huge or non-finite
    number, deep nesting, or a key removed."""
    doc = json.loads(json.dumps(obj))
    paths = []

    def walk(o, path):
        paths.append(path)
        if isinstance(o, dict):
            for k, v in o.items():
                walk(v, path + [k])
        elif isinstance(o, list):
            for i, v in enumerate(o[:6]):
                walk(v, path + [i])

    walk(doc, [])
    path = rng.choice(paths[1:] or [[]])
    replacement = rng.choice([None, "text", -1, 0, 10 ** 30, 1e308, [], {}, [1, 2], True, 3.5, -1e-9,
                              "../../etc/passwd", "/abs/forest_dx.joblib", "x" * 1000])
    if rng.random() < 0.05:
        return "[" * 100000 + "]" * 100000
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    if path and isinstance(parent, dict) and rng.random() < 0.3:
        parent.pop(path[-1], None)
    elif path:
        parent[path[-1]] = replacement
    else:
        doc = replacement
    return json.dumps(doc)


def broken_forest(path: Path, rng: random.Random) -> bytes:
    """The forest file with one node array damaged (its values, dtype or length), as valid npz."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    key = rng.choice([k for k in arrays if k != "meta"] + ["meta"])
    a = arrays[key]
    how = rng.choice(["value", "dtype", "length", "meta"]) if key != "meta" else "meta"
    if how == "value" and a.size:
        a = a.copy()
        value = rng.choice([-5, 10 ** 6, -1, 0, 2 ** 31 - 1]) if a.dtype.kind in "iu" else \
            rng.choice([np.nan, np.inf, -1e300, 0.0])
        try:
            a.flat[rng.randrange(a.size)] = value
        except (ValueError, OverflowError):
            a.flat[rng.randrange(a.size)] = 0
    elif how == "dtype":
        a = a.astype(rng.choice([np.float32, np.int8, np.uint64, np.bool_]))
    elif how == "length":
        a = a[: max(0, a.shape[0] - rng.randrange(1, 4))] if a.ndim else a
    else:
        meta = json.loads(str(arrays["meta"]))
        a = np.array(mutate_json(meta, rng))
        key = "meta"
    arrays[key] = a
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def run_case(case: int, sess: Path, model: Path, work: Path, rng: random.Random) -> str:
    """'ok', 'error' (exit 2) or 'traceback'."""
    import hashlib

    from impactsense.commands.train import parse_exclude
    from impactsense.data import load_session
    from impactsense.errors import ImpactSenseError
    from impactsense.export import load_models
    from impactsense.models import ImpactModel

    target_kind = rng.choice(["npz", "csv", "rig", "card", "forest", "forest_rehash", "cal"])
    s2, m2 = work / f"s{case}", work / f"m{case}"
    shutil.copytree(sess, s2)
    shutil.copytree(model, m2)
    try:
        if target_kind == "npz":
            p = s2 / "recordings.npz"
            p.write_bytes(corrupt_bytes(p.read_bytes(), rng))
        elif target_kind == "csv":
            p = s2 / "impacts.csv"
            text = p.read_bytes()
            if rng.random() < 0.3:
                lines = text.split(b"\n")
                i = rng.randrange(1, max(2, len(lines) - 1))
                cells = lines[i].split(b",")
                cells[rng.randrange(len(cells))] = rng.choice([b"1" * 31, b"-1", b"nan", b"inf", b"", b"1e999",
                                                               b"\xff\xfe", b"3.5", b"x"])
                lines[i] = b",".join(cells)
                text = b"\n".join(lines)
            else:
                text = corrupt_bytes(text, rng)
            p.write_bytes(text)
        elif target_kind == "rig":
            p = s2 / "rig.json"
            if rng.random() < 0.6:
                p.write_text(mutate_json(json.loads(p.read_text()), rng))
            else:
                p.write_bytes(corrupt_bytes(p.read_bytes(), rng))
        elif target_kind == "card":
            p = m2 / "model_card.json"
            if rng.random() < 0.7:
                p.write_text(mutate_json(json.loads(p.read_text()), rng))
            else:
                p.write_bytes(corrupt_bytes(p.read_bytes(), rng))
        elif target_kind in ("forest", "forest_rehash"):
            name = rng.choice(["forest_dx.npz", "forest_dy.npz", "forest_energy.npz"])
            p = m2 / name
            data = broken_forest(p, rng) if target_kind == "forest_rehash" and rng.random() < 0.7 else \
                corrupt_bytes(p.read_bytes(), rng)
            p.write_bytes(data)
            if target_kind == "forest_rehash":   # the checksum updated: the structure checks must hold
                card = json.loads((m2 / "model_card.json").read_text())
                card["sha256"][name] = hashlib.sha256(data).hexdigest()
                (m2 / "model_card.json").write_text(json.dumps(card))
        else:
            p = work / f"cal{case}.json"
            p.write_text(mutate_json({"drops": [0, 1, 2, 3], "sim_params": {}}, rng))
        try:
            if target_kind in ("npz", "csv", "rig"):
                s = load_session(s2)
                n_rows = (s2 / "impacts.csv").read_text().strip().count("\n")
                if len(s) != n_rows:
                    return "traceback"   # loaded, but not what the file says
            elif target_kind == "cal":
                from impactsense.checks import exclude_rows

                exclude_rows(parse_exclude(str(p)), load_session(sess), "--exclude")
            else:
                model_obj = ImpactModel.load(m2)
                load_models(m2)
                x = np.random.default_rng(case).normal(size=(5, model_obj.forest_dx.n_features_in_))
                if not np.isfinite(model_obj.forest_dx.predict(x)).all():
                    return "traceback"
            return "ok"
        except ImpactSenseError:
            return "error"
    except Exception:  # noqa: BLE001  (what the fuzz counts)
        if "--verbose" in sys.argv:
            traceback.print_exc()
        return "traceback"
    finally:
        shutil.rmtree(s2, ignore_errors=True)
        shutil.rmtree(m2, ignore_errors=True)


def fuzz(n: int, seed: int = 0, root: Path | None = None) -> dict:
    own = root is None
    root = Path(tempfile.mkdtemp(prefix="impactsense-fuzz-")) if own else root
    try:
        sess, model = make_fixtures(root)
        work = root / "work"
        work.mkdir()
        rng = random.Random(seed)
        counts = {"ok": 0, "error": 0, "traceback": 0}
        for case in range(n):
            counts[run_case(case, sess, model, work, rng)] += 1
        return counts
    finally:
        if own:
            shutil.rmtree(root, ignore_errors=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--verbose", action="store_true", help="print each traceback")
    args = ap.parse_args()
    counts = fuzz(args.n, args.seed)
    print(f"fuzzed inputs: {args.n}; exit 0: {counts['ok']}, exit 2: {counts['error']}, "
          f"tracebacks: {counts['traceback']} (target 0)")
    return 0 if counts["traceback"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
