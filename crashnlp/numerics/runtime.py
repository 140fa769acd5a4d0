"""Process-wide settings that do not change results, only how they are computed."""

from __future__ import annotations

import os

import casadi as ca

THREADS_ENV = "CRASHNLP_THREADS"


def map_threads() -> int:
    """Threads evaluating mapped interval functions: CRASHNLP_THREADS, else up to 4 cores.

    Study workers set it to 1 so that parallel cases do not compete for the cores.
    """
    value = os.environ.get(THREADS_ENV)
    return max(1, int(value)) if value else max(1, min(os.cpu_count() or 1, 4))


def mapped(fn: ca.Function, n: int, threads: int | None = None) -> ca.Function:
    """`fn` mapped over n columns, threaded when more than one thread is allowed (`threads`,
    else map_threads())."""
    threads = map_threads() if threads is None else threads
    return fn.map(n, "thread", threads) if threads > 1 else fn.map(n)
