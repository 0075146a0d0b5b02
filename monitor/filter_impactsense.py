"""`pio device monitor` filter: the board's binary frames as the lines `impactsense monitor` prints.

PlatformIO loads filters from the project's `monitor/` folder (platformio.ini: monitor_filters = impactsense,
monitor_encoding = latin-1 so every byte reaches the filter as one character). The decoding is the host's:
the C++ decoder (firmware/lib/impactlink through `impactsense._link`) and `impactsense.link.monitor`'s line
formats, imported from the installed package or, failing that, from this repository's `host/` (the package
must have been built there: `pip install -e .`). Without it the filter says so once and shows hex.
"""

import sys
from pathlib import Path

from platformio.public import DeviceMonitorFilterBase


def _host():
    try:
        from impactsense.link import monitor, protocol
    except ImportError:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "host"))
        try:
            from impactsense.link import monitor, protocol
        except ImportError as exc:
            return None, exc
    return (monitor, protocol), None


class Impactsense(DeviceMonitorFilterBase):
    NAME = "impactsense"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._host, self._error = _host()
        self._decoder = self._host[1].Decoder() if self._host else None
        self._header = False
        self._warned = False

    def rx(self, text):
        data = text.encode("latin-1", errors="replace")
        if self._decoder is None:
            note = "" if self._warned else f"[impactsense filter: cannot import impactsense ({self._error}); hex]\n"
            self._warned = True
            return note + data.hex(" ") + "\n"
        monitor = self._host[0]
        lines = []
        for frame in self._decoder.feed(data):
            kind = frame["kind"]
            if kind == "report":
                if not self._header:
                    lines.append(monitor.REPORT_HEADER)
                    self._header = True
                lines.append(monitor.report_line(frame["report"]))
            elif kind == "status":
                lines.append(monitor.status_line(frame["status"]))
            elif kind == "ack":
                lines.append("ack " + " ".join(f"{k}={v}" for k, v in sorted(frame["ack"].items())))
        return "".join(line + "\n" for line in lines)

    def tx(self, text):
        return text
