"""Move or delay (`effects.sensor_position.direction_test`): a constant delay on a channel is constant over the
impacts, a moved disc's timing change depends on the direction to each impact. Synthetic drop-centred ToAs
on a 300 mm square with four corner discs, 40 cases x 3 drops; each case shares a pick/landing error
(3 µs per channel) and each drop adds its own (2 µs): the noise the test must count at case level.
`band_test`: the same drops' band picks (their own slowness, 1.4 x the threshold picks', and their own noise,
4 µs per case and channel, 4 µs per drop): a delay shifts both picks alike, a move each by its own slowness. `joint_test`: both pick sets in one
regression with a constant shared by both."""

from __future__ import annotations

import numpy as np
import pytest

from impactsense import residuals as R
from impactsense.effects.sensor_position import band_test, direction_test, joint_test

SENSORS = np.array([[30.0, 30.0], [270.0, 30.0], [270.0, 270.0], [30.0, 270.0]])
SLOWNESS = 1.0   # µs/mm
CASES, REPS = 40, 3


def _features(rng, move=None, sensor=2, delay_us=0.0, case_sd=3.0, drop_sd=2.0) -> R.Features:
    xy = rng.uniform(60.0, 240.0, (CASES, 2))
    case = np.repeat(np.arange(CASES), REPS)
    x, y = xy[case, 0], xy[case, 1]
    true = SENSORS.copy()
    if move is not None:
        true[sensor] += move
    d = np.hypot(x[:, None] - true[None, :, 0], y[:, None] - true[None, :, 1])
    toa = SLOWNESS * d + rng.normal(0, case_sd, (CASES, 4))[case] + rng.normal(0, drop_sd, (len(case), 4))
    toa[:, sensor] += delay_us
    n = len(case)
    z = np.zeros((n, 4))
    return R.Features(x_mm=x, y_mm=y, height_mm=np.full(n, 150.0), case_id=case, order=np.linspace(0, 1, n),
                      toa_us=toa + 20.0, log_energy=z, clipped=z.astype(bool), log_centroid=z, decay_per_s=z,
                      log_noise=z, hum_counts=np.zeros((n, 4, 2)), plateau_hi=z - 1, plateau_lo=z - 1,
                      sensor_xy_mm=SENSORS.copy(), plate_mm=(300.0, 300.0), fs_hz=100e3, adc_max=4095)


def _reference() -> R.Reference:
    return R.Reference(sensor_xy_mm=SENSORS.copy(), slowness_us_per_mm=SLOWNESS, sigma={"timing": 3.0})


def test_a_constant_delay_is_not_taken_for_a_move_at_case_level_noise():
    """Under a true 6 µs delay the direction part is noise: rejected at 5 % in 1-10 % of 300 sessions (the
    binomial's +-4 sd around 5 %; measured 8 %). Counting the 3 drops of a case as independent (each drop its
    own case) rejects far more often (the case error is 9 / 13 of the variance here; measured 33 %)."""
    from dataclasses import replace

    rng = np.random.default_rng(0)
    ref = _reference()
    p_case, p_drop = [], []
    for _ in range(300):
        F = _features(rng, delay_us=6.0)
        p_case.append(direction_test(ref, F, 2)["p_value"])
        p_drop.append(direction_test(ref, replace(F, case_id=np.arange(len(F))), 2)["p_value"])
    assert 0.01 <= np.mean(np.array(p_case) < 0.05) <= 0.10, np.mean(np.array(p_case) < 0.05)
    assert np.mean(np.array(p_drop) < 0.05) > 0.2, np.mean(np.array(p_drop) < 0.05)


def test_a_move_across_the_look_direction_is_seen():
    """S3 (the (270, 270) corner) moved 7.1 mm across its look direction: the direction part stands out of the
    case-level noise (p < 0.01 on 5 of 5 draws: expected T² ~ 40 x (2.6 µs signature / 3.5 µs case noise)²),
    and its component across the look direction is the move's (within 2 mm; the along-look part trades with
    the free constant and is not asserted)."""
    move = np.array([5.0, -5.0])
    across = np.array([1.0, -1.0]) / np.sqrt(2.0)
    for seed in range(1, 6):
        out = direction_test(_reference(), _features(np.random.default_rng(seed), move=move), 2)
        assert out["p_value"] < 0.01, out
        assert abs(np.array([out["dx_mm"], out["dy_mm"]]) @ across - move @ across) <= 2.0, out


