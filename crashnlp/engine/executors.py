"""Where tasks run: a local process pool or a dask.distributed cluster (crashnlp[dask]), as lanes.

An executor has `lanes` (worker processes, or a cluster's worker threads) and
runs one task per lane at a time: `submit(lane, fn, item)`, then `wait()` for
`(lane, result)` of a task that finished. An exception the task raised (or a
worker that died) comes back as the result, so one broken task never stops the
others. `fn` must be a top-level function of plain, picklable data. The workers
start once and live until `close`, so what a worker keeps (a solver built for a
problem shape) serves every later task on its lane; crashnlp.engine.schedule
decides what runs where.
"""

from __future__ import annotations

import logging
import multiprocessing
import multiprocessing.util
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from typing import Any, Protocol

from crashnlp.compile_job import stop_compiles
from crashnlp.engine import CONNECT_TIMEOUT, DASK_EXTRA, EXECUTORS
from crashnlp.errors import InputError, RunError


class Executor(Protocol):
    lanes: int

    def submit(self, lane: int, fn: Callable[[Any], Any], item: Any) -> None: ...

    def wait(self) -> tuple[int, Any]: ...

    def close(self) -> None: ...

    def abort(self) -> None: ...


def default_workers() -> int:
    """Cores this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


# imported once by the fork server, so each worker starts in milliseconds, not seconds: what a
# study's cases and a fit's profile chains run
PRELOAD = [
    "crashnlp.studies.run",
    "crashnlp.studies.worker",
    "crashnlp.pipeline",
    "crashnlp.result",
]


def _context() -> multiprocessing.context.BaseContext:
    """forkserver (workers forked from a clean, single-threaded server that preloaded the code) where
    available, else spawn; never a plain fork of this process and whatever CasADi state it holds."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(PRELOAD)
    return context


def start_early() -> None:
    """Start the fork server now, so that it preloads crashnlp while this process reads the
    study and plans its cases (both cores busy instead of one waiting for the other)."""
    if _context().get_start_method() == "forkserver":
        from multiprocessing import forkserver

        forkserver.ensure_running()


