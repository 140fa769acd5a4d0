"""Where tasks run: a local process pool or a dask.distributed cluster (crashnlp[dask]), as lanes.

An executor has `lanes` (worker processes, or a cluster's worker threads) and
runs one task per lane at a time: `submit(lane, fn, item)`, then `wait()` for
`(lane, result)` of a task that finished. A task whose worker died under it
(killed, out of memory) runs again on a fresh worker, up to WORKER_DEATHS times:
the death was the machine's, not the task's, and the task's item is the same, so
its result is too. An exception the task raised (or a worker that died on it
every time) comes back as the result, so one broken task never stops the others.
`fn` must be a top-level function of plain, picklable data. The workers start
once and live until `close`, so what a worker keeps (a solver built for a problem
shape) serves every later task on its lane; crashnlp.engine.schedule decides what
runs where.
"""

from __future__ import annotations

import logging
import multiprocessing
import multiprocessing.util
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import ExitStack, contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from crashnlp.base.choices import EXECUTORS
from crashnlp.base.errors import InputError, RunError
from crashnlp.engine import CONNECT_TIMEOUT, DASK_EXTRA
from crashnlp.numerics.compile_job import stop_compiles

WORKER_DEATHS = 2  # a task runs again on a fresh worker after at most this many deaths of its worker
LOST_WORKER_POLL = 1.0  # s: how often a Dask study looks for workers that left while nothing finishes
ABORT_WAIT = 5.0  # s: how long an aborted study's workers have to end after SIGTERM before they are killed
HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)
NO_WORKERS_WAIT = 120.0  # s: how long a Dask study waits on a cluster that has no worker left
ORPHAN_POLL = 1.0  # s: how often a worker looks whether its main process is there, where no pidfd tells it
# a LocalCluster's housekeeping, which shares the cores with the cases it runs: no statistical
# profiler sampling every worker's stacks (it holds the GIL a solve's callbacks need), the
# event loops' tick and the system monitor at intervals a study of whole solves does not miss,
# and glibc's malloc left as in a local worker: dask's nanny sets MALLOC_TRIM_THRESHOLD_ for the
# workers it starts, which turns off malloc's adaptive mmap threshold, so that every large block
# a solve allocates is mapped and unmapped again (13 to 15 % more CPU a case)
# (measured in docs/design-notes.md, "Dask's housekeeping on a LocalCluster")
LOCAL_CLUSTER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "200ms",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
}


class Executor(Protocol):
    lanes: int

    def submit(self, lane: int, fn: Callable[[Any], Any], item: Any) -> None: ...

    def wait(self) -> tuple[int, Any]: ...

    def close(self) -> None: ...

    def abort(self) -> None: ...