BAND_SLOWNESS = 1.4 * SLOWNESS


def _with_band(rng, F: R.Features, move=None, sensor=2, delay_us=0.0) -> R.Features:
    """F with band picks: the true discs' distances at the band's slowness, the delay as on the threshold picks."""
    from dataclasses import replace

    true = SENSORS.copy()
    if move is not None:
        true[sensor] += move
    d = np.hypot(F.x_mm[:, None] - true[None, :, 0], F.y_mm[:, None] - true[None, :, 1])
    cases = int(F.case_id.max()) + 1
    tb = BAND_SLOWNESS * d + rng.normal(0, 4.0, (cases, 4))[F.case_id] + rng.normal(0, 4.0, d.shape) + 35.0
    tb[:, sensor] += delay_us
    return replace(F, toa_band_us=tb)


def _band_reference() -> R.Reference:
    ref = _reference()
    ref.band = {"slowness_us_per_mm": BAND_SLOWNESS, "offset_us": [0.0] * 4}
    return ref


@pytest.mark.parametrize("test, seed", [(band_test, 3), (joint_test, 5)])
def test_a_delay_is_not_taken_for_a_move(test, seed):
    """A true 4-9 µs delay (either sign) shifts the threshold and the band picks alike: the band test (their
    difference, where the delay cancels) and the joint test (both pick sets sharing one constant: the move's
    coefficients are noise) reject it at 5 % in 1-10 % of 200 sessions (the binomial's +-3 sd around 5 %;
    measured 4.5 % and 4 %)."""
    rng = np.random.default_rng(seed)
    ref = _band_reference()
    p = []
    for _ in range(200):
        delay = rng.choice([-1.0, 1.0]) * rng.uniform(4.0, 9.0)
        F = _with_band(rng, _features(rng, delay_us=delay), delay_us=delay)
        p.append(test(ref, F, 2)["p_value"])
    assert 0.01 <= np.mean(np.array(p) < 0.05) <= 0.10, np.mean(np.array(p) < 0.05)


def test_band_picks_tell_a_move_along_the_look_direction_from_a_delay():
    """S3 (the (270, 270) corner) moved 7.1 mm along its look direction (towards the plate's centre): to the
    threshold picks nearly a constant (the direction test does not reject it on most draws), but its band
    picks move 1.4 x as much: the band test rejects a delay (p < 0.05 on at least 4 of 5 draws, measured 5 of 5 at p
    0.000004-0.017, the direction test p 0.56-0.89; expected
    difference 0.4 x ~7 µs against ~1 µs of case-level noise on the mean)."""
    move = np.array([-5.0, -5.0])
    ref = _band_reference()
    band_p, direction_p = [], []
    for seed in range(1, 6):
        rng = np.random.default_rng(seed)
        F = _with_band(rng, _features(rng, move=move), move=move)
        band_p.append(band_test(ref, F, 2)["p_value"])
        direction_p.append(direction_test(ref, F, 2)["p_value"])
    assert np.sum(np.array(band_p) < 0.05) >= 4, band_p
    assert np.sum(np.array(direction_p) < 0.05) <= 2, direction_p


def test_band_test_without_band_picks_is_silent():
    rng = np.random.default_rng(0)
    assert band_test(_reference(), _features(rng, move=np.array([-5.0, -5.0])), 2)["p_value"] == 1.0


def test_the_joint_test_sees_moves_along_and_across_the_look_direction():
    """S3 moved 7.1 mm across its look direction (the direction dependence of both pick sets): p < 0.01 on at
    least 4 of 5 draws (measured 5 of 5, 1e-5 .. 2e-4). Moved 7.1 mm along it (only the band picks' larger
    shift tells it): p < 0.05 on at least 3 of 5 (measured 3, p 0.0002-0.09; two parameters against the band
    test's one-sided mean, which stays beside it for these moves)."""
    ref = _band_reference()
    for move, level, draws in ((np.array([5.0, -5.0]), 0.01, 4), (np.array([-5.0, -5.0]), 0.05, 3)):
        p = []
        for seed in range(1, 6):
            rng = np.random.default_rng(seed)
            F = _with_band(rng, _features(rng, move=move), move=move)
            p.append(joint_test(ref, F, 2)["p_value"])
        assert np.sum(np.array(p) < level) >= draws, (move, p)


