"""Executors: one code path over :class:`concurrent.futures.Executor` for every way of running a campaign.

- ``serial``: in the driver process, one run after the other (debugging, ``rerun``; a worker death is the
  driver's death here).
- ``local``: a :class:`~concurrent.futures.ProcessPoolExecutor` (``forkserver``: workers fork from a clean
  server process that has imported the job's modules once, no inherited threads), one BLAS/OpenMP thread per
  worker (the driver's environment gets the ``*_NUM_THREADS=1`` variables for its children); after a worker
  dies the broken pool is shut down and a new one built
  (:meth:`ExecutorHandle.rebuild`), and the driver resubmits.
- ``dask://HOST:PORT``: an existing Dask scheduler, through ``distributed.Client(address).get_executor()``.
- ``dask-local``: a :class:`distributed.LocalCluster` of worker processes bound to 127.0.0.1 (one thread each).

With Dask the scheduler is told not to retry a task whose worker died (``allowed-failures`` 0): the driver's own
retry rule applies on every executor (:mod:`oacli.campaign.driver`).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

from oacli.campaign.jobs import BLAS_ENV, pin_threads
from oacli.errors import InputError

EXECUTOR_HELP = "serial | local | dask-local | dask://HOST:PORT"


class SerialExecutor(Executor):
    """Runs each task in the calling process when it is submitted (a completed future)."""

    def submit(self, fn: Any, /, *args: Any, **kwargs: Any) -> Future:  # type: ignore[override]
        """Run ``fn(*args, **kwargs)`` now.

        Returns
        -------
        concurrent.futures.Future
            Already done.
        """
        future: Future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:
            future.set_exception(exc)
        return future


def _worker_init(memory_limit_mb: int) -> None:
    """Process-pool worker start: one BLAS thread, ignore Ctrl-C (the driver handles it), optional memory limit."""
    pin_threads()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if memory_limit_mb > 0:
        import resource

        limit = memory_limit_mb * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


def _is_worker_death(exc: BaseException) -> bool:
    if isinstance(exc, BrokenProcessPool):
        return True
    return type(exc).__name__ in ("KilledWorker", "CommClosedError", "FutureCancelledError")


@dataclass
class ExecutorHandle:
    """An executor plus what the driver needs around it.

    Attributes
    ----------
    kind : str
        ``serial``, ``local``, ``dask-local`` or ``dask``.
    workers : int
        Runs in flight at once.
    executor : concurrent.futures.Executor
    """

    kind: str
    workers: int
    executor: Executor
    memory_limit_mb: int = 0
    _closers: list[Any] = field(default_factory=list)

    def is_worker_death(self, exc: BaseException) -> bool:
        """Whether ``exc`` (raised by a future) means the worker died rather than the task raised.

        Parameters
        ----------
        exc : BaseException

        Returns
        -------
        bool
        """
        return _is_worker_death(exc)

    def broken(self) -> bool:
        """Whether the executor can take no more work (a process pool after a worker died)."""
        return isinstance(self.executor, ProcessPoolExecutor) and bool(getattr(self.executor, "_broken", False))

    def rebuild(self) -> None:
        """Replace a broken process pool by a new one (other kinds recover by themselves)."""
        if self.kind != "local":
            return
        self.kill_workers()
        self.executor.shutdown(wait=False, cancel_futures=True)
        self.executor = _process_pool(self.workers, self.memory_limit_mb)

    def kill_workers(self) -> None:
        """Kill the process pool's workers (a run past its timeout cannot be stopped otherwise)."""
        processes = getattr(self.executor, "_processes", None) or {}
        for proc in list(processes.values()):
            if proc.is_alive():
                os.kill(proc.pid, signal.SIGKILL)

    def close(self) -> None:
        """Shut the executor (and a local Dask cluster) down."""
        if self.kind == "local":
            self.kill_workers()
            self.executor.shutdown(wait=False, cancel_futures=True)
        else:
            self.executor.shutdown(wait=False)
        for close in self._closers:
            try:
                close()
            except Exception:
                pass


PRELOAD = ("oacli.campaign.jobs", "oacli.stages.track", "oacli.control.tracking", "oacli.sim.simulator")
"""Modules the fork server imports once, so that a new worker (also one replacing a dead one) starts warm."""


def _process_pool(workers: int, memory_limit_mb: int) -> ProcessPoolExecutor:
    os.environ.update({k: "1" for k in BLAS_ENV})  # inherited by the fork server and every worker
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(list(PRELOAD))
    return ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                               initargs=(memory_limit_mb,))


def _dask_client(address: str | None, workers: int, memory_limit_mb: int) -> tuple[Any, list[Any], int]:
    import dask
    from distributed import Client, LocalCluster

    dask.config.set({"distributed.scheduler.allowed-failures": 0})
    closers: list[Any] = []
    if address is None:
        env = {k: "1" for k in BLAS_ENV}
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None, memory_limit=(f"{memory_limit_mb}MiB" if memory_limit_mb
                                                                     else 0),
                               env=env, silence_logs=logging.ERROR)
        client = Client(cluster)
        closers += [client.close, cluster.close]
    else:
        client = Client(address)
        closers.append(client.close)
        workers = max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values()))
    return client, closers, workers


def check_executor(spec: str, workers: int) -> None:
    """Refuse an unknown executor or a worker count below 1 before anything is written.

    Parameters
    ----------
    spec : str
        ``--executor``.
    workers : int
        ``--workers``.

    Raises
    ------
    InputError
    """
    if workers < 1:
        raise InputError(f"--workers: {workers}: must be >= 1")
    if spec in ("serial", "local", "dask-local"):
        return
    if spec.startswith("dask://"):
        host, sep, port = spec.removeprefix("dask://").rpartition(":")
        if sep and host and port.isdigit():
            return
        raise InputError(f"--executor: {spec!r}: expected dask://HOST:PORT")
    raise InputError(f"--executor: {spec!r}: unknown executor (expected {EXECUTOR_HELP})")


def make_executor(spec: str, workers: int, *, memory_limit_mb: int = 0) -> ExecutorHandle:
    """Build the executor ``spec`` names (module docstring).

    Parameters
    ----------
    spec : str
        ``serial``, ``local``, ``dask-local`` or ``dask://HOST:PORT``.
    workers : int
        Worker processes (``local``, ``dask-local``); a remote Dask cluster has its own.
    memory_limit_mb : int
        Per-worker memory limit [MiB] (0: none).

    Returns
    -------
    ExecutorHandle

    Raises
    ------
    InputError
        An unknown executor or an unreachable Dask scheduler.
    """
    if workers < 1:
        raise InputError(f"--workers: {workers}: must be >= 1")
    if spec == "serial":
        return ExecutorHandle("serial", 1, SerialExecutor())
    if spec == "local":
        return ExecutorHandle("local", workers, _process_pool(workers, memory_limit_mb), memory_limit_mb)
    if spec == "dask-local" or spec.startswith("dask://"):
        address = None if spec == "dask-local" else "tcp://" + spec.removeprefix("dask://")
        try:
            client, closers, n = _dask_client(address, workers, memory_limit_mb)
        except OSError as exc:
            raise InputError(f"--executor {spec}: cannot reach the Dask scheduler: {exc}") from None
        handle = ExecutorHandle("dask-local" if address is None else "dask", n, client.get_executor(pure=False),
                                memory_limit_mb)
        handle._closers.extend(closers)
        return handle
    raise InputError(f"--executor: {spec!r}: unknown executor (expected {EXECUTOR_HELP})")


__all__ = ["EXECUTOR_HELP", "ExecutorHandle", "SerialExecutor", "check_executor", "make_executor"]
