"""Where a batch of step tests runs: this process, a local process pool, or a Dask cluster.

Everything returned has the `concurrent.futures` shape the sweep uses — ``submit(fn, *args)``
giving a future with ``result()`` — so one code path serves them all (a `distributed.Client`
has that shape too). hilbench runs no coordinator of its own: a lab's Dask scheduler is named by
its address, ``tcp://host:8786``; ``local-dask[:N]`` starts a LocalCluster for trying it.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Iterator, Protocol

from hilbench.config import clipped
from hilbench.errors import ConfigError

#: the most processes a local cluster is started with
MAX_LOCAL_WORKERS = 256
EXECUTOR_FORMS = "local (a process pool; --workers N), local-dask[:N] (a Dask LocalCluster) or tcp://HOST:PORT (a Dask scheduler)"


class Executor(Protocol):
    def submit(self, fn: Callable[..., Any], *args: Any) -> Any: ...


class _Deferred:
    """A task of `InThisProcess`: it runs when its result is asked for, so a sweep collecting
    results in order runs (and stores) them one by one."""

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        self._fn, self._args = fn, args

    def result(self) -> Any:
        return self._fn(*self._args)


class InThisProcess:
    """The executor of one worker: each task runs in this process when its result is asked for
    (no pickling, no process)."""

    def submit(self, fn: Callable[..., Any], *args: Any) -> _Deferred:
        return _Deferred(fn, args)


def tasks_in_flight(pool: Executor) -> int:
    """How many tasks a caller keeps submitted at once: two per worker. A caller that submits this
    many, reads each result in order and drops its future holds this window's results in memory,
    not the whole batch's (a finished future keeps its result for as long as it lives)."""
    if isinstance(pool, InThisProcess):
        return 1
    if isinstance(pool, ProcessPoolExecutor):
        return 2 * max(1, pool._max_workers)  # type: ignore[attr-defined]
    scheduler_info = getattr(pool, "scheduler_info", None)  # a distributed.Client
    if callable(scheduler_info):
        try:
            return 2 * max(1, len(scheduler_info().get("workers", {})))
        except Exception:  # noqa: BLE001 - a scheduler that does not say: the local guess below
            pass
    return 2 * (os.cpu_count() or 1)


def _dask() -> Any:
    try:
        import distributed
    except ImportError:
        raise ConfigError("a Dask executor needs the dask extra: pip install 'hilbench[dask]'") from None
    return distributed


@contextlib.contextmanager
def open_executor(spec: str | None, workers: int | None) -> Iterator[tuple[Executor, str]]:
    """The executor named by ``spec`` (None: local) and a one-line description of it."""
    spec = (spec or "local").strip()
    if spec == "local":
        n = max(1, workers or os.cpu_count() or 1)
        if n == 1:
            yield InThisProcess(), "this process"
            return
        from hilbench.processes import worker_init

        with ProcessPoolExecutor(max_workers=n, initializer=worker_init, initargs=(os.getpid(),)) as pool:  # die with us
            try:
                yield pool, f"a local pool of {n} processes"
            except BaseException:  # a task failed, Ctrl-C: the queued tasks are not run first
                pool.shutdown(wait=True, cancel_futures=True)
                raise
        return
    if spec == "local-dask" or spec.startswith("local-dask:"):
        count = spec.partition(":")[2]
        try:
            n = int(count) if count else min(max(1, workers or os.cpu_count() or 1), MAX_LOCAL_WORKERS)
        except ValueError:
            n = 0
        if not 1 <= n <= MAX_LOCAL_WORKERS:  # (0 workers: a cluster that never runs a task)
            raise ConfigError(f"executor {clipped(repr(spec), 60)}: expected local-dask:N with N a number of workers, "
                              f"1 to {MAX_LOCAL_WORKERS}")
        distributed = _dask()
        import dask  # distributed's own dependency

        # the scheduler's and the workers' scratch space (dask-scratch-space in /tmp otherwise) goes with the
        # cluster; a removal that fails (a worker still writing as a failed sweep ends) hides no error
        with (tempfile.TemporaryDirectory(prefix="hilbench-dask-", ignore_cleanup_errors=True) as scratch,
              dask.config.set({"temporary-directory": scratch}),
              distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                                       local_directory=scratch) as cluster,
              distributed.Client(cluster) as client):
            yield client, f"a local Dask cluster of {n} workers"
        return
    if spec.startswith(("tcp://", "tls://", "dask://")):
        address = "tcp://" + spec.split("://", 1)[1] if spec.startswith("dask://") else spec
        distributed = _dask()
        try:
            client = distributed.Client(address, timeout="10s")
        except OSError as exc:
            raise ConfigError(f"executor {spec}: cannot reach the Dask scheduler ({exc})") from None
        with client:
            yield client, f"the Dask cluster at {address}"
        return
    raise ConfigError(f"executor {spec!r}: unknown (use {EXECUTOR_FORMS})")


__all__ = ["EXECUTOR_FORMS", "Executor", "InThisProcess", "open_executor", "tasks_in_flight"]
