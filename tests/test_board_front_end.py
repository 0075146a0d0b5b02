"""The board's declared analog front end (rig.json `board_front_end`: an anti-alias Butterworth before the SAADC):
parsed with errors naming the field, applied by the emulated board when declared and only then, its modelled
response the analog Butterworth's, and what it is for: the board's onset pick no longer moves with where the
50 kHz samples fall on an arrival with much of its energy above 25 kHz."""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from impactsense import _link
from impactsense.board.capture import (app_config, board_anti_alias, board_frames, board_samples,
                                        continued_for_capture)
from impactsense.board.front_end import anti_alias_response, anti_aliased
from impactsense.data import rig_from_dict
from impactsense.errors import DataError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_onset_phase as bench  # noqa: E402

from impactsense.signal import SignalConfig  # noqa: E402

FS_IN = 100000.0


def _rig(session1, front=None):
    raw = dict(session1.rig.to_dict())
    raw.pop("board_front_end", None)
    if front is not None:
        raw["board_front_end"] = front
    return rig_from_dict(raw)


def test_the_front_end_is_read_from_rig_json_with_errors_naming_the_field(session1):
    assert _rig(session1).board_anti_alias is None
    assert _rig(session1, {"anti_alias_hz": 15000, "anti_alias_poles": 2}).board_anti_alias == (15000.0, 2)
    assert _rig(session1, {"anti_alias_hz": 12000}).board_anti_alias == (12000.0, 4)   # the default poles
    for front, field in [({"anti_alias_hz": 60000}, "anti_alias_hz"), ({"anti_alias_hz": -1}, "anti_alias_hz"),
                         ({"anti_alias_hz": 15000, "anti_alias_poles": 0}, "anti_alias_poles"),
                         ({"anti_alias_hz": 15000, "anti_alias_poles": 2.5}, "anti_alias_poles"),
                         ({"anti_alias_poles": 4}, "anti_alias_hz"), ({"anti_alias_khz": 15}, "anti_alias_khz"),
                         (15000, "board_front_end")]:
        with pytest.raises(DataError, match=field):
            _rig(session1, front)


def test_the_emulated_board_applies_the_declared_filter_and_only_then(session1):
    sub = session1.subset(np.arange(3))
    app = _link.App(app_config(sub.rig, 50000), None)
    plain = board_frames(sub.adc, _rig(session1), app)
    records = continued_for_capture(sub.adc, FS_IN, app.capture_frames, 50000, app.core_config.baseline_samples,
                                    app.pretrigger_frames, sub.rig.pretrigger_samples)
    np.testing.assert_array_equal(plain, board_samples(records, FS_IN, 50000, adc_max=sub.rig.adc_max))
    declared = _rig(session1, {"anti_alias_hz": 15000, "anti_alias_poles": 4})
    filtered = board_frames(sub.adc, declared, app)
    assert filtered.shape == plain.shape
    # the records' quiet starts keep their level (the filter starts at rest on it; their noise is smoothed) ...
    quiet = slice(0, 40)
    assert np.abs(filtered[:, quiet].mean(axis=1) - plain[:, quiet].mean(axis=1)).max() < 1.0
    # ... and the board's samples lose what lies above the corner: their power at 18-25 kHz (the Butterworth's
    # -3.6 .. -17.8 dB, and less folded down from above 25 kHz) falls by more than half
    def high_power(frames):
        spec = np.abs(np.fft.rfft(frames.astype(float) - frames.mean(axis=1, keepdims=True), axis=1)) ** 2
        return spec[:, np.fft.rfftfreq(frames.shape[1], 1 / 50000.0) >= 18000.0].sum()
    assert high_power(filtered) < 0.5 * high_power(plain), (high_power(filtered), high_power(plain))
    # a session the board recorded itself (the rig's rate is the board's) came through its front end already
    assert board_anti_alias(declared, 50000) == (15000.0, 4)
    assert board_anti_alias(replace(declared, fs_hz=50000.0), 50000) is None
    assert board_anti_alias(_rig(session1), 50000) is None


