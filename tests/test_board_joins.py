"""The emulated board's stream joins recorded drops without a step (board.capture.joined_without_steps): a step
between two records' offsets would fire the board's trigger on the quiet start, a drop no board sees."""

import numpy as np

from impactsense.board.capture import JOIN_SLOPE_SHARE, joined_without_steps

THR = 4.0   # the trigger's threshold floor in the rig's counts


def _records(offsets, n=400, noise=0.3, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, noise, (len(offsets), 4, n)) + np.asarray(offsets, float)[:, None, None]
    t = np.arange(n - 250)
    x[:, :, 250:] += 40.0 * np.sin(t / 3.0) * np.exp(-t / 15.0)   # a hit after the quiet start, rung out
    return np.rint(x + 128).astype(np.int16)


def test_records_without_a_step_are_the_stream_as_it_was():
    adc = _records([0.0, 1.0, -1.0])
    assert joined_without_steps(adc, THR, 20.0, 200) is adc


def test_a_step_as_large_as_the_threshold_is_crossfaded_slowly():
    adc = _records([0.0, 3 * THR, -2 * THR])
    out = joined_without_steps(adc, THR, 20.0, 200)
    lead = out.shape[-1] - adc.shape[-1]
    assert lead > 0
    np.testing.assert_array_equal(out[:, :, lead:], adc)   # each record kept whole after its lead
    stream = out.reshape(-1, 4, out.shape[-1]).transpose(1, 0, 2).reshape(4, -1).astype(float)
    # the level through each lead (20-sample means: one board frame) moves by at most the slope the rule allows, plus
    # one count (the crossfade rounded to whole counts), far below the threshold a step must reach to fire
    for k in range(1, adc.shape[0]):
        j = k * out.shape[-1]
        seg = stream[:, j: j + lead]
        frames = seg[:, : seg.shape[1] // 20 * 20].reshape(4, -1, 20).mean(-1)
        assert np.abs(np.diff(frames, axis=1)).max() <= JOIN_SLOPE_SHARE * THR * 1.6 + 1.0
    # the lead ends on the record's own level and starts on the previous record's end level
    for k in range(1, adc.shape[0]):
        assert abs(out[k, :, :8].mean() - adc[k - 1, :, -8:].mean()) < 1.0
        assert abs(out[k, :, lead - 8:lead].mean() - adc[k, :, :8].mean()) < 1.0


def _hum_records(n_rec=3, n=600, quiet=200, amp=30.0, fs=100000.0, seed=1):
    """Records with a 50 Hz hum of a random phase each (the joins then step) and a hit at `quiet`."""
    rng = np.random.default_rng(seed)
    t = np.arange(-400, n) / fs   # 400 samples before each record: the hum as a continuous stream would have it
    phase = rng.uniform(0, 2 * np.pi, (n_rec, 4, 1))
    hum = amp * np.sin(2 * np.pi * 50.0 * t + phase) + 2048
    x = hum + rng.normal(0.0, 0.5, hum.shape)
    k = np.arange(n - quiet)
    x[..., 400 + quiet:] += 400.0 * np.sin(k / 3.0) * np.exp(-k / 40.0)
    return np.rint(x[..., 400:]).astype(np.int16), hum[..., :400]


def test_a_hum_runs_on_through_the_lead_as_far_back_as_a_capture_reaches():
    adc, hum_before = _hum_records()
    reach = 96
    out = joined_without_steps(adc, THR * 10, 2.0, 200, reach)
    lead = out.shape[-1] - adc.shape[-1]
    assert lead > reach
    np.testing.assert_array_equal(out[:, :, lead:], adc)
    near = out[:, :, lead - reach:lead].astype(float)   # what a capture can hold of the lead: the hum going on
    # the hum as it was (not mirrored back): within the noise and the line's bend over 96 + 150 samples of a 50 Hz hum
    # (30 x (2 pi 50 x 2.5 ms)^2 / 2 ~ 9 counts at most, most phases far less)
    err = np.abs(near - hum_before[..., -reach:])
    assert np.median(err) < 2.0 and err.max() < 10.0
    mirrored = adc[..., :reach][..., ::-1].astype(float)
    assert np.median(np.abs(mirrored - hum_before[..., -reach:])) > 3 * np.median(err)


def test_an_arrival_inside_the_declared_quiet_start_stays_out_of_the_lead():
    adc, _ = _hum_records(quiet=120)     # the hit 120 samples in: inside the 150 the quiet share would take
    out = joined_without_steps(adc, THR * 10, 2.0, 200, 96)
    lead = out.shape[-1] - adc.shape[-1]
    head = out[:, :, :lead].astype(float)
    assert np.abs(np.diff(head, axis=-1)).max() < 0.25 * 400.0   # no copy of the hit's swing (400 counts) in it