def test_joint_test_without_band_picks_is_silent():
    rng = np.random.default_rng(0)
    assert joint_test(_reference(), _features(rng, move=np.array([5.0, -5.0])), 2)["p_value"] == 1.0


def test_joint_test_without_the_channels_band_picks_is_silent():
    """A strong bond's low-pass can lose one channel's band picks on every drop: no evidence, not an error."""
    from dataclasses import replace

    rng = np.random.default_rng(0)
    F = _with_band(rng, _features(rng, move=np.array([5.0, -5.0])), move=np.array([5.0, -5.0]))
    tb = F.toa_band_us.copy()
    tb[:, 2] = np.nan
    assert joint_test(_band_reference(), replace(F, toa_band_us=tb), 2)["p_value"] == 1.0


# ---- the selection's rule: a move is named where it predicts the held-out picks better than the delay ----
def _select_timing(F: R.Features, monkeypatch, band_sd: float = 4.0):
    """`diagnose.select` with only the two rivals (a move, a constant delay) as candidates, on the synthetic
    drops: the rule under test, without the effects these drops carry nothing for."""
    from impactsense import diagnose as D
    from impactsense.effects import EFFECTS

    monkeypatch.setattr(D, "EFFECTS", {k: EFFECTS[k] for k in ("sensor_position", "channel_delay")})
    ref = _band_reference()
    ref.band["sigma_us"] = float(np.hypot(band_sd, band_sd))
    ref.sigma = {"timing": float(np.hypot(3.0, 2.0)), "energy": 1.0, "spectrum": 1.0, "decay": 1.0,
                 "noise": 1.0, "hum": 1.0}
    ref.plateau_rate = 0.01
    accepted, _, _ = D.select(ref, F, max_effects=1)
    return accepted


def _delay_whose_threshold_picks_vary(rng, delay_us: float, band_sd: float) -> R.Features:
    """A channel delay whose threshold picks do not follow it alike on every drop (a delay that is not a whole
    number of samples on a near-Nyquist onset: loopdraws3, loopdelay2), at its worst: the threshold picks'
    response varies over the impacts as a 7.1 mm move across the look direction would make them, the band picks
    (an envelope) follow the delay whole (case and drop noise band_sd each)."""
    from dataclasses import replace

    F = _features(rng, delay_us=delay_us)
    _, _, ux, uy = _reference().geometry(F)
    toa = F.toa_us.copy()
    toa[:, 2] -= SLOWNESS * (ux[:, 2] * 5.0 - uy[:, 2] * 5.0)
    d = np.hypot(F.x_mm[:, None] - SENSORS[None, :, 0], F.y_mm[:, None] - SENSORS[None, :, 1])
    tb = BAND_SLOWNESS * d + rng.normal(0, band_sd, (CASES, 4))[F.case_id] + rng.normal(0, band_sd, d.shape) + 35.0
    tb[:, 2] += delay_us
    return replace(F, toa_us=toa, toa_band_us=tb)


def test_a_delay_that_fools_the_tests_of_a_constant_is_named_a_delay(monkeypatch):
    """The threshold picks alone say "a move" (the direction test rejects a constant on at least 3 of 6 draws,
    measured 4: the old rule named a move on each of those), the band picks say "a constant": a move fitted to
    both predicts the held-out picks worse than the delay, so the delay is named on its channel on all 6
    (within 1.5 us: the threshold picks' varying response has a mean of its own over these impacts)."""
    rejected = 0
    for seed in range(6):
        rng = np.random.default_rng(30 + seed)
        F = _delay_whose_threshold_picks_vary(rng, -7.5, band_sd=1.5)
        rejected += direction_test(_band_reference(), F, 2)["p_value"] < 0.05
        (c,) = _select_timing(F, monkeypatch, band_sd=1.5)
        assert (c.effect, c.sensor) == ("channel_delay", 2), (seed, c.effect, c.params, c.rival)
        assert abs(c.params["delay_us"] + 7.5) <= 1.5, c.params
        assert c.rival["both_picks_score_difference"] > 0, c.rival
    assert rejected >= 3, rejected


