"""The calibration's nu stage (`calibration.plate_nu.fit`) declares how many twin runs it may make
(`max_evaluations`), so `impactsense calibrate` shows the stage's bar with a total and an ETA: every twin run
advances the bar by one, the count never passes the total, and a fit that stops early ends at its total."""

from itertools import combinations

import numpy as np
import pytest

from impactsense.calibration import group_delay, plate_nu

SENSORS = np.array([[10.0, 10.0], [310.0, 10.0], [310.0, 307.0], [10.0, 307.0]])
PAIRS = list(combinations(range(4), 2))


def twin(e_mpa, nu, d_s, x, y, h):
    """Band group delays [R, 3, 6] of a dispersive plate: per band a velocity from the bending stiffness, nu
    setting how the bands differ, D_s a band-dependent lag, the six sensor pairs' path differences."""
    d = np.hypot(np.asarray(x)[:, None] - SENSORS[:, 0], np.asarray(y)[:, None] - SENSORS[:, 1])      # [R, 4]
    band = np.arange(3)
    v = 0.3 * np.sqrt(e_mpa / 4000.0 / (1 - nu ** 2)) * (1 + 2.0 * (nu - 0.35) * (band + 1))         # [3]
    diff = np.stack([d[:, j] - d[:, i] for i, j in PAIRS], axis=-1)                                    # [R, 6]
    return diff[:, None, :] / v[None, :, None] * (1 + 1e-4 * d_s * (band[None, :, None] - 1))


@pytest.mark.parametrize("rounds, start", [(1, (4000.0, 0.35, 700.0)), (2, (3300.0, 0.32, 900.0))])
def test_nu_fit_progress_reaches_its_declared_total(rounds, start):
    rng = np.random.default_rng(1)
    x, y = rng.uniform(60, 260, 8), rng.uniform(60, 260, 8)
    h = np.full(8, 150.0)
    truth = (4200.0, 0.36, 800.0)
    per_rep = twin(*truth, x + rng.normal(0, 0.5, 8), y + rng.normal(0, 0.5, 8), h) + rng.normal(0, 0.3, (8, 3, 6))
    calls, steps = [0], []

    def counted(*args):
        calls[0] += 1
        return twin(*args)

    total = plate_nu.max_evaluations(rounds)
    res = plate_nu.fit(counted, per_rep, np.full(3, 0.3), group_delay.names(), x, y, h, start,
                       ds_prior=(800.0, 80.0), rounds=rounds, progress=steps.append)
    assert sum(steps) == total                    # the bar closes at 100 %
    assert steps[:calls[0]] == [1] * calls[0]     # one step per twin run while it works ...
    assert calls[0] <= total                      # ... never more than declared
    assert len(steps) in (calls[0], calls[0] + 1)
    # the bound is a usable ETA, not a wild one: at least a third of it is spent
    assert calls[0] >= total / 3
    assert abs(res.nu - truth[1]) < 0.02 and abs(res.e_mpa / truth[0] - 1) < 0.05


def test_max_evaluations_holds_when_the_fit_runs_out_of_trial_points():
    """A trust-region fit stopped by max_nfev (a start far off, two trial points) still stays in its bound."""
    rng = np.random.default_rng(2)
    x, y, h = rng.uniform(60, 260, 5), rng.uniform(60, 260, 5), np.full(5, 150.0)
    per_rep = twin(5000.0, 0.38, 600.0, x, y, h)
    calls, steps = [0], []

    def counted(*args):
        calls[0] += 1
        return twin(*args)

    plate_nu.fit(counted, per_rep, np.full(3, 0.3), group_delay.names(), x, y, h, (2500.0, 0.31, 1000.0),
                 rounds=2, max_nfev=2, progress=steps.append)
    assert calls[0] <= plate_nu.max_evaluations(2, max_nfev=2) == sum(steps)


