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