def default_workers() -> int:
    """Cores this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


# imported once by the fork server, so each worker starts in milliseconds, not seconds (and by
# each worker of a LocalCluster as it starts, not on its first case): what a study's cases and a
# fit's profile chains run
PRELOAD = [
    "crashnlp.studies.run",
    "crashnlp.studies.worker",
    "crashnlp.optimize.pipeline",
    "crashnlp.results.result",
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


def _worker_init(main: int) -> None:
    """Workers leave Ctrl-C to the main process `main`, which stops them (a terminal sends SIGINT
    to all), stop the C compiles they started when they end (a worker ended by a signal stops them
    too: crashnlp.numerics.compile_job watches its starter), and end once `main` is gone
    (`_end_with`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    multiprocessing.util.Finalize(None, stop_compiles, exitpriority=0)
    threading.Thread(target=_end_with, args=(main,), name="crashnlp-main-watch", daemon=True).start()


def _end_with(main: int) -> None:
    """End this worker once the process that started it has ended, however it ended: killed by
    SIGKILL or the kernel's out-of-memory killer, it stops nothing, and its workers, children of
    the fork server, waited on their queues for ever. Watched through a pidfd where the system has
    one (Linux), else by polling the process every ORPHAN_POLL seconds."""
    try:
        watched = os.pidfd_open(main)
    except (AttributeError, OSError):  # no pidfd here, or `main` gone already
        while _alive(main):
            time.sleep(ORPHAN_POLL)
    else:
        select.select([watched], [], [])
    stop_compiles()
    os._exit(1)


def _alive(pid: int) -> bool:
    """Whether process `pid` is there (one of another user's, PermissionError: the pid taken again)."""
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    return True


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


@dataclass
class _Task:
    lane: int
    fn: Callable[[Any], Any]
    item: Any
    deaths: int = 0


class LocalExecutor:
    """Worker processes on this machine, one single-process pool per lane (so that a task can be
    sent to the worker that ran its parent); a lane whose worker died starts a new one, and runs
    the task it died under again (WORKER_DEATHS)."""

    def __init__(self, workers: int | None = None):
        self.lanes = workers or default_workers()
        self.pools = [_new_pool() for _ in range(self.lanes)]
        self.running: dict[Future, _Task] = {}

    def submit(self, lane: int, fn: Callable[[Any], Any], item: Any) -> None:
        self._start(_Task(lane, fn, item))

    def _start(self, task: _Task) -> None:
        with _workers_skip_main_script(), _signals_held():
            try:
                future = self.pools[task.lane].submit(task.fn, task.item)
            except BrokenProcessPool:  # its worker died on an earlier task
                self._renew(task.lane)
                future = self.pools[task.lane].submit(task.fn, task.item)
        self.running[future] = task

    def _renew(self, lane: int) -> None:
        self.pools[lane].shutdown(cancel_futures=True)
        self.pools[lane] = _new_pool()

    def wait(self) -> tuple[int, Any]:
        while True:
            done, _ = wait(self.running, return_when=FIRST_COMPLETED)
            future = min(done, key=lambda f: self.running[f].lane)
            task = self.running.pop(future)
            exc = future.exception()
            if not isinstance(exc, BrokenProcessPool) or task.deaths >= WORKER_DEATHS:
                return task.lane, exc if exc is not None else future.result()
            task.deaths += 1
            self._renew(task.lane)
            self._start(task)

    def close(self) -> None:
        for pool in self.pools:
            pool.shutdown(cancel_futures=True)

    def abort(self) -> None:
        """Stop at once (a signal): end the workers mid-case instead of waiting for their cases, then
        wait for each pool's threads. A pool's queue feeder thread drops its semaphores as it ends,
        and the command ends the process right after: a thread cut short between removing a
        semaphore and telling multiprocessing's resource tracker leaves the tracker warning on
        the user's terminal about a semaphore it cannot find."""
        processes = [p for pool in self.pools for p in (getattr(pool, "_processes", None) or {}).values()]
        for process in processes:
            process.terminate()
        deadline = time.monotonic() + ABORT_WAIT
        for process in processes:
            process.join(timeout=max(0.0, deadline - time.monotonic()))
            if process.is_alive():
                process.kill()
                process.join()
        for pool in self.pools:
            pool.shutdown(wait=True, cancel_futures=True)


def _new_pool() -> ProcessPoolExecutor:
    return ProcessPoolExecutor(max_workers=1, mp_context=_context(), initializer=_worker_init, initargs=(os.getpid(),))


@contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM that arrive while a worker starts are handled once it has started and its
    pool knows it (in the main thread; elsewhere nothing is held). A signal handled mid-start
    leaves a worker that `abort` cannot see: it goes on reading its start message after the
    command has removed that message's semaphores, and prints a traceback."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    try:
        with ExitStack() as restore:  # every handler put back, even where a signal interrupts one of them
            for s in HELD_SIGNALS:
                previous = signal.getsignal(s)
                if previous is None:  # a handler set outside Python: left alone
                    continue
                restore.callback(signal.signal, s, previous)
                signal.signal(s, lambda signum, frame: held.append(signum))
            yield
    finally:
        for signum in held:
            signal.raise_signal(signum)


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
    """Cases as dask tasks: on the cluster at `address`, else on a LocalCluster of `workers` processes.

    A task is sent to its lane's worker, other workers allowed. dask keeps a task bound to the
    address of a worker that has left the cluster until a worker of that address returns
    (dask/distributed#7346), so a task whose worker is gone is sent again, to any worker, once
    `wait` sees it missing (every LOST_WORKER_POLL seconds while nothing finishes). A cluster left
    without any worker for NO_WORKERS_WAIT seconds ends the run with a RunError, not a wait for ever."""

    def __init__(self, workers: int | None = None, address: str | None = None, timeout: float = CONNECT_TIMEOUT):
        self.distributed = require_dask()

        self.cluster = None
        if address is None:
            self.cluster = _take_started_cluster(workers or default_workers())
            self.client = self.distributed.Client(self.cluster)
        else:
            self.client = _connect(address, timeout)
        # a lane per worker thread of the cluster (one unrestricted lane while it has no workers)
        threads = self._workers()
        self.addresses: list[str | None] = [a for a in sorted(threads) for _ in range(threads[a])] or [None]
        self.lanes = len(self.addresses)
        self.running: dict[Any, _Task] = {}  # future -> its task
        self.empty_since: float | None = None  # when the cluster was last seen without workers

    def _workers(self) -> dict[str, int]:
        """The cluster's workers now: address -> threads."""
        return {a: w.get("nthreads", 1) for a, w in self.client.scheduler_info()["workers"].items()}

    def submit(self, lane: int, fn: Callable[[Any], Any], item: Any) -> None:
        self._start(_Task(lane, fn, item), self.addresses[lane])

    def _start(self, task: _Task, where: str | None) -> None:
        bound = {"workers": [where], "allow_other_workers": True} if where else {}
        future = self.client.submit(task.fn, task.item, pure=False, **bound)
        self.running[future] = task

    def wait(self) -> tuple[int, Any]:
        while True:
            try:
                done = self.distributed.wait(list(self.running), timeout=LOST_WORKER_POLL, return_when="FIRST_COMPLETED").done
            except TimeoutError:
                self._resend_lost()
                continue
            future = min(done, key=lambda f: self.running[f].lane)
            task = self.running.pop(future)
            exc = future.exception()
            return task.lane, exc if exc is not None else future.result()

    def _resend_lost(self) -> None:
        """Send again, to any worker, the tasks bound to a worker that has left the cluster; a
        RunError once the cluster has had no worker for NO_WORKERS_WAIT seconds."""
        alive = self._workers()
        self._check_not_empty(bool(alive))
        for lane, where in enumerate(self.addresses):
            if where is not None and where not in alive:
                self.addresses[lane] = None
                for future, task in list(self.running.items()):
                    if task.lane == lane:
                        del self.running[future]
                        future.cancel()
                        self._start(task, None)

    def _check_not_empty(self, has_workers: bool) -> None:
        now = time.monotonic()
        self.empty_since = None if has_workers else self.empty_since or now
        if self.empty_since is not None and now - self.empty_since > NO_WORKERS_WAIT:
            raise RunError(f"the dask cluster has had no worker for {NO_WORKERS_WAIT:g} s; {len(self.running)} cases left")

    def close(self) -> None:
        """Cancel what still runs and end a local cluster: its workers are killed, not asked to
        close, as every result they held has been taken (their own close, which ends the process
        as Python ends, took 0.4 s to 1.4 s at the end of every study)."""
        try:
            self.client.close(timeout=5)
        finally:
            if self.cluster is not None:
                _end_cluster(self.cluster)

    def abort(self) -> None:
        """Stop at once (a signal): the same as close."""
        self.close()


def _end_cluster(cluster: Any) -> None:
    """Close a LocalCluster, its worker processes killed first (SIGKILL): their nannies, told the
    cluster is closing, start no others, and what the workers compile stops with them, as a local
    worker's compiles do (crashnlp.numerics.compile_job). A killed worker leaves its lock file in
    dask's scratch folder (its nanny removes the worker's folder): removed here."""
    for nanny in list(cluster.workers.values()):
        pid, folder = nanny.pid, nanny.worker_dir
        if pid is None:  # no process (it failed to start)
            continue
        nanny.close_gracefully()
        with suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
        if folder is not None:
            Path(folder + ".dirlock").unlink(missing_ok=True)
    cluster.close(timeout=5)


def _local_cluster(workers: int) -> Any:
    """A LocalCluster of `workers` single-threaded processes that preload what the cases run."""
    import dask.config  # installed with distributed

    distributed = require_dask()
    logging.getLogger("distributed").setLevel(logging.CRITICAL)  # failures reach the user as one line
    # the worker processes inherit it: Ctrl-C is the main process's to handle
    with _sigint_ignored(), _workers_skip_main_script(), dask.config.set(LOCAL_CLUSTER_CONFIG):
        return distributed.LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.CRITICAL,
            preload=PRELOAD,
        )


_started_clusters: dict[int, Any] = {}  # worker count -> a LocalCluster start_cluster started for the next DaskExecutor


def start_cluster(workers: int) -> None:
    """Start a LocalCluster of `workers` now, for the next DaskExecutor of that many workers to
    take: a study starts it while another thread checks the cases (the cluster starts in the main
    thread, which alone can ignore SIGINT while the worker processes start: _local_cluster)."""
    if workers not in _started_clusters:
        _started_clusters[workers] = _local_cluster(workers)


def _take_started_cluster(workers: int) -> Any:
    """The LocalCluster of `workers` start_cluster started (others are closed), else one started now."""
    cluster = _started_clusters.pop(workers, None)
    discard_started_clusters()
    return cluster if cluster is not None else _local_cluster(workers)


def discard_started_clusters() -> None:
    """Close the clusters start_cluster started that no executor took (a study refused, stopped or
    with fewer cases left than workers)."""
    while _started_clusters:
        _end_cluster(_started_clusters.popitem()[1])


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
