"""A report that is not valid says why: its reason, an impactcore status code (impactcore.h IMPACTCORE_STATUS, the
only list; the host reads it through the binding), on the serial frame and the BLE notification. A frame of another
protocol version, or a corrupt one, is dropped and counted, never read as a report. The monitor's table and JSON
lines and the event log show the reason and count the reports per reason, and the firmware app (the emulated board)
replaying recorded drops names why it could not report a drop: a dead channel with models that have no three-channel
path (the twin off), two dead channels, every channel clipped (the twin has no energies), no models."""

import io
import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from test_link_e2e import FakeBleakClient, FakeTransport

from impactsense import _core
from impactsense import _link as L
from impactsense.link import monitor as mon
from impactsense.link import protocol
from impactsense.link.eventlog import EventLog, connect, read_reports, reason_counts, report_reason
from impactsense.link.transport import BleTransport

ROOT = Path(__file__).resolve().parents[1]
REASONS = sorted(c for c in _core.STATUS_KEYS if c != _core.STATUS_OK)


def report(**kw):
    r = dict(seq=7, timestamp_ms=123456, x_mm=123.4, y_mm=56.7, uncertainty_mm=3.2, energy_class=1,
             order=[2, 0, 3, 1], accepted=True, valid=True, clipped=0b0101, dead=0b1000)
    r.update(kw)
    return r


def rejected(code, **kw):
    return report(valid=False, reason=code, energy_class=0, **kw)


def test_the_reasons_are_the_cores_status_codes_once():
    """Codes are distinct wire bytes with distinct keys and texts; the app's reasons are past the core's own."""
    keys = _core.STATUS_KEYS
    assert keys[_core.STATUS_OK] == "ok" and keys[_core.STATUS_NO_TRIGGER] == "no_trigger"
    assert len(set(keys.values())) == len(keys) and all(0 <= c < 256 for c in keys)
    texts = [_core.status_name(c) for c in keys]
    assert len(set(texts)) == len(texts) and "unknown status" not in texts
    assert {"no_models", "channel_missing", "channels_missing", "clipped"} <= set(keys.values())
    assert protocol.reason_code("clipped") in keys and protocol.reason_text(250) == "reason 250 (unknown to this host)"


@pytest.mark.parametrize("code", REASONS)
def test_every_reason_round_trips_serial_and_ble(code):
    f = L.encode_report(rejected(code))
    assert len(f) == L.REPORT_FRAME_BYTES and f[6 + 18] == code  # the body's last byte
    assert struct.unpack("<I", f[-4:])[0] == zlib.crc32(f[2:-4])
    [frame] = L.Decoder().feed(f)
    got = frame["report"]
    assert not got["valid"] and got["reason"] == code and got["reason_key"] == _core.STATUS_KEYS[code]
    ble = L.ble_payload(rejected(code))
    assert len(ble) == L.BLE_PAYLOAD_BYTES <= 20 and L.parse_ble_payload(ble) == got
    line = mon.report_line(got)
    assert line.endswith(f"{_core.STATUS_KEYS[code]}: {_core.status_name(code)}")


def test_a_valid_report_has_no_reason_and_a_report_that_is_not_valid_has_one():
    got = L.Decoder().feed(L.encode_report(report()))[0]["report"]
    assert got["valid"] and got["reason"] == 0 and mon.report_line(got).endswith("1000")
    for bad in (report(reason=protocol.reason_code("clipped")), report(valid=False)):
        with pytest.raises(ValueError, match="reason"):
            L.encode_report(bad)
    # the same bodies with a right CRC: malformed, counted, never a report
    body = bytearray(L.report_body(report()))
    with_reason, without = bytearray(body), bytearray(body)
    with_reason[18] = protocol.reason_code("clipped")
    without[16] &= ~0b10  # not valid, no reason
    dec = L.Decoder()
    out = dec.feed(L.encode_frame(L.TYPE_REPORT, bytes(with_reason)) + L.encode_frame(L.TYPE_REPORT, bytes(without))
                   + L.encode_report(report(seq=8)))
    assert [f["report"]["seq"] for f in out] == [8] and dec.stats["payload_errors"] == 2


