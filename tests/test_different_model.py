"""Calibration on data a different model made: the drops come from the FEM on a finer mesh (3.5 mm) than the
twin that fits them (5 mm), with the rig's noise and 1 mm landing scatter; the fit starts from the true
plate values (as test_disc_bond does; not yet from the pipeline's own estimates). Unlike tests/test_disc_bond.py (`..._same_model`: the same 5 mm FEM makes
and fits the drops) the mesh's discretisation error stands in for the twin's model error, so the tolerance
is wider and stated against that error."""

from pathlib import Path

import numpy as np
import pytest

from impactsense.calibration import disc_bond, fem

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
@pytest.mark.skipif(not fem.available(), reason="FEM simulator not built")
def test_disc_bond_from_finer_mesh_drops(tmp_path):
    """Four cases the 3.5 mm FEM made with discs at 0.4 of their bonded stiffness, fitted by the 5 mm twin
    (~90 s): the scale within 0.05 of 0.4, and the bonded disc fits the group delays at least 1.5x worse
    than the fit. The mesh's own error shows in the misfit: chi^2 / dof at the fit is ~80 here against ~1
    when the same mesh makes and fits the drops (test_disc_bond's `..._same_model`, which asserts < 3 and
    a 20x worse bonded disc: figures only an inverse crime reaches; docs/findings.md). The misfit sits in the
    5-15 kHz band (21 us rms against ~3 us in 1-3 and 2-5 kHz): a 5 mm mesh does not resolve it, and no E
    takes it away (E x0.94-1.03 all fit worse), so the bands it resolves are held to 4 us."""
    from impactsense.calibration import drops, pipeline
    from impactsense.calibration.problem import DropsAndTwin
    from impactsense.data import load_session
    from test_calibrate import _session

    from impactsense.sim import SimParams, simulate_drops

    rig = load_session(ROOT / "host/impactsense/data/session-1").rig
    truth = dict(fem.base_params(rig, 4500.0, 0.36), damping_per_s=850.0, pzt_d31_pc_n=-300.0,
                 disc_stiffness_scale=0.4)

    def fine(p, rig_, x, y, h):
        return simulate_drops(SimParams.from_rig(rig_, **p, element_mm=3.5, duration_ms=12.0), rig_, x, y, h,
                              noise=True, seed=5, progress=False)

    session = load_session(_session(tmp_path, rig, fine, truth, n_cases=4, reps=3))
    cfg = pipeline.measured_core_config(rig, pipeline.CalibrateOptions())
    feats = drops.extract(session, cfg)
    targets = drops.select_drops(session, feats, [0, 1, 2, 3], tol_us=20.0)
    coarse_twin = DropsAndTwin(session, targets, feats, cfg, pipeline.sim_core_config(rig, pipeline.CalibrateOptions()),
                               fem.fem_simulator(2, element_mm=5.0), (1.5, 4, 0))
    start = {k: v for k, v in truth.items() if k != disc_bond.FIELD}
    out = disc_bond.fit(coarse_twin, start)
    assert abs(out["scale"] - 0.4) < 0.05, (out["scale"], out["chi2_dof"])
    assert out["chi2_dof_bonded"] > 1.5 * out["chi2_dof_fit"], out["chi2_dof"]
    assert np.isfinite(out["chi2_dof_fit"])
    # the bands the 5 mm mesh resolves fit to ~3 us (bonded disc: 8.3 / 6.1 us); the 5-15 kHz band's ~21 us
    # is the mesh's own dispersion error, the same at any E or bond (docs/findings.md)
    low = [v for k, v in out["rms_us_fit"].items() if "5-15" not in k]
    assert len(low) == 2 and max(low) <= 4.0, out["rms_us_fit"]
