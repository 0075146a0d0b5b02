"""End to end: recorded drops -> pty emulator (the firmware app, compiled natively) -> pyserial -> decoder,
checked against the host pipeline (C++ core + scikit-learn + the twin's fingerprint) on the captures the
firmware took. The models classify the energy on the twin's site map as the board sees it (a coarse 20 mm
map, to keep the test quick)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from impactsense import _link
from impactsense.data import load_session
from impactsense.export import export_models
from impactsense.link import monitor as mon
from impactsense.link.record import CaptureAssembler
from impactsense.link.transport import BleTransport, PortClosed, open_serial


@pytest.fixture(scope="module")
def exported(tmp_path_factory, board_site_map_20mm):
    from impactsense.board.models import train_board_models

    root = tmp_path_factory.mktemp("fw")
    s = load_session()
    model_dir = train_board_models(s, root / "model", n_trees=10, site_map=board_site_map_20mm)
    export_models(model_dir, root / "out", write_m2cgen=False)
    return model_dir, root / "out"


def start_emulator(models, *extra, once=True, cwd=None):
    models = [] if models is None else ["--models", str(models)]
    proc = subprocess.Popen([sys.executable, "-m", "impactsense.cli", "emulate", "--pty", "--speed", "0",
                             *models, *(["--once"] if once else []), *extra], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=cwd)
    path = proc.stdout.readline().strip()
    assert path.startswith("/dev/pts/"), proc.stderr.read()
    return proc, path


def host_reference(model_dir, captures, signal):
    """The host pipeline on the firmware's captures: the trainer's featurize + ImpactModel.predict."""
    from impactsense.models import ImpactModel
    from impactsense.pipeline import featurize

    feats = featurize(captures, signal)
    pred = ImpactModel.load(model_dir).predict(feats)
    return feats, pred


def read_all(port, dump_raw=False):
    if dump_raw:
        port.write(_link.encode_command(_link.CMD_DUMP_RAW, 1))
    m = mon.Monitor(port)
    asm = CaptureAssembler()
    reports, caps = [], []
    for f in m.frames(idle_timeout_s=60):
        if f["kind"] == "raw":
            asm.add(f["raw"])
        elif f["kind"] == "report":
            reports.append(f["report"])
            caps.append(asm.take(f["report"]["seq"]) if dump_raw else None)
    return reports, caps, m.counters()


def check_against_host(exported, n_drops):
    model_dir, out = exported
    proc, path = start_emulator(out, "--limit", str(n_drops))
    port = open_serial(path, timeout=0.5)
    try:
        reports, caps, counters = read_all(port, dump_raw=True)
    finally:
        port.close()
    assert proc.wait(60) == 0
    assert len(reports) == n_drops  # one report per drop: trigger, hold-off and re-arm work
    assert counters["crc_errors"] == 0 and counters["seq_gaps"] == 0
    assert [r["seq"] for r in reports] == list(range(n_drops))
    from impactsense.export import firmware_models
    from impactsense.board.capture import signal_for_board

    s = load_session()
    signal = signal_for_board(s.rig, firmware_models(out)[1], 50000)  # what the board runs
    feats, pred = host_reference(model_dir, np.stack(caps), signal)
    got = {k: np.array([r[k] for r in reports]) for k in ("x_mm", "y_mm", "energy_class", "accepted", "valid")}
    use = feats.usable & (pred["energy_class"] >= 0)  # the models ran: usable features, a twin estimate
    assert use.mean() > 0.9 and "height_mm" in pred
    np.testing.assert_array_equal(got["valid"], use)
    np.testing.assert_allclose(got["x_mm"][use], pred["xy_mm"][use, 0], atol=0.05 + 1e-3)  # 0.1 mm on the wire
    np.testing.assert_allclose(got["y_mm"][use], pred["xy_mm"][use, 1], atol=0.05 + 1e-3)
    np.testing.assert_array_equal(got["energy_class"][use], pred["energy_class"][use])
    np.testing.assert_array_equal(got["accepted"], feats.accepted)
    np.testing.assert_array_equal(np.array([r["order"] for r in reports]), feats.raw["order"])
    # the uncertainty of the reported position: the twin's spread where the models ran, else the localiser's
    unc = np.where(use, pred["uncertainty_mm"], np.sqrt(feats.phys_cov[:, 0] + feats.phys_cov[:, 2]))
    reported = np.array([r["uncertainty_mm"] for r in reports])
    assert np.isfinite(unc[use]).all()
    np.testing.assert_allclose(reported[use], unc[use], atol=0.051)
    phys = ~use & np.isfinite(unc)
    np.testing.assert_allclose(reported[phys], unc[phys], atol=0.051)
    # and the positions mean something: near the true drop positions on the training data
    truth = s.xy_mm[:n_drops]
    err = np.hypot(got["x_mm"] - truth[:, 0], got["y_mm"] - truth[:, 1])[use]
    assert np.median(err) < 15.0


def test_pty_emulator_matches_host_pipeline(exported):
    check_against_host(exported, 12)


@pytest.mark.slow
def test_pty_emulator_all_session1_drops(exported):
    check_against_host(exported, 771)


def test_cli_monitor_json_lines(exported):
    proc, path = start_emulator(exported[1], "--limit", "5")
    out = subprocess.run([sys.executable, "-m", "impactsense.cli", "monitor", "--port", path, "--json-lines"],
                         capture_output=True, text=True, timeout=120)
    assert proc.wait(60) == 0
    lines = [json.loads(s) for s in out.stdout.splitlines()]
    assert [d["seq"] for d in lines] == list(range(5))
    assert all({"seq", "x_mm", "y_mm", "energy_class", "accepted"} <= d.keys() for d in lines)
    assert "crc_errors=0" in out.stderr


def test_mid_stream_disconnect(exported):
    proc, path = start_emulator(exported[1], "--limit", "400")
    port = open_serial(path, timeout=0.5)
    m = mon.Monitor(port)
    got = []
    for f in m.frames(idle_timeout_s=30):
        if f["kind"] == "report":
            got.append(f["report"]["seq"])
            if len(got) == 3:
                break
    port.close()  # the client goes away mid-stream
    assert proc.wait(60) == 0  # the emulator notices and exits cleanly
    assert got == [0, 1, 2]


def test_record_writes_a_loadable_session(exported, tmp_path):
    proc, path = start_emulator(exported[1], "--limit", "4")
    out = subprocess.run([sys.executable, "-m", "impactsense.cli", "record", "--port", path, "--out",
                          str(tmp_path / "rec")], capture_output=True, text=True, timeout=120)
    assert proc.wait(60) == 0 and out.returncode == 0, out.stderr
    s = load_session(tmp_path / "rec")
    assert s.adc.shape == (4, 4, 1024) and s.rig.fs_hz == 50000


class FakeTransport:
    """A port that delivers some bytes, then disconnects."""

    def __init__(self, data, chunk=7):
        self.data, self.chunk, self.is_open, self.timeout = data, chunk, True, 0.01

    def read(self, n=1):
        if not self.data:
            self.is_open = False
            raise PortClosed("gone")
        out, self.data = self.data[:min(n, self.chunk)], self.data[min(n, self.chunk):]
        return out

    def close(self):
        self.is_open = False


def frames_for(seqs):
    return b"".join(_link.encode_report(dict(seq=s, x_mm=1.0, y_mm=2.0)) for s in seqs)


def test_monitor_reconnects_and_counts_gaps_and_crc(capsys):
    import io

    bad = bytearray(frames_for([2]))
    bad[10] ^= 0x40
    sessions = [FakeTransport(frames_for([0, 1]) + bytes(bad)), FakeTransport(frames_for([3, 4, 7]))]
    opened = []

    def opener():
        if not sessions:
            raise OSError("no board")
        opened.append(1)
        return sessions.pop(0)

    buf = io.StringIO()
    totals = mon.run(opener, json_lines=True, reconnect=True, out=buf, retry_s=0.0, max_retries=2)
    seqs = [json.loads(s)["seq"] for s in buf.getvalue().splitlines()]
    assert seqs == [0, 1, 3, 4, 7] and len(opened) == 2
    assert totals["crc_errors"] == 1 and totals["reports"] == 5
    assert totals["seq_gaps"] == 1  # 4 -> 7 (per connection; 1 -> 3 spans the reconnect)


class FakeBleakClient:
    """Stands in for bleak.BleakClient: replays report notifications, records config writes."""

    def __init__(self, address):
        self.address, self.writes, self.cb = address, [], None

    async def connect(self):
        return True

    async def start_notify(self, uuid, cb):
        from impactsense.link.transport import REPORT_UUID

        assert uuid == REPORT_UUID
        self.cb = cb

    async def write_gatt_char(self, uuid, data, response=True):
        self.writes.append((uuid, data))

    async def disconnect(self):
        return True


def test_ble_transport_double_feeds_the_same_decoder():
    clients = []

    def factory(addr):
        clients.append(FakeBleakClient(addr))
        return clients[-1]

    t = BleTransport("AA:BB", client_factory=factory)
    c = clients[0]
    sent = [dict(seq=i, x_mm=10.0 * i, y_mm=5.0, energy_class=i % 2, order=[1, 0, 2, 3], accepted=True)
            for i in range(4)]
    for r in sent:
        c.cb(0, bytearray(_link.ble_payload(r)))
    c.cb(0, bytearray(b"\x01garbage"))  # malformed notification: dropped and counted
    t.disconnected()
    t.write(_link.encode_command(_link.CMD_SET_THRESHOLD, 80))
    m = mon.Monitor(t)
    got = [f["report"] for f in m.frames()]
    assert [r["seq"] for r in got] == [0, 1, 2, 3]
    assert [r["x_mm"] for r in got] == pytest.approx([0, 10, 20, 30])
    assert t.bad_payloads == 1 and m.counters()["crc_errors"] == 0
    assert c.writes and c.writes[0][1] == _link.encode_command(_link.CMD_SET_THRESHOLD, 80)
    t.close()
