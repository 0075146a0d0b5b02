"""The PlatformIO monitor filter (monitor/filter_impactsense.py) decodes what the emulated board sends, with
the host's own decoder and line formats: the lines `impactsense monitor` prints, for every report and status
frame, however the serial bytes are split between rx() calls.

PlatformIO is not a test dependency: when it is absent, the filter's one import from it
(platformio.public.DeviceMonitorFilterBase) is given a stand-in base class with the same constructor."""

import importlib.util
import sys
import types
from pathlib import Path

import numpy as np

from impactsense.data import load_session
from impactsense.link import monitor
from impactsense.link.emulator import Emulator
from impactsense.link.protocol import Decoder

ROOT = Path(__file__).resolve().parents[1]


def load_filter():
    try:
        import platformio.public  # noqa: F401
    except ImportError:
        pio = types.ModuleType("platformio")
        public = types.ModuleType("platformio.public")

        class DeviceMonitorFilterBase:  # the constructor PlatformIO's base has (options, project dir, env)
            def __init__(self, options=None, *args, **kwargs):
                self.options = options

        public.DeviceMonitorFilterBase = DeviceMonitorFilterBase
        pio.public = public
        sys.modules.setdefault("platformio", pio)
        sys.modules.setdefault("platformio.public", public)
    spec = importlib.util.spec_from_file_location("filter_impactsense", ROOT / "monitor" / "filter_impactsense.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.Impactsense


def test_filter_prints_the_monitor_lines_for_the_emulators_bytes():
    s = load_session("bundled").subset(np.arange(0, 60))
    emu = Emulator(s, None, fs_hz=50000)
    data = b"".join(emu.stream()) + emu.app.pull(1 << 20)
    frames = Decoder().feed(data)
    want = [monitor.report_line(f["report"]) if f["kind"] == "report" else monitor.status_line(f["status"])
            for f in frames if f["kind"] in ("report", "status")]
    assert sum(f["kind"] == "report" for f in frames) == 60 and any(f["kind"] == "status" for f in frames)

    filt = load_filter()()
    rng = np.random.default_rng(0)
    text, i = "", 0
    while i < len(data):  # arbitrary splits, through latin-1 as PlatformIO's monitor_encoding hands them over
        n = int(rng.integers(1, 200))
        text += filt.rx(data[i:i + n].decode("latin-1"))
        i += n
    lines = text.splitlines()
    assert lines[0] == monitor.REPORT_HEADER or lines[0].startswith("status")
    assert [ln for ln in lines if ln != monitor.REPORT_HEADER] == want
    assert filt.tx("x") == "x"


def test_filter_without_the_host_package_says_so_and_shows_hex():
    f = load_filter()()
    f._decoder, f._error = None, ImportError("no impactsense")  # as when neither import path works
    out = f.rx(b"\xa5\x5a\x01".decode("latin-1"))
    assert "cannot import impactsense" in out and out.endswith("a5 5a 01\n")
    assert f.rx("\x00") == "00\n"  # the note comes once
