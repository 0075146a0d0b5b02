"""The core's per-event work counters (impactcore.h WorkCounts; _core.process_batch's "work"): counted on the host's
build only, zeroed for each event, and counting what they name (benchmarks/bench_signal_work.py fits the board's
per-drop signal cost on them)."""

from pathlib import Path

import numpy as np

from impactsense import _core
from impactsense.data import load_session
from impactsense.pipeline import as_int16
from impactsense.signal import SignalConfig

ROOT = Path(__file__).resolve().parents[1]


def _work(adc, cfg):
    out = _core.process_batch(adc, cfg.core(), cfg.localiser())
    return np.asarray(out["work"]), list(out["work_fields"])


def test_a_modelled_hum_and_the_peak_scan_are_counted_per_event():
    """A 50 Hz hum of 60 counts added to one channel of clean drops is modelled on that channel alone (hum_channels
    0 -> 1 on every drop, its fit counted); every channel is passed once, the peak scan reads at least the crossing's
    blocks and never more than the capture has; a batch's row counts what the same drop alone counts."""
    s = load_session(None)
    cfg = SignalConfig.for_rig(s.rig)
    adc = as_int16(s.adc[:12], cfg)
    clean, fields = _work(adc, cfg)
    col = {f: j for j, f in enumerate(fields)}
    assert {"peak_blocks", "hum_fits", "hum_channels", "spike_hunts", "channel_passes"} <= set(col)
    n = adc.shape[-1]
    assert (clean[:, col["hum_channels"]] == 0).all() and (clean[:, col["channel_passes"]] == 4).all()
    assert (clean[:, col["peak_blocks"]] >= 4).all() and (clean[:, col["peak_blocks"]] <= 4 * (n // 16 + 1)).all()   # kBlock 16
    t = np.arange(n) / s.rig.fs_hz
    hum = adc.astype(np.int32)
    hum[:, 1] += np.round(60 * np.sin(2 * np.pi * 50 * t + 0.3)).astype(np.int32)
    hummed, _ = _work(np.clip(hum, -32768, 32767).astype(np.int16), cfg)
    assert (hummed[:, col["hum_channels"]] == 1).all()
    assert (hummed[:, col["hum_fits"]] >= 1).all()
    alone, _ = _work(adc[5:6], cfg)
    np.testing.assert_array_equal(alone[0], clean[5])


def test_the_boards_build_does_not_count():
    """Only the host binding's CMake defines IMPACTCORE_WORK_COUNTS: the board's and the qemu image's builds compile
    the core without the counters (IC_WORK is ((void)0) there), so the board's code and cost are unchanged."""
    defines = [p.relative_to(ROOT).as_posix() for p in ROOT.glob("**/*")
               if p.is_file() and p.suffix in {".cmake", ".txt", ".ini", ".sh", ".py", ".json", ".cpp", ".h"}
               and not any(part.startswith(".") or part in {"build", "tests"} for part in p.relative_to(ROOT).parts)
               and "IMPACTCORE_WORK_COUNTS" in p.read_text(errors="ignore")]
    assert "host/bindings/core.cmake" in defines
    assert all(d in {"host/bindings/core.cmake", "firmware/lib/impactcore/src/impactcore.h",
                     "firmware/lib/impactcore/src/event.cpp"} for d in defines), defines
    header = (ROOT / "firmware/lib/impactcore/src/impactcore.h").read_text()
    assert "#define IC_WORK(field, n) ((void)0)" in header