def test_a_corrupt_frame_is_dropped_and_counted():
    """Any one bit flipped in a rejected report's frame (its reason byte too): no report with that content, the
    decoder counts an error and resynchronises on the next frame."""
    good = L.encode_report(rejected(protocol.reason_code("channel_missing")))
    for bit in range(16, 8 * len(good)):  # past the sync bytes (a broken sync is skipped bytes, not a frame)
        f = bytearray(good)
        f[bit // 8] ^= 1 << (bit % 8)
        dec = L.Decoder()
        out = dec.feed(bytes(f) + L.encode_report(report(seq=9)))
        assert [fr["report"]["seq"] for fr in out] == [9], bit
        assert dec.errors >= 1, bit


def v1_report_frame(seq=5) -> bytes:
    """A report as version-1 firmware sent it: an 18-byte body (no reason byte), version byte 1, its CRC right."""
    body = L.report_body(report(seq=seq))[:18]
    head = bytes([1, L.TYPE_REPORT]) + struct.pack("<H", len(body)) + body
    return b"\xa5\x5a" + head + struct.pack("<I", zlib.crc32(head))


def test_an_old_version_frame_is_dropped_counted_and_named():
    """A version-1 board's report (and a later version's longer one) between this version's reports: both dropped
    whole (not resynchronised into: no CRC error), counted, the version kept; the reports around them decoded."""
    v3 = bytes([3, L.TYPE_REPORT]) + struct.pack("<H", 24) + bytes(24)
    v3 = b"\xa5\x5a" + v3 + struct.pack("<I", zlib.crc32(v3))
    stream = L.encode_report(report(seq=1)) + v1_report_frame() + L.encode_report(report(seq=2)) + v3
    dec = L.Decoder()
    assert [f["report"]["seq"] for f in dec.feed(stream)] == [1, 2]
    s = dec.stats
    assert s["version_errors"] == 2 and s["other_version"] == 3 and s["crc_errors"] == 0
    assert s["payload_errors"] == 0 and s["bytes_skipped"] == 0
    # the new frame, to an old host, is a frame of another version: its version byte is not 1
    assert L.encode_report(rejected(protocol.reason_code("no_models")))[2] == L.VERSION == 2
    # a board that only speaks version 1: the monitor says so, once, and reads no report
    out, err = io.StringIO(), io.StringIO()
    totals = mon.run(lambda: FakeTransport(v1_report_frame(1) + v1_report_frame(2)), out=out, err=err)
    assert totals["reports"] == 0 and totals["version_errors"] == 2 and totals["other_version"] == 1
    assert err.getvalue().count("of protocol version 1 dropped") == 1 and "reads version 2" in err.getvalue()
    assert out.getvalue() == ""


def test_ble_carries_the_reason_and_counts_old_version_notifications():
    clients = []
    t = BleTransport("AA:BB", client_factory=lambda a: clients.append(FakeBleakClient(a)) or clients[-1])
    code = protocol.reason_code("channels_missing")
    clients[0].cb(0, bytearray(L.ble_payload(rejected(code, seq=3))))
    clients[0].cb(0, bytearray(b"\x01" + L.report_body(report(seq=4))[:18]))  # a version-1 board's notification
    t.disconnected()
    m = mon.Monitor(t)
    got = [f["report"] for f in m.frames()]
    assert [(r["seq"], r["reason"]) for r in got] == [(3, code)]
    c = m.counters()
    assert c["ble_version_errors"] == 1 and c["ble_other_version"] == 1 and c["bad_payloads"] == 1
    assert c["rejected:channels_missing"] == 1 and "protocol version 1" in m.version_note()
    t.close()


def test_monitor_and_event_log_show_the_reason_and_count_per_reason(tmp_path, capsys, monkeypatch):
    from impactsense.cli import main
    from impactsense.link import eventpage

    codes = [0, "channel_missing", 0, "clipped", "channel_missing", 0, "no_trigger"]
    sent = [report(seq=i) if c == 0 else rejected(protocol.reason_code(c), seq=i) for i, c in enumerate(codes)]
    stream = b"".join(L.encode_report(r) for r in sent)
    out, err = io.StringIO(), io.StringIO()
    db = tmp_path / "ev.sqlite"
    log = EventLog(db, "b1")
    totals = mon.run(lambda: FakeTransport(stream), out=out, err=err, log=log)
    log.close()
    assert totals["rejected"] == 4 and totals["rejected:channel_missing"] == 2 and totals["rejected:clipped"] == 1
    assert "rejected:channel_missing=2" in err.getvalue()  # the monitor's closing counts
    lines = out.getvalue().splitlines()[1:]
    assert lines[4].endswith("channel_missing #2: " + _core.status_name(protocol.reason_code("channel_missing")))
    assert lines[6].endswith("no_trigger #1: no channel crossed the onset threshold")
    js = io.StringIO()
    mon.run(lambda: FakeTransport(stream), json_lines=True, out=js, err=io.StringIO())
    rows = [json.loads(s) for s in js.getvalue().splitlines()]
    assert [r["reason_key"] for r in rows] == [c if c else "ok" for c in codes]
    assert rows[3]["reason_text"] == _core.status_name(protocol.reason_code("clipped")) and "reason_text" not in rows[0]
    stored = read_reports(connect(db))
    assert reason_counts(stored) == {("b1", 1): {"channel_missing": 2, "clipped": 1, "no_trigger": 1}}
    assert report_reason(stored[3]).startswith("clipped: every channel")
    # a report logged from firmware older than the reason byte
    assert report_reason(dict(stored[1], flags={})) == "no reason (older firmware)"
    capsys.readouterr()
    assert main(["events", str(db)]) == 0
    cap = capsys.readouterr()
    assert "board b1 boot 1: not reported: 2 channel_missing, 1 clipped, 1 no_trigger" in cap.err
    listed = cap.out.splitlines()
    assert listed[5].endswith("channel_missing: " + _core.status_name(protocol.reason_code("channel_missing")))
    # the --html page's tables (its figures left out here: they take seconds and test_eventlog draws them)
    for fig in ("plate_figure", "heatmap_figure", "energy_figure", "link_figure"):
        monkeypatch.setattr(eventpage, fig, lambda *a, **k: "")
    page = eventpage.page(stored, [], [], None, str(db))
    assert "reports not valid, per reason" in page and "clipped: every channel" in page
    assert "<td>channel_missing</td><td>2</td>" in page


@pytest.fixture(scope="module")
def replay():
    """The emulated board (impactapp's App through the binding, as `impactsense emulate` runs it) on five recorded
    drops of the bundled session with the shipped board models (twin on) or their position forests without a twin
    or three-channel classes (the twin off)."""
    from impactsense.board.capture import app_config, board_frames, replay_reports
    from impactsense.data import load_session
    from impactsense.export import firmware_models, load_tables

    s = load_session()
    models, signal = firmware_models(ROOT / "models")
    t = load_tables(ROOT / "models" / "forest_tables.npz")
    spec = {r: {k: v if isinstance(v, str) else v.tolist() for k, v in t[r].items()} for r in ("x", "y")}
    twin_off = L.ForestModels(spec["x"], spec["y"], spec["y"], bool(t["residual_xy"]))
    adc = s.adc[np.arange(0, 40, 8)].copy()
    base = np.median(adc[..., :200], axis=-1, keepdims=True)

    def run(m, adc):
        app = L.App(app_config(s.rig, 50000, signal), m)
        reports, _ = replay_reports(app, board_frames(adc, s.rig, app))
        return [r for rr in reports for r in rr]

    def dead(adc, channels):
        out = adc.copy()
        for c in channels:
            out[:, c, :] = base[:, c, :].astype(adc.dtype)  # a flat line at the channel's bias
        return out

    clipped = np.clip(base + (adc - base) * 40.0, 0, s.rig.adc_max).astype(adc.dtype)
    return dict(models=models, twin_off=twin_off, run=run, adc=adc, dead=dead, clipped=clipped)


def test_the_emulated_board_says_why_it_could_not_report_a_drop(replay):
    run, adc, dead = replay["run"], replay["adc"], replay["dead"]
    clean = run(replay["twin_off"], adc)
    assert len(clean) == 5 and all(r["valid"] and r["reason"] == 0 for r in clean)
    one_off = run(replay["twin_off"], dead(adc, [2]))
    assert len(one_off) == 5 and all(not r["valid"] and r["reason_key"] == "channel_missing" and r["dead"] == 0b100
                                     for r in one_off)
    one_twin = run(replay["models"], dead(adc, [2]))  # the twin matches the other three: reported
    assert all(r["valid"] and r["reason"] == 0 and r["left_out"] == 2 for r in one_twin)
    two = run(replay["models"], dead(adc, [1, 2]))
    assert len(two) == 5 and all(not r["valid"] and r["reason_key"] == "channels_missing" for r in two)
    clip = run(replay["models"], replay["clipped"])
    assert clip and all(not r["valid"] and r["reason_key"] == "clipped" and r["clipped"] == 0b1111 for r in clip)
    bare = run(None, adc)
    assert len(bare) == 5 and all(not r["valid"] and r["reason_key"] == "no_models" for r in bare)
    # what the board sends, the monitor shows: the reason per drop and the count per reason
    stream = b"".join(L.encode_report(r) for r in one_off + two)
    out, err = io.StringIO(), io.StringIO()
    totals = mon.run(lambda: FakeTransport(stream), out=out, err=err)
    assert totals["rejected:channel_missing"] == 5 and totals["rejected:channels_missing"] == 5
    assert "channels_missing #5: two or more channels" in out.getvalue().splitlines()[-1]