@pytest.mark.parametrize("poles", [2, 4])
def test_the_modelled_response_is_the_analog_butterworths(poles):
    """Steady sines through the model (anti_aliased at the recording's 100 kHz) against the analytic Butterworth
    magnitude 1 / sqrt(1 + (f / fc)^(2 poles)): -3.01 dB at the corner, within 0.1 dB at every frequency up to
    the recording's band (no bilinear warping: 25 kHz, the board's Nyquist frequency, is where the real filter's
    leak matters)."""
    fc = 15000.0
    t = np.arange(6000) / FS_IN
    for f in (2000.0, fc, 20000.0, 25000.0, 40000.0):
        y = anti_aliased((1000.0 * np.sin(2 * np.pi * f * t))[None], FS_IN, fc, poles)[0]
        gain_db = 20 * np.log10(np.sqrt(2 * np.mean(y[1000:5000].astype(float) ** 2)) / 1000.0)
        want_db = -10 * np.log10(1 + (f / fc) ** (2 * poles))
        assert abs(gain_db - want_db) < 0.1, (f, gain_db, want_db)
        assert abs(20 * np.log10(abs(anti_alias_response(f, fc, poles)[0])) - want_db) < 1e-6
    assert abs(-10 * np.log10(2.0) + 3.0103) < 1e-3


def _ricker(shift_us, f_hz=25000.0, amp=1500.0, n=5000, t0_us=3000.0):
    """A broadband arrival: a Ricker wavelet peaking at 25 kHz (57 % of its energy above the board's 25 kHz
    Nyquist frequency, as the rigs' first 100 us carry 42-69 %), at t0 + shift, sampled at 100 kHz."""
    t = (np.arange(n) / FS_IN * 1e6 - t0_us - shift_us) * 1e-6
    a = (np.pi * f_hz * t) ** 2
    return 2048.0 + amp * (1 - 2 * a) * np.exp(-a)


def _sinc_picks(x100, phases, anti_alias):
    """The board's channel-0 samples of each shifted arrival (board_samples) picked by the windowed-sinc crossing
    (bench_onset_phase.sinc, anchored at the core's threshold crossing): us, back on the arrival's clock."""
    adc = np.stack([np.repeat(np.rint(x)[None], 4, axis=0) for x in x100]).astype(np.uint16)
    y = np.ascontiguousarray(np.transpose(board_samples(adc, FS_IN, 50000, anti_alias=anti_alias), (0, 2, 1)))
    cfg = SignalConfig.from_dict({**SignalConfig().to_dict(), "fs_hz": 50000, "onset_threshold_counts": 50.0})
    got, raw = bench.core_picks(y, cfg)
    base = np.asarray(raw["baseline"], float)[:, :1]
    thr = np.maximum(50.0, cfg.onset_noise_factor * np.asarray(raw["noise_rms"], float))[:, :1]
    return bench.sinc(y[:, :1], base, thr, got["core threshold crossing"][:, :1])[:, 0] - np.asarray(phases) * 20.0


def test_with_the_filter_the_boards_pick_does_not_move_with_the_sample_phase():
    """Eight arrivals 2.5 us apart (one 50 kHz sample's phases). Through the declared filter (15 kHz, 4 poles)
    the sinc crossing's spread is bounded by what is left above 25 kHz: the aliased residual r (the filtered
    arrival's part above 25 kHz, largest within 3 samples of the crossing) over the in-band slope s of |x| there
    moves the crossing by at most r / s either way (2 r / s ~ 9 us here, the interpolant's ~1 % and the x4 grid's
    step add < 1 us); without it the residual is the arrival's 57 % and the spread is several times larger."""
    phases = np.arange(8) / 8.0
    x100 = [_ricker(p * 20.0) for p in phases]
    aa = (15000.0, 4)
    filtered = anti_aliased(np.asarray(x100[0])[None] - 2048.0, FS_IN, *aa)[0].astype(float)
    spec = np.fft.rfft(filtered)
    f = np.fft.rfftfreq(filtered.size, 1 / FS_IN)
    inband = np.fft.irfft(spec * (f <= 25000.0), n=filtered.size)
    k = int(np.argmax(np.abs(filtered) >= 50.0))
    r = np.abs(filtered - inband)[k - 3:k + 4].max()
    s = np.abs(np.diff(np.abs(inband)))[k - 2:k + 1].mean() * FS_IN / 1e6   # counts / us
    bound = 2 * r / s + 1.0
    with_filter = _sinc_picks(x100, phases, aa)
    without = _sinc_picks(x100, phases, None)
    assert np.isfinite(with_filter).all() and np.isfinite(without).all()
    assert np.ptp(with_filter) < bound < 12.0, (with_filter, bound)
    assert np.ptp(without) > 2.5 * np.ptp(with_filter), (without, with_filter)
