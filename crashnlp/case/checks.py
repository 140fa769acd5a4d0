"""The checks a problem passes before a solve, beyond its schema (crashnlp.optimize.pipeline runs them all).

Light to import (no CasADi): a study's main process checks every case with them
before any is solved.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from crashnlp.base.errors import InputError
from crashnlp.case.testcase import check_data, load_tests
from crashnlp.problem import Problem
from crashnlp.problem.load import check_fit_keys


@contextmanager
def named(source: str) -> Iterator[None]:
    """An input error raised inside names `source` (unless it does already)."""
    try:
        yield
    except InputError as exc:
        raise InputError(exc if str(exc).startswith(source) else f"{source}: {exc}") from None


def check_keys(problem: Problem, source: str | None = None) -> None:
    """The checks of a problem's keys a solve needs beyond the schema: none that an identification
    would ignore (crashnlp.problem.load.check_fit_keys), and dask installed if the profiles ask for it."""
    source = source or problem.name
    check_fit_keys(problem, source)
    if problem.uncertainty.profile and problem.uncertainty.executor == "dask":
        from crashnlp.engine.executors import require_dask  # the process pool's modules: only here

        with named(source):
            require_dask("uncertainty.executor")


def check_tests(problem: Problem, source: str | None = None) -> None:
    """The tests' data read, and refused where they contradict the problem's speed or mass or end before
    a fit's duration, without building the model (a study checks every case so before it solves any)."""
    with named(source or problem.name):
        loaded, tests = load_tests(problem)
        vehicle = loaded.vehicle
        check_data(tests, vehicle.known_mass, vehicle.cg_above_impact < 0, vehicle.speed is not None)