@pytest.mark.parametrize("move", [(7.0, -7.0), (-7.0, -7.0)], ids=["across", "along"])
def test_a_move_is_still_named_a_move(move, monkeypatch):
    """S3 moved 9.9 mm across and along its look direction (threshold and band picks each at their own
    slowness): the move predicts both pick sets better than a delay, and is named on its disc on at least 2 of
    3 draws (measured 2 of 3 each: a draw under the evidence bar, a look-direction draw the band test does not
    read, as before the rule)."""
    move = np.array(move)
    named = 0
    for seed in range(3):
        rng = np.random.default_rng(20 + seed)
        F = _with_band(rng, _features(rng, move=move), move=move)
        out = _select_timing(F, monkeypatch)
        named += bool(out) and (out[0].effect, out[0].sensor) == ("sensor_position", 2)
    assert named >= 2, named


# ---- a move along the look direction: its energies tell it from a delay (docs/findings.md, lookdir) ----
ENERGY_BETA = -1.0   # log-energy per log-distance (geometric spreading, 1/d energy)
ENERGY_SD = 0.1      # nepers per channel and drop


def _moved_along_with_energies(rng, move) -> R.Features:
    """Threshold picks and log-energies of a disc moved by `move` (no band picks): the energies follow the
    true (moved) distances by ENERGY_BETA log d, per-drop source strength and noise ENERGY_SD."""
    from dataclasses import replace

    F = _features(rng, move=move)
    true = SENSORS.copy()
    true[2] += move
    d = np.hypot(F.x_mm[:, None] - true[None, :, 0], F.y_mm[:, None] - true[None, :, 1])
    le = ENERGY_BETA * np.log(d) + rng.normal(0, 1.0, (len(F), 1)) + rng.normal(0, ENERGY_SD, d.shape) + 20.0
    return replace(F, log_energy=le)


def _select_energy(F: R.Features, monkeypatch, by_energy: bool):
    from impactsense import diagnose as D
    from impactsense import move_or_delay as MD
    from impactsense.effects import EFFECTS

    monkeypatch.setattr(D, "EFFECTS", {k: EFFECTS[k] for k in ("sensor_position", "channel_delay")})
    monkeypatch.setattr(MD, "MOVE_BY_ENERGY", by_energy)
    monkeypatch.setattr(MD, "HELD_OUT_FIGURES", by_energy)   # the old rule: neither held-out figure names a move
    ref = _reference()
    ref.beta = ENERGY_BETA
    ref.sigma = {"timing": float(np.hypot(3.0, 2.0)), "energy": ENERGY_SD, "spectrum": 1.0, "decay": 1.0,
                 "noise": 1.0, "hum": 1.0}
    ref.plateau_rate = 0.01
    accepted, _, _ = D.select(ref, F, max_effects=1)
    return accepted


def test_a_move_along_the_look_direction_is_named_by_its_energies(monkeypatch):
    """S3 moved 8.5 mm along its look direction (towards the plate centre): its threshold picks change by a
    near-constant (the tests of a constant name a delay: the old rule named channel_delay[2] on at least 2 of 3
    draws), its energies by ENERGY_BETA x the log of the distance ratio, up to ~0.2 nepers near the disc: the
    move predicts the held-out picks and energies better than the delay by more than n_candidates / ALPHA and
    is named on its disc on at least 2 of 3 draws, within 3 mm (the along-look size trades with the pick
    constant)."""
    move = np.array([-6.0, -6.0])
    old, new = 0, 0
    for seed in range(3):
        F = _moved_along_with_energies(np.random.default_rng(40 + seed), move)
        out = _select_energy(F, monkeypatch, by_energy=False)
        old += bool(out) and (out[0].effect, out[0].sensor) == ("channel_delay", 2)
        out = _select_energy(F, monkeypatch, by_energy=True)
        if out and (out[0].effect, out[0].sensor) == ("sensor_position", 2):
            new += np.hypot(out[0].params["dx_mm"] - move[0], out[0].params["dy_mm"] - move[1]) <= 3.0
    assert old >= 2, old
    assert new >= 2, new


