"""Short records from a 16-bit logger replayed through the natively compiled firmware app.

A logger that keeps 8 ms at 100 kHz with 30 samples before the hit, 16 bits, a negative-going front end whose
DC sits 2300 counts under the declared bias (the synthetic kind cfrp-crossply's). The qemu image's fixture fed
such records to the app back to back as they were: a drop every 8 ms, inside the app's 20 ms capture and
40 ms hold-off and before it had armed, so most drops got no report ("drop 2: not one report from the native
app"). Every replay now reads board.capture.board_frames (the stream a board sees: drops apart, the plate
quiet between them), the board's site-map capture hook too (it kept 3 of 20 such drops).
"""

from __future__ import annotations

import numpy as np

from impactsense import _core, _link
from impactsense.board.capture import (app_config, board_capture, board_frames, board_samples, replay_reports,
                                       signal_for_board)
from impactsense.data import load_session, write_session
from impactsense.pipeline import featurize
from impactsense.signal import SignalConfig, core_samples

KEEP, SAMPLES, DC, GAIN = 30, 800, -2300, -16.0


def sixteen_bit_short_records(session, rows, tmp_path):
    """The bundled drops as that logger records them: cut to KEEP samples before the earliest threshold
    crossing and SAMPLES long, re-scaled to 16 bits through an inverting front end GAIN x, DC counts off the
    declared bias."""
    s = session.subset(rows)
    cfg = SignalConfig.for_rig(session.rig)
    first = np.nanmin(_core.extract_batch(core_samples(s.adc, cfg), cfg.core())["toa_threshold"], axis=1)
    start = np.floor(first).astype(int) - KEEP
    assert (start >= 0).all()
    cut = np.stack([a[:, b:b + SAMPLES] for a, b in zip(s.adc.astype(float), start)])
    adc = np.clip(np.rint(32768 + DC + GAIN * (cut - session.rig.bias_counts)), 0, 65535).astype(np.uint16)
    raw = dict(session.rig.to_dict(), samples=SAMPLES, adc_bits=16, bias_counts=32768)
    path = write_session(tmp_path / "short16", raw, s.x_mm, s.y_mm, s.height_mm, adc, s.case_id, s.repetition)
    return load_session(path)


def test_every_drop_of_a_short_record_16_bit_logger_gets_one_report(tmp_path, session1):
    rows = np.arange(0, 771, 64)
    short = sixteen_bit_short_records(session1, rows, tmp_path)
    assert short.rig.pretrigger_samples <= KEEP + 6

    app = _link.App(app_config(short.rig, 50000, dump_raw=True), None)
    reports, captures = replay_reports(app, board_frames(short.adc, short.rig, app))
    assert [len(r) for r in reports] == [1] * len(rows)
    # each report's capture holds its drop: onsets on all four channels, the hit after the pre-trigger
    caps = np.stack([c[0] for c in captures])
    feats = featurize(caps, signal_for_board(short.rig))
    assert feats.usable.mean() >= 0.9, feats.usable
    first = np.nanmin(feats.toa_us, axis=1) * 50000 * 1e-6
    assert (first[feats.usable] > 0.5 * app.pretrigger_frames).all(), first

    # the records back to back as they are (the fixture's old replay) lose drops to the capture and hold-off
    bare = _link.App(app_config(short.rig, 50000, dump_raw=True), None)
    lost, _ = replay_reports(bare, board_samples(short.adc, short.rig.fs_hz, 50000, adc_max=short.rig.adc_max))
    assert sum(len(r) != 1 for r in lost) >= len(rows) // 2

    # the board's capture hook (its site map's simulated drops, the core's int16 counts) takes each one too
    caps_hook, got = board_capture(short.rig)(short.adc.astype(np.int32) - 32768)
    assert got.tolist() == list(range(len(rows)))
