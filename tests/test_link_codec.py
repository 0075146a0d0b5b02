"""Wire protocol: round trips, layout against an independent CRC, BLE payload = serial report body."""

import struct
import zlib

import numpy as np
import pytest

from impactsense import _core  # noqa: F401
from impactsense import _link as L


def report(**kw):
    r = dict(seq=7, timestamp_ms=123456, x_mm=123.4, y_mm=56.7, uncertainty_mm=3.2, energy_class=1,
             order=[2, 0, 3, 1], accepted=True, valid=True, clipped=0b0101, dead=0b1000)
    r.update(kw)
    return r


def test_report_round_trip_and_layout():
    r = report()
    f = L.encode_report(r)
    assert len(f) == L.REPORT_FRAME_BYTES == 29
    assert f[:2] == b"\xa5\x5a" and f[2] == L.VERSION and f[3] == L.TYPE_REPORT
    assert struct.unpack("<H", f[4:6])[0] == L.REPORT_BODY_BYTES
    # CRC is zlib's CRC-32 over version..body
    assert struct.unpack("<I", f[-4:])[0] == zlib.crc32(f[2:-4])
    seq, ts, x, y, u, e, order, st, ch, reason = struct.unpack("<IIhhHBBBBB", f[6:-4])
    assert (seq, ts, x, y, u, e) == (7, 123456, 1234, 567, 32, 1)
    assert [(order >> (2 * i)) & 3 for i in range(4)] == [2, 0, 3, 1]
    assert st == 0b11 and ch == 0b1000_0101 and reason == 0
    [frame] = L.Decoder().feed(f)
    got = frame["report"]
    for k in ("seq", "timestamp_ms", "energy_class", "order", "accepted", "valid", "clipped", "dead"):
        assert got[k] == r[k]
    for k in ("x_mm", "y_mm", "uncertainty_mm"):
        assert got[k] == pytest.approx(r[k], abs=0.05)


@pytest.mark.parametrize("x", [-3276.8, -0.04, 0.0, 319.95, 3276.7])
def test_position_quantisation_and_saturation(x):
    got = L.Decoder().feed(L.encode_report(report(x_mm=x, y_mm=1e6)))[0]["report"]
    assert got["x_mm"] == pytest.approx(x, abs=0.051)
    assert got["y_mm"] == pytest.approx(3276.7, abs=0.01)  # saturated, not wrapped


def test_unknown_uncertainty_is_nan():
    got = L.Decoder().feed(L.encode_report(report(uncertainty_mm=float("nan"))))[0]["report"]
    assert np.isnan(got["uncertainty_mm"])


def test_ble_payload_is_version_plus_serial_body():
    r = report(seq=99)
    p = L.ble_payload(r)
    assert len(p) == L.BLE_PAYLOAD_BYTES <= 20  # fits a default-MTU notification
    assert p == bytes([L.VERSION]) + L.encode_report(r)[6:-4]
    assert L.parse_ble_payload(p) == L.Decoder().feed(L.encode_report(r))[0]["report"]
    assert L.parse_ble_payload(bytes([L.VERSION + 1]) + p[1:]) is None  # other version
    assert L.parse_ble_payload(p[:-1]) is None


def test_commands_and_acks_through_the_app():
    app = L.App({}, None)
    dec = L.Decoder()
    acks = [f["ack"] for f in dec.feed(app.rx(L.encode_command(L.CMD_SET_THRESHOLD, 90)))]
    assert acks == [dict(command=L.CMD_SET_THRESHOLD, status=0, fs_hz=50000, threshold_counts=90,
                         capture_frames=1024, dump_raw=0)]
    ack = dec.feed(app.rx(L.encode_command(L.CMD_SET_RATE, 25000)))[0]["ack"]
    assert ack["status"] == 0 and ack["fs_hz"] == 25000 and ack["capture_frames"] == 512
    assert app.core_config.fs_hz == 25000 and app.core_config.capture_delay_us == [0, -5, -10, -15]  # read c x 5 us late: onsets early
    ack = dec.feed(app.rx(L.encode_command(L.CMD_SET_RATE, 100000)))[0]["ack"]  # beyond 200 ksps
    assert ack["status"] == 1 and ack["fs_hz"] == 25000
    ack = dec.feed(app.rx(L.encode_command(L.CMD_DUMP_RAW, 1)))[0]["ack"]
    assert ack["dump_raw"] == 1
    # a report sent to the board is not a command
    assert dec.feed(app.rx(L.encode_report(report())))[0]["ack"]["status"] == 2
    assert dec.errors == 0


def test_raw_chunks_rebuild_the_capture():
    from impactsense.data import load_session
    from impactsense.board.capture import board_samples
    from impactsense.link.record import CaptureAssembler

    s = load_session().subset([0, 1])
    frames = board_samples(s.adc, s.rig.fs_hz, 50000)
    app = L.App({"dump_raw": True}, None)
    dec = L.Decoder()
    asm = CaptureAssembler()
    caps = []
    for k in range(2):
        for f in dec.feed(app.feed(frames[k])):
            if f["kind"] == "raw":
                asm.add(f["raw"])
            elif f["kind"] == "report":
                caps.append(asm.take(f["report"]["seq"]))
    assert len(caps) == 2 and all(c is not None for c in caps)
    # the capture is a contiguous window of the stream: find it in the fed frames
    c = caps[0]
    start = int(np.flatnonzero((frames[0][:, 0] == c[0, 0]) & (frames[0][:, 1] == c[1, 0]))[0])
    np.testing.assert_array_equal(c.T, frames[0][start:start + c.shape[1]])


def test_board_samples_follow_the_saadc_scan():
    """Channel c of frame k is the signal at k / fs + c * 5 us (a slow sine, interior samples)."""
    from impactsense.board.capture import board_samples

    t_in = np.arange(5000) / 100000.0
    f_hz = 1000.0
    sig = 2048 + 1000 * np.sin(2 * np.pi * f_hz * t_in)
    adc = np.repeat(np.rint(sig)[None, None, :], 4, axis=1).astype(np.uint16)
    for fs in (50000, 25000):
        y = board_samples(adc, 100000.0, fs)
        k = np.arange(y.shape[1])
        for c in range(4):
            want = 2048 + 1000 * np.sin(2 * np.pi * f_hz * (k / fs + c * 5e-6))
            inner = slice(20, -20)
            assert np.max(np.abs(y[0, inner, c] - want[inner])) <= 1.2, (fs, c)  # a 5 us slip is ~30 counts