def test_a_delay_with_unchanged_energies_stays_a_delay(monkeypatch):
    """A -7.5 us delay on S3, energies at the declared discs: the delay is named on all 3 draws with the rule."""
    from dataclasses import replace

    for seed in range(3):
        rng = np.random.default_rng(50 + seed)
        F = _moved_along_with_energies(rng, np.zeros(2))
        F = replace(F, toa_us=F.toa_us + np.r_[0.0, 0.0, -7.5, 0.0])
        (c,) = _select_energy(F, monkeypatch, by_energy=True)
        assert (c.effect, c.sensor) == ("channel_delay", 2), (seed, c.effect, c.params, c.rival)


# ---- either held-out figure, Bonferroni over the two (docs/findings.md, loop16) ----
def test_a_move_beats_the_delay_on_either_figure_at_the_two_figure_bound(monkeypatch):
    """`move_beats_delay`: the move over the delay on the held-out picks alone or on the picks and energies, each
    against ln(2 n / alpha) (two figures of one comparison). A move the picks favour by 9 nats and the energy law
    drags to 5.4 (a measured move's figures: docs/findings.md, loop16) passes; 6.5 on both (over the one-figure bound ln(n / alpha)
    = 6.33 with 28 candidates, under the two-figure 7.02) does not; the delay better on both does not.
    EITHER_FIGURE off: the picks-and-energies figure alone at ln(n / alpha)."""
    from impactsense import move_or_delay as MD

    def per_drop(total):
        return np.full(120, total / 120)

    both = {0: per_drop(9.0), 1: per_drop(6.5), 2: per_drop(-20.0), 3: per_drop(2.0)}
    energy = {0: per_drop(5.4), 1: per_drop(6.5), 2: per_drop(-25.0), 3: per_drop(7.5)}
    assert MD.move_beats_delay(both, energy, 28, 0.05) == {0, 3}
    monkeypatch.setattr(MD, "EITHER_FIGURE", False)
    assert MD.move_beats_delay(both, energy, 28, 0.05) == {1, 3}


def _along_with_outlier_cases(rng, move, delay_us: float = 0.0) -> R.Features:
    """S3 moved by `move` (or delayed by delay_us), threshold picks as `_features`, band picks at their own
    slowness with heavy-tailed case errors (3 us x t with 1.5 dof: a few cases far off, as the measured band
    picks: the per-case t-test loses them, the Huber likelihood does not) and log-energies at the declared discs
    (the energy law reads no move)."""
    from dataclasses import replace

    F = _features(rng, move=move, delay_us=delay_us)
    true = SENSORS.copy()
    true[2] += move
    d = np.hypot(F.x_mm[:, None] - true[None, :, 0], F.y_mm[:, None] - true[None, :, 1])
    tb = (BAND_SLOWNESS * d + 3.0 * rng.standard_t(1.5, (CASES, 4))[F.case_id] + rng.normal(0, 2.0, d.shape)
          + 35.0)
    tb[:, 2] += delay_us
    d0 = np.hypot(F.x_mm[:, None] - SENSORS[None, :, 0], F.y_mm[:, None] - SENSORS[None, :, 1])
    le = ENERGY_BETA * np.log(d0) + rng.normal(0, 1.0, (len(F), 1)) + rng.normal(0, ENERGY_SD, d.shape) + 20.0
    return replace(F, toa_band_us=tb, log_energy=le)


