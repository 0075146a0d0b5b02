"""One executor for batches (impactsense.sim.executor): local threads / processes, or a Dask cluster.

- local: results in the tasks' order, for threads and processes; inside a daemonic worker process the
  "processes" tasks run in turn (such a process may not start children);
- a Dask LocalCluster (one worker process, so every task and result crosses a process boundary as it would on
  a real cluster): the same drops simulated through `--scheduler` are bit for bit the local ones for the
  direct FEM (the drops split into chunks over the worker's threads), and within float32 rounding (1e-5 of the
  peak) for the modal solver (the basis computed here first, loaded from the shared cache by the worker; a
  modal batch's float32 sums depend on which drops share it); `simulate-dataset --scheduler` writes the same
  session as without; with a process-wide scheduler the basis' inertia counts and slices run on the cluster
  and give the local basis. Skipped with a reason when dask.distributed is not installed (`impactsense[cluster]`;
  the test extra installs it).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from impactsense.sim import SimParams, simulate_voltages
from impactsense.sim import executor
from impactsense.sim.executor import Executor

from test_sim_modal import small_rig


def _square(v):
    return v * v


@pytest.mark.parametrize("kind", ["threads", "processes"])
def test_local_executor_keeps_the_tasks_order(kind):
    assert list(Executor("", workers=2, kind=kind).map(_square, range(7))) == [v * v for v in range(7)]
    assert list(Executor("", workers=1).map(_square, [3])) == [9]
    with pytest.raises(ValueError):
        Executor("", kind="fibres")


def _nested_map(n):
    return list(Executor("", workers=2, kind="processes").map(_square, range(n)))


def test_processes_inside_a_worker_process_run_in_turn():
    """A daemonic worker (a Dask worker computing a basis, a Pool worker) may not start processes."""
    import multiprocessing

    with multiprocessing.get_context("spawn").Pool(1) as pool:
        assert pool.apply(_nested_map, (4,)) == [0, 1, 4, 9]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    distributed = pytest.importorskip("distributed", reason="dask.distributed not installed (impactsense[cluster])")
    import os

    cache = tmp_path_factory.mktemp("modal-cache")
    old = os.environ.get("IMPACTSENSE_MODAL_CACHE")
    os.environ["IMPACTSENSE_MODAL_CACHE"] = str(cache)      # the worker process inherits it: a shared cache
    env = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=True, dashboard_address=None,
                                  env=env) as lc:
        yield lc.scheduler_address
    if old is None:
        os.environ.pop("IMPACTSENSE_MODAL_CACHE", None)
    else:
        os.environ["IMPACTSENSE_MODAL_CACHE"] = old


@pytest.mark.parametrize("solver", ["direct", "modal"])
def test_drops_on_a_dask_cluster_equal_the_local_ones(cluster, solver):
    rig = small_rig()
    p = SimParams.from_rig(rig, element_mm=6.0, duration_ms=1.0, taper_ms=0.2)
    x = np.array([40.0, 60.0, 85.0, 70.0, 50.0])
    y = np.array([35.0, 60.0, 45.0, 30.0, 70.0])
    h = np.array([120.0, 150.0, 175.0, 100.0, 140.0])
    local = simulate_voltages(p, rig, x, y, h, solver=solver, method="direct", scheduler="")
    remote = simulate_voltages(p, rig, x, y, h, solver=solver, method="direct", scheduler=cluster)
    assert Executor(cluster).parallelism() == 2
    assert remote["volts"].shape == local["volts"].shape == (5, 4, local["model"].n_record)
    if solver == "direct":
        assert np.array_equal(remote["volts"], local["volts"])
    else:   # a modal batch's float32 products depend on which drops share it (its window and sample split)
        assert np.allclose(remote["volts"], local["volts"], rtol=0, atol=1e-5 * np.abs(local["volts"]).max())
    assert np.array_equal(remote["contacts"], local["contacts"])
    assert np.array_equal(remote["contact_s"], local["contact_s"])


def test_simulate_dataset_with_scheduler_writes_the_local_session(cluster, tmp_path):
    from impactsense.cli import main
    from impactsense.data import load_session

    params = tmp_path / "p.json"
    params.write_text(json.dumps({"element_mm": 8.0, "duration_ms": 1.0, "taper_ms": 0.2}))
    common = ["simulate-dataset", "--params", str(params), "--n", "6", "--solver", "direct"]
    try:
        assert main(common + ["--out", str(tmp_path / "remote"), "--scheduler", cluster]) == 0
    finally:
        executor.set_scheduler(None)
    assert main(common + ["--out", str(tmp_path / "local")]) == 0
    a, b = load_session(tmp_path / "remote"), load_session(tmp_path / "local")
    assert np.array_equal(a.adc, b.adc) and a.adc.shape[0] == 6


def test_basis_slices_on_a_dask_cluster_give_the_local_basis(cluster):
    """With a process-wide scheduler (the CLI's --scheduler) the basis' inertia counts and slices run on the
    cluster: the same modes as in local processes."""
    from impactsense.sim import modal_basis
    from impactsense.sim.model import build_model

    rig = small_rig()
    model = build_model(SimParams.from_rig(rig, element_mm=6.0, duration_ms=1.0, taper_ms=0.2), rig)
    local = modal_basis.compute_basis(model)
    from distributed import get_task_stream

    executor.set_scheduler(cluster)
    try:
        with get_task_stream(client=executor.client(cluster)) as stream:
            remote = modal_basis.compute_basis(model)
    finally:
        executor.set_scheduler(None)
    ran = {str(t["key"]).split("-")[0].strip("('\"") for t in stream.data}
    assert {"_count_task", "_slice_task"} <= ran
    assert remote.modes == local.modes > 20
    assert np.allclose(remote.omega, local.omega, rtol=1e-9, atol=0)
    assert np.allclose(remote.residual, local.residual, rtol=0, atol=1e-6 * np.abs(local.residual).max())


def test_in_background_gives_the_result_and_raises_the_tasks_error_in_the_caller():
    import threading

    from impactsense.errors import DataError
    from impactsense.sim.executor import in_background

    names = []
    done = in_background(lambda: names.append(threading.current_thread().name) or 42, "worker-a")
    assert done() == 42 and names == ["worker-a"]          # ran in its own thread, its value returned

    def broken():
        raise DataError("x.npz", "adc", "truncated")
    failed = in_background(broken, "worker-b")
    with pytest.raises(DataError, match="truncated"):
        failed()