def test_a_twin_far_off_stops_after_its_first_round():
    """Group delays the twin cannot explain (chi^2 / dof far above the claim's limit after round 1): the later
    rounds are not run (they refine, they cannot make nu claimable), the bar still closes at its total, and nu
    is not claimed; a twin that explains them runs every round."""
    rng = np.random.default_rng(3)
    x, y, h = rng.uniform(60, 260, 6), rng.uniform(60, 260, 6), np.full(6, 150.0)
    clean = twin(4200.0, 0.36, 800.0, x, y, h)
    off = clean + rng.normal(0, 6.0, clean.shape)          # 20 x the sigma below, no model makes it
    steps = []
    res = plate_nu.fit(twin, off, np.full(3, 0.3), group_delay.names(), x, y, h, (4000.0, 0.35, 800.0),
                       ds_prior=(800.0, 80.0), rounds=2, progress=steps.append)
    assert len(res.rounds) == 1 and "stopped" in res.rounds[0]
    assert res.chi2_dof > plate_nu.STOP_CHI2_DOF
    assert sum(steps) == plate_nu.max_evaluations(2)
    assert not res.identified((0.30, 0.40))[0]
    good = plate_nu.fit(twin, clean + rng.normal(0, 0.3, clean.shape), np.full(3, 0.3), group_delay.names(), x, y,
                        h, (4000.0, 0.35, 800.0), ds_prior=(800.0, 80.0), rounds=2)
    assert len(good.rounds) == 2 and not any("stopped" in r for r in good.rounds)


def test_a_hopeless_round_is_judged_before_its_fit_and_a_far_start_is_not():
    """The round's trust-region fit is not run when its linearised optimum (the Jacobian it would start with)
    stays far above the claim's limit: only the position fit, the position Jacobian and the start's Jacobian
    are paid, and not the position fit either when the optimum from the declared positions (their linear
    freedom projected out) stays above a wider limit. A start far from the truth on group delays the twin
    explains (chi^2 / dof in the thousands at the start) is not mistaken for one: the prediction sees the fit
    reach them, and the fit runs."""
    rng = np.random.default_rng(3)
    x, y, h = rng.uniform(60, 260, 6), rng.uniform(60, 260, 6), np.full(6, 150.0)
    clean = twin(4200.0, 0.36, 800.0, x, y, h)
    calls = [0]

    def counted(*args):
        calls[0] += 1
        return twin(*args)

    off = clean + rng.normal(0, 6.0, clean.shape)
    res = plate_nu.fit(counted, off, np.full(3, 0.3), group_delay.names(), x, y, h, (4000.0, 0.35, 800.0),
                       ds_prior=(800.0, 80.0), rounds=2)
    assert "stopped" in res.rounds[0] and res.rounds[0]["fem_runs"] == 4     # the start and its 3 differences
    # far above even the wider limit at the declared positions: the position fit is not run either (the
    # position Jacobian's four runs, the start and its three differences)
    assert res.rounds[0]["positions"] == "declared" and calls[0] == 4 + 1 + 3
    assert res.rounds[0]["chi2_predicted"] / res.dof > plate_nu.EARLY_STOP_CHI2_DOF
    assert not res.identified((0.30, 0.40))[0]
    # between the two limits: the positions are fitted and the round judged again from them, as before
    calls[0] = 0
    mid = plate_nu.fit(counted, clean + rng.normal(0, 2.0, clean.shape), np.full(3, 0.3), group_delay.names(), x,
                       y, h, (4000.0, 0.35, 800.0), ds_prior=(800.0, 80.0), rounds=2)
    assert "stopped" in mid.rounds[0] and "positions" not in mid.rounds[0]
    assert plate_nu.STOP_CHI2_DOF < mid.rounds[0]["chi2_predicted"] / mid.dof
    assert mid.rounds[0]["chi2_dof_predicted_at_declared_positions"] < plate_nu.EARLY_STOP_CHI2_DOF
    assert 8 + 1 + 3 * plate_nu.POSITION_ITERS + 4 + 4 >= calls[0] > 8 + 3 * plate_nu.POSITION_ITERS
    far = plate_nu.fit(twin, clean + rng.normal(0, 0.3, clean.shape), np.full(3, 0.3), group_delay.names(), x, y,
                       h, (2500.0, 0.31, 1000.0), ds_prior=(800.0, 80.0), rounds=2)
    assert far.rounds[0]["chi2_start"] / far.rounds[0]["dof"] > 100 * plate_nu.STOP_CHI2_DOF
    assert not any("stopped" in r for r in far.rounds)
    assert far.identified((0.30, 0.40))[0] and abs(far.nu - 0.36) < 0.01
