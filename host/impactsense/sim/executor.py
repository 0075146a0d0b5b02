"""One executor for batches (site maps, virtual sets, calibration designs and grids).

- Local (the default): the tasks run in this process's threads (`kind="threads"`: the C++ kernel and BLAS
  release the GIL) or in worker processes (`kind="processes"`: Python-heavy tasks), `workers` at a time.
- A Dask cluster when a scheduler address is given (`--scheduler ADDRESS` on the batch commands, or
  `set_scheduler` for the whole process): the tasks go to the cluster's workers (dask.distributed; the
  optional extra `impactsense[cluster]`). A task is a module-level function and picklable arguments.
- Inside a worker process (daemonic: a Dask worker computing a basis its cache lacks), "processes" runs the
  tasks one after the other instead.

Results come back in the order of the tasks either way.
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from typing import Callable, Iterable, Iterator

from ..errors import ConfigError

_scheduler: str | None = None     # the process-wide default (the CLI's --scheduler)
_clients: dict = {}


def set_scheduler(address: str | None) -> None:
    """The Dask scheduler every batch of this process uses (None: local)."""
    global _scheduler
    _scheduler = address or None


def scheduler() -> str | None:
    return _scheduler


def client(address: str):
    """A dask.distributed Client connected to `address` (one per address and process)."""
    if address in _clients:
        return _clients[address]
    try:
        from distributed import Client
    except ImportError as exc:
        raise ConfigError(f"--scheduler {address}: dask.distributed is not installed "
                          "(pip install 'impactsense[cluster]')") from exc
    try:
        c = Client(address, set_as_default=False, timeout=10)
    except (OSError, TimeoutError) as exc:
        raise ConfigError(f"--scheduler {address}: no Dask scheduler answers there ({exc})") from exc
    _clients[address] = c
    return c


def cluster_threads(address: str) -> int:
    """Worker threads of the cluster at `address` (at least 1)."""
    return max(1, sum(client(address).nthreads().values()))


def _daemonic() -> bool:
    """True inside a daemonic process (a Dask or multiprocessing worker), which may not start processes."""
    import multiprocessing

    return bool(multiprocessing.current_process().daemon)


class Executor:
    """map(fn, tasks): fn(task) for every task, results in order (module doc)."""

    def __init__(self, scheduler_address: str | None = None, *, workers: int = 2, kind: str = "threads"):
        if kind not in ("threads", "processes"):
            raise ValueError(f"kind must be 'threads' or 'processes', got {kind!r}")
        self.address = scheduler_address if scheduler_address is not None else scheduler()
        self.workers = max(1, int(workers))
        self.kind = kind

    @property
    def distributed(self) -> bool:
        return bool(self.address)

    def parallelism(self) -> int:
        """How many tasks run at once."""
        return cluster_threads(self.address) if self.distributed else self.workers

    def map(self, fn: Callable, tasks: Iterable) -> Iterator:
        tasks = list(tasks)
        if self.distributed:
            futures = client(self.address).map(fn, tasks, pure=False)
            try:
                for fut in futures:
                    yield fut.result()
            finally:
                for fut in futures:
                    fut.cancel()
            return
        if self.workers == 1 or len(tasks) <= 1 or (self.kind == "processes" and _daemonic()):
            for t in tasks:
                yield fn(t)
            return
        pool_type = ThreadPoolExecutor if self.kind == "threads" else ProcessPoolExecutor
        with pool_type(max_workers=self.workers) as pool:
            yield from pool.map(fn, tasks)


def in_background(task: Callable[[], object], name: str) -> Callable[[], object]:
    """`task()` started in a daemon thread (the C++ kernel releases the GIL, so it takes the second core while
    this thread goes on). Returns a callable that waits for it and gives its result, or re-raises its error
    in the caller's thread."""
    import threading

    got: dict = {}

    def run():
        try:
            got["result"] = task()
        except BaseException as exc:        # re-raised where the result is needed
            got["error"] = exc

    thread = threading.Thread(target=run, name=name, daemon=True)
    thread.start()

    def result():
        thread.join()
        if "error" in got:
            raise got["error"]
        return got["result"]
    return result