@pytest.mark.slow
def test_either_figure_names_no_delay_a_move_and_misses_no_move_the_old_rule_named(monkeypatch):
    """S3 moved 7.1 mm along its look direction with outlier-prone band picks and energies that read no move
    (16 draws), and a -7.5 us delay with the same noise (16 draws). The either-figure rule (EITHER_FIGURE,
    HELD_OUT_FIGURES) against the picks-and-energies rule alone: the move is named within 3 mm on at least as
    many draws (measured 9 -> 10 of 16), and every delay stays a delay (measured 16 of 16 both ways). ~4 min."""
    from impactsense import diagnose as D
    from impactsense import move_or_delay as MD
    from impactsense.effects import EFFECTS

    monkeypatch.setattr(D, "EFFECTS", {k: EFFECTS[k] for k in ("sensor_position", "channel_delay")})

    def select(F, new):
        monkeypatch.setattr(MD, "EITHER_FIGURE", new)
        monkeypatch.setattr(MD, "HELD_OUT_FIGURES", new)
        ref = _band_reference()
        ref.band["sigma_us"] = float(np.hypot(3.0, 3.0))
        ref.beta = ENERGY_BETA
        ref.sigma = {"timing": float(np.hypot(3.0, 2.0)), "energy": ENERGY_SD, "spectrum": 1.0, "decay": 1.0,
                     "noise": 1.0, "hum": 1.0}
        ref.plateau_rate = 0.01
        return D.select(ref, F, max_effects=1)[0]

    move = np.array([-5.0, -5.0])
    moves = {False: 0, True: 0}
    for seed in range(16):
        rng = np.random.default_rng(100 + seed)
        F = _along_with_outlier_cases(rng, move)
        for new in (False, True):
            out = select(F, new)
            moves[new] += bool(out) and (out[0].effect, out[0].sensor) == ("sensor_position", 2) and bool(
                np.hypot(out[0].params["dx_mm"] - move[0], out[0].params["dy_mm"] - move[1]) <= 3.0)
        F = _along_with_outlier_cases(rng, np.zeros(2), delay_us=-7.5)
        out = select(F, True)
        assert out and (out[0].effect, out[0].sensor) == ("channel_delay", 2), (seed, out and out[0].effect)
    assert moves[True] >= moves[False], moves


def test_the_delay_is_named_where_the_channels_move_has_the_evidence():
    """`move_or_delay.name_the_delay_of_an_evident_move`: a channel whose move has the evidence against no change
    (not named: no test rejects a constant) names its delay when the delay's held-out ratio reaches
    ln(n / ALPHA) though its per-case t-test misses (a measured delay: 19.3 nats, p 0.06; docs/findings.md, loop16); not
    without the move's evidence, nor under the bound, nor where a rival is already named on the channel."""
    from impactsense import diagnose as D
    from impactsense import move_or_delay as MD

    def cands(delay_score, named_move=False):
        return [D.Candidate("sensor_position", 2, {"dx_mm": -4.0, "dy_mm": -2.3, "offset_mm": 4.6}, 20.3, 0.031,
                            True, named_move, []),
                D.Candidate("channel_delay", 2, {"delay_us": -2.8}, delay_score, 0.06, True, False, [])]

    n = 28   # ln(28 / 0.05) = 6.33
    out = cands(19.3)
    MD.name_the_delay_of_an_evident_move(out, {("sensor_position", 2)}, n, 0.05)
    assert out[1].significant
    out = cands(19.3)
    MD.name_the_delay_of_an_evident_move(out, set(), n, 0.05)
    assert not out[1].significant
    out = cands(6.0)
    MD.name_the_delay_of_an_evident_move(out, {("sensor_position", 2)}, n, 0.05)
    assert not out[1].significant
    out = cands(19.3, named_move=True)
    MD.name_the_delay_of_an_evident_move(out, {("sensor_position", 2)}, n, 0.05)
    assert not out[1].significant


def test_a_moves_own_evidence_needs_the_scaled_bound():
    """`move_or_delay.MOVE_EVIDENCE_SCALE`: on unchanged sessions the move's own held-out ratio reached ~11 nats
    with per-case p ~0.035 (a false move by the plain bound ln(28 / 0.05) = 6.33), the weakest true move named
    18.2 nats at p 0.036 (docs/findings.md, falsealarm). At the scaled bound (2 x 6.33 = 12.7) the first has no
    evidence of its own, the second keeps it; the delay's own bound and the Bonferroni path are unchanged."""
    from impactsense import diagnose as D
    from impactsense import move_or_delay as MD

    n = 28
    move = MD.own_evidence_scale("sensor_position")
    assert 1.5 <= move <= 3.0 and MD.own_evidence_scale("channel_delay") == 1.0
    assert D._evidence(10.9, 0.035, n) and not D._evidence(10.9, 0.035, n, move)
    assert D._evidence(18.2, 0.036, n, move)
    assert D._evidence(10.9, 0.001, n, move)          # per-case gains at alpha / n: no ratio bound
    assert not D._evidence(18.2, 0.06, n, move)       # the ratio alone is never enough
