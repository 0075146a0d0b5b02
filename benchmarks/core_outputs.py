"""The core's outputs (`_core.process_batch`) on sessions, at the host's rate and on the emulated board's captures,
saved to an npz; or two such files compared array by array (bit for bit, NaN equal to NaN). For a core change
that must not move any output (a cheaper event): save before the change, rebuild, save again, compare.

    python benchmarks/core_outputs.py save OUT.npz --run DATA MODEL_DIR [--run DATA MODEL_DIR ...]
    python benchmarks/core_outputs.py compare A.npz B.npz

MODEL_DIR is a host model (`impactsense train`): its card's signal is used at the host's rate; the board's
captures and signal are those of MODEL_DIR/../export/board-model when that exists (`impactsense export`), else
the board's defaults for the model's signal. Exit 1 when any array differs.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def save(out: str, runs: list[list[str]]) -> None:
    from impactsense import _core
    from impactsense.board.capture import board_captures
    from impactsense.data import load_session
    from impactsense.pipeline import as_int16
    from impactsense.signal import SignalConfig

    res = {}
    for data, mdir in runs:
        card = json.loads((Path(mdir) / "model_card.json").read_text())
        board = Path(mdir).parent / "export" / "board-model" / "model_card.json"
        bcard = json.loads(board.read_text()) if board.exists() else card
        s = load_session(data)
        name = Path(data).name
        host_cfg = SignalConfig.from_dict(card["signal"])
        caps, _, board_cfg = board_captures(s, int(bcard.get("board_fs_hz", 50000)), bcard["signal"])
        for tag, x, cfg in (("host", s.adc, host_cfg), ("board", caps, board_cfg)):
            pe = _core.process_batch(as_int16(x, cfg)[..., : _core.MAX_SAMPLES], cfg.core(), cfg.localiser())
            for k, v in pe.items():
                a = np.asarray(v)
                if k not in ("work", "work_fields") and a.dtype.kind in "fiub":
                    res[f"{name}-{tag}:{k}"] = a
            print(f"{name}-{tag}: {x.shape[0]} drops, localiser evaluations max {int(np.max(pe['localiser_evaluations']))}")
    np.savez(out, **res)


def compare(a_path: str, b_path: str) -> int:
    a, b = np.load(a_path), np.load(b_path)
    if set(a.files) != set(b.files):
        print("different arrays:", sorted(set(a.files) ^ set(b.files)))
        return 1
    bad = [k for k in sorted(a.files) if not np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f")]
    print(f"{len(a.files)} arrays; differing: {bad or 'none'}")
    return 1 if bad else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("save")
    s.add_argument("out")
    s.add_argument("--run", nargs=2, action="append", required=True, metavar=("DATA", "MODEL_DIR"))
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args()
    if args.cmd == "save":
        save(args.out, args.run)
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
