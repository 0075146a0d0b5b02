"""Host link benchmarks: emulator throughput over all session-1 drops vs real time (target >= 100x), and
the C++ stream decoder over 1e6 fuzzed frames (random, truncated, corrupted, intact).

The emulator's throughput is read on the process's CPU time (one thread: the resampling and the firmware app),
which the machine's other work does not inflate; the wall-clock figure is printed beside it.

    python benchmarks/bench_link.py [--frames 1000000] [--trees 30]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from impactsense import _core  # noqa: F401
from impactsense import _link
from impactsense.data import load_session
from impactsense.export import export_models, firmware_models
from impactsense.board.models import train_board_models
from impactsense.link.emulator import Emulator


def bench_emulator(trees: int) -> dict:
    s = load_session()
    with tempfile.TemporaryDirectory() as tmp:
        model_dir = train_board_models(s, Path(tmp) / "m", n_trees=trees)
        export_models(model_dir, Path(tmp) / "out", write_m2cgen=False)
        models, signal = firmware_models(Path(tmp) / "out")
    w0, t0 = time.perf_counter(), time.process_time()
    emu = Emulator(s, models, signal=signal)
    _ = emu.frames
    t1 = time.process_time()
    dec = _link.Decoder()
    reports = 0
    for _, data in emu.drops():
        reports += dec.count(data)["reports"]
    w2, t2 = time.perf_counter(), time.process_time()
    real = emu.real_time_s()
    return {"drops": len(s), "reports": reports, "real_time_s": real, "resample_s": t1 - t0, "app_s": t2 - t1,
            "x_real_time": real / (t2 - t0), "x_real_time_app_only": real / (t2 - t1), "wall_s": w2 - w0,
            "x_real_time_wall": real / (w2 - w0)}


def fuzz_stream(n_frames: int, seed: int = 0) -> tuple[bytes, int]:
    rng = np.random.default_rng(seed)
    base = [_link.encode_report(dict(seq=i, x_mm=float(i % 320), y_mm=float(i % 317), order=[0, 1, 2, 3]))
            for i in range(4096)]
    parts, intact = [], 0
    kinds = rng.integers(0, 4, n_frames)
    for i, k in enumerate(kinds):
        f = base[i % 4096]
        if k == 0:
            parts.append(f)
            intact += 1
        elif k == 1:
            b = bytearray(f)
            b[int(rng.integers(0, len(b)))] ^= 1 << int(rng.integers(0, 8))
            parts.append(bytes(b))
        elif k == 2:
            parts.append(f[: int(rng.integers(1, len(f)))])
        else:
            parts.append(rng.integers(0, 256, len(f), dtype=np.uint8).tobytes())
    return b"".join(parts), intact


def bench_decoder(n_frames: int) -> dict:
    stream, intact = fuzz_stream(n_frames)
    dec = _link.Decoder()
    t0 = time.perf_counter()
    got = dec.count(stream)
    dt = time.perf_counter() - t0
    # Second pass with objects: every report out must be one that was sent (seq, x, y as encoded).
    false = sum(1 for f in _link.Decoder().feed(stream)
                if (f["report"]["x_mm"], f["report"]["y_mm"]) != (float(f["report"]["seq"] % 320),
                                                                  float(f["report"]["seq"] % 317)))
    return {"frames_fuzzed": n_frames, "bytes": len(stream), "intact_sent": intact, "reports_out": got["reports"],
            "false_reports": false, "errors": dec.errors, "s": dt, "mb_per_s": len(stream) / dt / 1e6,
            **dec.stats}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--trees", type=int, default=30)
    args = ap.parse_args()
    e = bench_emulator(args.trees)
    print(f"emulator: {e['reports']} reports from {e['drops']} drops; {e['real_time_s']:.1f} s of board time in "
          f"{e['resample_s']:.2f} s resampling + {e['app_s']:.2f} s firmware app (CPU) -> {e['x_real_time']:.0f}x real "
          f"time ({e['x_real_time_app_only']:.0f}x for the app alone; target >= 100x); wall {e['wall_s']:.2f} s, "
          f"{e['x_real_time_wall']:.0f}x (the machine's load)")
    d = bench_decoder(args.frames)
    print(f"decoder: {d['frames_fuzzed']:,} fuzzed frames ({d['bytes'] / 1e6:.1f} MB) in {d['s']:.2f} s "
          f"({d['mb_per_s']:.1f} MB/s); {d['reports_out']:,} reports out ({d['intact_sent']:,} sent intact; a truncated "
          f"frame is now and then completed by the bytes that follow), false reports {d['false_reports']}; "
          f"errors {d['errors']:,} (crc {d['crc_errors']:,}, length {d['length_errors']:,}, "
          f"version {d['version_errors']:,}, type {d['type_errors']:,}, payload {d['payload_errors']:,})")
    ok = d["false_reports"] == 0 and e["x_real_time"] >= 100
    print("targets (emulator >= 100x real time, 0 false reports): " + ("met" if ok else "MISSED"))
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