def _worker_init() -> None:
    """Workers leave Ctrl-C to the main process, which stops them (a terminal sends SIGINT to all),
    and stop the C compiles they started when they end (a worker ended by a signal stops them
    too: crashnlp.compile_job watches its starter)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    multiprocessing.util.Finalize(None, stop_compiles, exitpriority=0)


@contextmanager
def _workers_skip_main_script() -> Iterator[None]:
    """Workers started here do not run the calling script again: multiprocessing re-runs the
    __main__ file in every new worker (the `if __name__ == "__main__"` idiom), which a script
    calling crashnlp.study at top level would turn into a study per worker. The workers need
    only crashnlp's own functions, so the script's path is hidden while they start."""
    main = sys.modules["__main__"]
    path, spec = getattr(main, "__file__", None), getattr(main, "__spec__", None)
    if path is None or spec is not None:
        yield
        return
    del main.__file__
    try:
        yield
    finally:
        main.__file__ = path


class LocalExecutor:
    """Worker processes on this machine, one single-process pool per lane (so that a task can be
    sent to the worker that ran its parent); a lane whose worker died starts a new one."""

    def __init__(self, workers: int | None = None):
        self.lanes = workers or default_workers()
        self.pools = [_new_pool() for _ in range(self.lanes)]
        self.running: dict[Future, int] = {}

    def submit(self, lane: int, fn: Callable[[Any], Any], item: Any) -> None:
        with _workers_skip_main_script():
            try:
                future = self.pools[lane].submit(fn, item)
            except BrokenProcessPool:  # its worker died on an earlier task
                self.pools[lane].shutdown(cancel_futures=True)
                self.pools[lane] = _new_pool()
                future = self.pools[lane].submit(fn, item)
        self.running[future] = lane

    def wait(self) -> tuple[int, Any]:
        done, _ = wait(self.running, return_when=FIRST_COMPLETED)
        future = min(done, key=self.running.__getitem__)
        exc = future.exception()
        return self.running.pop(future), exc if exc is not None else future.result()

    def close(self) -> None:
        for pool in self.pools:
            pool.shutdown(cancel_futures=True)

    def abort(self) -> None:
        """Stop at once (a signal): end the workers mid-case instead of waiting for their cases."""
        processes = [p for pool in self.pools for p in (getattr(pool, "_processes", None) or {}).values()]
        for process in processes:
            process.terminate()
        for pool in self.pools:
            pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.join(timeout=5)


def _new_pool() -> ProcessPoolExecutor:
    return ProcessPoolExecutor(max_workers=1, mp_context=_context(), initializer=_worker_init)


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored while processes are started (they keep it ignored), in the main thread only."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


class DaskExecutor:
    """Cases as dask tasks: on the cluster at `address`, else on a LocalCluster of `workers` processes."""

    def __init__(self, workers: int | None = None, address: str | None = None, timeout: float = CONNECT_TIMEOUT):
        distributed = require_dask()

        logging.getLogger("distributed").setLevel(logging.CRITICAL)  # failures reach the user as one line
        self.cluster = None
        if address is None:
            # the worker processes inherit it: Ctrl-C is the main process's to handle
            with _sigint_ignored(), _workers_skip_main_script():
                self.cluster = distributed.LocalCluster(
                    n_workers=workers or default_workers(),
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    silence_logs=logging.CRITICAL,
                )
            self.client = distributed.Client(self.cluster)
        else:
            self.client = _connect(address, timeout)
        # a lane per worker thread of the cluster (one unrestricted lane while it has no workers)
        threads = {a: w.get("nthreads", 1) for a, w in self.client.scheduler_info()["workers"].items()}
        self.addresses: list[str | None] = [a for a in sorted(threads) for _ in range(threads[a])] or [None]
        self.lanes = len(self.addresses)
        self.done = distributed.as_completed()
        self.lane_of: dict[Any, int] = {}  # task key -> lane

    def submit(self, lane: int, fn: Callable[[Any], Any], item: Any) -> None:
        """The task goes to the lane's worker, or another if that one has left the cluster."""
        where = self.addresses[lane]
        future = self.client.submit(fn, item, pure=False, workers=[where] if where else None, allow_other_workers=True)
        self.lane_of[future.key] = lane
        self.done.add(future)

    def wait(self) -> tuple[int, Any]:
        future = next(self.done)
        exc = future.exception()
        return self.lane_of.pop(future.key), exc if exc is not None else future.result()

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()

    def abort(self) -> None:
        """Stop at once (a signal): cancel the cases, end a local cluster's workers."""
        try:
            self.client.close(timeout=5)
        finally:
            if self.cluster is not None:
                self.cluster.close(timeout=5)


def require_dask(where: str = "--executor dask") -> Any:
    """The dask.distributed module; without it (a plain `pip install crashnlp`) an InputError that
    names `where` dask was asked for and says what to install."""
    try:
        import distributed
    except ImportError:
        raise InputError(f"{where}: dask is not installed ({DASK_EXTRA})") from None
    return distributed


def _connect(address: str, timeout: float) -> Any:
    """A client of the dask scheduler at `address`; a bad or silent address is one line."""
    try:
        return require_dask().Client(address, timeout=timeout)
    except (ValueError, TypeError) as exc:
        raise InputError(f"--address {address}: not a scheduler address ({exc})") from None
    except (OSError, TimeoutError) as exc:
        why = type(exc).__name__
        raise RunError(f"--address {address}: no dask scheduler answered within {timeout:g} s ({why})") from None


def make_executor(
    kind: str = "local", workers: int | None = None, address: str | None = None, timeout: float = CONNECT_TIMEOUT
) -> Executor:
    """The executor a study asked for."""
    if kind not in EXECUTORS:
        raise InputError(f"--executor: {kind!r} is none of {', '.join(EXECUTORS)}")
    if kind == "dask":
        return DaskExecutor(workers, address, timeout)
    if address is not None:
        raise InputError("--address needs --executor dask")
    return LocalExecutor(workers)
