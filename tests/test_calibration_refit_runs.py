"""The calibration's E refit and its nu identifiability share FEM runs (`stages.REFIT_RATIOS`): when E stays where
the refit's scan started, the identifiability's ln E difference is taken on the scan's own outer points, so
it pays only the two runs along nu at fixed bending stiffness; its derivative is still d obs / d ln E."""

import numpy as np

from impactsense.calibration import plate_fem
from impactsense.calibration.stages import REFIT_RATIOS


def test_identifiability_reuses_the_refit_scans_runs_and_keeps_its_derivative():
    names = plate_fem.names()
    k = len(names)
    slope = np.linspace(-3.0, 3.0, 4 * k * 6).reshape(4, k, 6)      # d obs / d ln E, us
    bend = np.linspace(1.0, 2.0, 4 * k * 6).reshape(4, k, 6)        # d obs / d nu at fixed D, us
    e_true, nu = 4500.0, 0.35
    stiff = e_true / (1 - nu ** 2)

    def obs(e_mpa, nu_):
        # a plate whose observables follow ln E linearly (the AIC DToA's minimum at e_true) and nu at fixed D
        d_nu = nu_ - nu
        e_at_d = stiff * (1 - nu_ ** 2)
        return slope * np.log(e_mpa / e_at_d) + bend * d_nu

    calls = []

    def counted(e_mpa, nu_):
        calls.append((e_mpa, nu_))
        return obs(e_mpa, nu_)

    meas = plate_fem.PlateTargets(dtoa=obs(e_true, nu), sigma=np.ones(k), names=names)
    ev = plate_fem.Evaluations(counted)
    e_fit, scan = plate_fem.e_scan(ev, meas, e_true, nu, (1000.0, 9000.0), ratios=REFIT_RATIOS, walk=1.03,
                                   observables=[0])
    assert e_fit == e_true                      # the scan's minimum is its start: E stayed
    n_scan = len(calls)
    ident = plate_fem.nu_identifiability(ev, meas, e_fit, nu, e_ratios=(REFIT_RATIOS[0], REFIT_RATIOS[-1]))
    assert len(calls) - n_scan == 2              # only nu +- d_nu at fixed bending stiffness are new runs
    # the ln E derivative is the plate's: per 1 % of E, rms over the drops and pairs of slope x 0.01 (within the
    # Evaluations' 0.01 MPa rounding of E: ~1e-4 of a 6 % difference)
    for i, n in enumerate(names):
        assert abs(ident["per_1pct_E_us"][n] / (np.sqrt(np.mean(slope[:, i] ** 2)) * 0.01) - 1) < 1e-4
    # the default (symmetric exp(+-0.03) points) gives the same figures with two more runs
    plain = plate_fem.nu_identifiability(plate_fem.Evaluations(obs), meas, e_fit, nu)
    assert all(abs(plain["per_1pct_E_us"][n] / ident["per_1pct_E_us"][n] - 1) < 1e-4 for n in names)
    assert abs(plain["sd_nu"] / ident["sd_nu"] - 1) < 1e-4
