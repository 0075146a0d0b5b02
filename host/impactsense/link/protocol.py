"""Frames on the wire. The codec is firmware/lib/impactlink (C++), bound as `impactsense._link`; this module
only names things. See impactlink.h for the byte layout."""

from __future__ import annotations

from .. import _core  # (registers CoreConfig, used by _link; the status codes a report's reason reads)
from .. import _link

Decoder = _link.Decoder
encode_report = _link.encode_report
ble_payload = _link.ble_payload
parse_ble_payload = _link.parse_ble_payload
VERSION = _link.VERSION
REPORT_FRAME_BYTES = _link.REPORT_FRAME_BYTES


# A report that is not valid says why: its `reason`, an impactcore status code (impactcore.h IMPACTCORE_STATUS,
# the only list; the decoded report's `reason_key` is its key).
REASON_KEYS: dict[int, str] = dict(_core.STATUS_KEYS)


def reason_text(code: int) -> str:
    """The text of a report's reason code (the core's status_name; a code this host does not know says so)."""
    code = int(code)
    return _core.status_name(code) if code in REASON_KEYS else f"reason {code} (unknown to this host)"


def reason_code(key: str) -> int:
    """The code of a reason key (e.g. "channels_missing")."""
    codes = {k: c for c, k in REASON_KEYS.items()}
    if key not in codes:
        raise KeyError(f"no reason {key!r}; the reasons are {sorted(codes)}")
    return codes[key]


def set_threshold(counts: int) -> bytes:
    return _link.encode_command(_link.CMD_SET_THRESHOLD, int(counts))


def set_rate(hz: int) -> bytes:
    return _link.encode_command(_link.CMD_SET_RATE, int(hz))


def dump_raw(enable: bool = True) -> bytes:
    return _link.encode_command(_link.CMD_DUMP_RAW, 1 if enable else 0)


def get_config() -> bytes:
    return _link.encode_command(_link.CMD_GET_CONFIG, 0)


class SeqTracker:
    """Counts sequence gaps (lost reports) between consecutive reports."""

    def __init__(self) -> None:
        self.last: int | None = None
        self.gaps = 0
        self.lost = 0

    def update(self, seq: int) -> None:
        if self.last is not None and seq != (self.last + 1) & 0xFFFFFFFF:
            self.gaps += 1
            if seq > self.last:
                self.lost += seq - self.last - 1
        self.last = seq
