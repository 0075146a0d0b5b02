"""The firmware app's transmit queue and status frame, on the emulated board (the natively compiled
firmware/lib/impactapp fed the bundled drops as the SAADC would read them, one 256-frame DMA buffer at a time,
with the board's service() between buffers):

- acquisition never waits on the host: a host that stops reading loses reports (whole frames, counted in the
  status frame, matching the sequence gaps) but not one acquisition buffer or event;
- impacts 20 ms apart each give one report;
- the status frame comes once a second of sample clock and counts what the app did."""

import numpy as np
import pytest

from impactsense import _core, _link
from impactsense.data import load_session
from impactsense.board.capture import board_samples
from impactsense.link.emulator import Emulator
from impactsense.link.protocol import Decoder, SeqTracker

FS = 50000
BUFFER = 256


@pytest.fixture(scope="module")
def drops():
    s = load_session("bundled")
    rows = np.arange(0, 771, 7)[:100]  # 100 drops spread over the session
    return s.subset(rows)


def decode(chunks):
    dec, seq = Decoder(), SeqTracker()
    reports, status = [], []
    for b in chunks:
        for f in dec.feed(b):
            if f["kind"] == "report":
                reports.append(f["report"])
                seq.update(f["report"]["seq"])
            elif f["kind"] == "status":
                status.append(f["status"])
    assert dec.errors == 0
    return reports, status, seq


def stream(session, reading, **config):
    emu = Emulator(session, None, fs_hz=FS, **config)
    chunks = list(emu.stream(reading, BUFFER))
    chunks.append(emu.app.pull(1 << 20))  # the host reads what is still queued
    return emu, chunks


def test_status_frame_once_a_second_counts_buffers_and_events(drops):
    emu, chunks = stream(drops, lambda t: True)
    reports, status, seq = decode(chunks)
    n_frames = drops.adc.shape[0] * emu.frames.shape[1]
    duration_s = n_frames / FS
    assert len(status) == pytest.approx(duration_s, abs=1.0)  # one a second of sample clock
    last = status[-1]
    # every recording is fed as ceil(frames / 256) buffers (the last one short); the status goes out at the end
    # of a buffer, so its uptime names the buffers fed so far (to the ms)
    nf = emu.frames.shape[1]
    f = last["uptime_ms"] * FS // 1000
    want = (f // nf) * -(-nf // BUFFER) + -(-(f % nf) // BUFFER)
    assert abs(last["buffers"] - want) <= 1
    assert last["overruns"] == 0 and last["dropped_reports"] == 0 and last["dropped_bytes"] == 0
    assert len(reports) == emu.app.events == drops.adc.shape[0]  # one report a drop, none lost
    assert seq.lost == 0 and last["events"] <= emu.app.events
    assert last["threshold_counts"] == 60  # AppConfig's default trigger threshold
    assert not last["cycle_counter"] and np.isnan(last["idle_load"])  # the emulator has no cycle counter
    # the noise the last event measured on its baseline: the discs' few counts, all four channels
    assert all(0 < n < 50 for n in last["noise_counts"])


def test_host_that_stops_reading_for_2_s_loses_counted_reports_not_buffers(drops):
    """With raw dumps on (8.5 KB an event, `impactsense record`), a host that stops reading for 2 s overflows
    the 4 KB transmit queue: whole frames are dropped and counted; every buffer and every event is still
    processed (acquisition never waits), and the reports the host does get are whole and in order."""
    stop = (1.0, 3.0)
    emu, chunks = stream(drops, lambda t: not stop[0] <= t < stop[1], dump_raw=True)
    reports, status, seq = decode(chunks)
    last = status[-1]
    n = drops.adc.shape[0]
    assert emu.app.events == n                               # every drop was captured and processed
    assert last["overruns"] == 0
    assert last["dropped_reports"] > 0 and last["dropped_bytes"] > 0
    assert len(reports) + last["dropped_reports"] == n       # a report is either delivered or counted
    assert seq.lost == last["dropped_reports"]               # ... and the gaps are exactly the dropped ones
    got = {r["seq"] for r in reports}
    assert all(k in got for k in range(0, 15))           # before the stop (t < 1 s, 20 drops/s): all there
    assert last["raw_dropped"] > 0                           # dumps cut short while the queue was full


def test_host_that_stops_reading_for_2_s_without_raw_loses_nothing(drops):
    """Reports only: 2 s at 20 drops a second is 40 x 29 bytes (+ 2 status frames), well inside the 4 KB queue."""
    assert 40 * _link.REPORT_FRAME_BYTES + 2 * _link.STATUS_FRAME_BYTES < _link.TX_QUEUE_BYTES
    emu, chunks = stream(drops, lambda t: not 1.0 <= t < 3.0)
    reports, status, seq = decode(chunks)
    assert len(reports) == drops.adc.shape[0] and seq.lost == 0
    assert status[-1]["dropped_reports"] == 0 and status[-1]["overruns"] == 0


def test_impacts_20_ms_apart_give_one_report_each(drops):
    """Drops spliced so that their triggers are exactly 1000 frames (20 ms) apart; the app runs with the
    shortest hold-off its configuration allows (the capture after the trigger, 18.56 ms) and a 1 ms quiet
    re-arm. Every impact is captured and reported, in order, with no overrun or dropped report."""
    k = 12
    frames = board_samples(drops.adc[:40], drops.rig.fs_hz, FS, adc_max=drops.rig.adc_max)
    segments, pre = [], 100
    for rec in frames:
        fire = _core.find_trigger(np.ascontiguousarray(rec.T), _core.TriggerConfig())
        if pre <= fire <= rec.shape[0] - 1000 + pre:
            segments.append(rec[fire - pre:fire - pre + 1000])
        if len(segments) == k:
            break
    assert len(segments) == k
    # lead-in and tail: the plate at rest, the first and the last drop's own pre-trigger baseline (a frame held)
    lead = np.repeat(segments[0][:1], 1500, axis=0)
    tail = np.repeat(segments[-1][:1], 1500, axis=0)
    burst = np.concatenate([lead] + segments + [tail])
    emu = Emulator(drops, None, fs_hz=FS, holdoff_us=18560.0, quiet_us=1000.0)
    out = emu.app.feed(np.ascontiguousarray(burst), BUFFER) + emu.app.pull(1 << 20)
    reports, _, seq = decode([out])
    assert [r["seq"] for r in reports] == list(range(k))
    t = np.array([r["timestamp_ms"] for r in reports])
    assert np.all(np.abs(np.diff(t) - 20) <= 1)  # the triggers 20 ms apart, as spliced
    assert seq.lost == 0 and emu.app.events == k
