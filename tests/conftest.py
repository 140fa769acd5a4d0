"""Settings for the whole test run: markers, the run's cache, the compiled NLP.

Markers (registered in pyproject.toml, where --strict-markers refuses any other):

    pytest -m unit                   one piece at a time: no IPOPT, no study, no worker process
    pytest -m integration            fits, designs, studies, the command line, processes and signals
    pytest -m "not slow"             all but the tests that cost more than ~5 s each
    pytest -m slow                   only those
    pytest -n 2 --dist loadfile      what `make test` runs: two workers, a file's tests on one
                                     worker (its module fixtures fit once), the files with a
                                     slow test handed out first (_file_order)

A test is `unit` unless it, or its module's `pytestmark`, says `integration`, and a unit test
that builds an IPOPT solver for an NLP (more than one variable: not the option probes) fails
and says so; `slow` is always written on the test (or on its module).

The run's cache: every process of the run (xdist workers, study workers, command lines the
tests start) shares one crashnlp cache folder, made fresh for the run and removed at its
end, so the compiled model functions and NLP libraries a run uses are compiled by that run
(as on a fresh clone), and nothing is read from or written to ~/.cache/crashnlp.

The compiled NLP: NLP compilation is off by default (CRASHNLP_COMPILE=model): nearly every
test builds an NLP of a shape of its own, and compiling one costs ~10 s of CPU at the
library's -O1 (designs with the exact Hessian ~90 s) against ~1 s to solve it. The tests
that take the `compiled_nlp` fixture turn it on, into the run's cache: the shipped pickup
problem (tests/test_shipped.py), a small identification by the API and the command line
(tests/test_api.py) and a study (tests/test_study.py) each compile their shape and are
compared with the virtual machine's solve; tests/test_oracle.py and tests/test_compile_once.py
compile into caches of their own.
No background compile outlives its command (CRASHNLP_KEEP_COMPILING=0), so none is left running
after the run; tests/test_hostile.py checks the default, a released compile, on a compile of its own.
"""

from __future__ import annotations

import os
import shutil
import tempfile

import casadi as ca
import pytest

from crashnlp.base.cache import CACHE_ENV
from crashnlp.numerics.compile_job import KEEP_ENV
from crashnlp.numerics.compiled import SWITCH_ENV, compiler

RUN_CACHE_ENV = "CRASHNLP_TEST_RUN_CACHE"  # set by the run's first process: the folder every process shares

os.environ.setdefault(SWITCH_ENV, "model")
os.environ.setdefault(KEEP_ENV, "0")  # no compile outlives the command that started it: none is left after the run


def pytest_configure(config: pytest.Config) -> None:
    # the controller (or a run without xdist) makes the folder before any worker starts; the
    # workers, which inherit its environment, find it set
    if RUN_CACHE_ENV not in os.environ:
        folder = tempfile.mkdtemp(prefix="crashnlp-test-cache-")
        os.environ[RUN_CACHE_ENV] = folder
        config.add_cleanup(lambda: shutil.rmtree(folder, ignore_errors=True))
    os.environ[CACHE_ENV] = os.environ[RUN_CACHE_ENV]


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("integration") is None:
            item.add_marker(pytest.mark.unit)
    items.sort(key=_file_order(items))


def _file_order(items: list[pytest.Item]):
    """The order the files run in (xdist's workers take them in it, pyproject.toml's
    --no-loadscope-reorder): the files with a slow test first, so that the long files start early
    and the short ones fill in at the end; then the files of more tests first (xdist's own order);
    a file's tests in their order."""
    files = [item.nodeid.split("::")[0] for item in items]
    slow = {file for file, item in zip(files, items) if item.get_closest_marker("slow") is not None}
    count = {file: files.count(file) for file in set(files)}
    first = {file: files.index(file) for file in reversed(files)}
    position = {id(item): (file not in slow, -count[file], first[file], n) for n, (file, item) in enumerate(zip(files, items))}
    return lambda item: position[id(item)]


@pytest.fixture(autouse=True)
def _unit_tests_solve_nothing(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    """A unit test that builds IPOPT for an NLP fails: it is an integration test. (Fits in module
    fixtures, set up before this, and in worker processes are not seen.)"""
    if request.node.get_closest_marker("integration") is not None:
        return
    nlpsol = ca.nlpsol

    def refused(name, plugin, problem, *args, **kwargs):
        size = problem["x"].numel() if isinstance(problem, dict) else problem.nnz_in(0)
        if plugin == "ipopt" and size > 1:
            pytest.fail(f"{request.node.nodeid} solves an NLP: mark it integration")
        return nlpsol(name, plugin, problem, *args, **kwargs)

    monkeypatch.setattr(ca, "nlpsol", refused)


@pytest.fixture
def compiled_nlp(monkeypatch: pytest.MonkeyPatch) -> str:
    """NLP compilation on (as in real use), into the run's cache; the test is skipped without
    a C compiler. Returns the compiler."""
    monkeypatch.setenv(SWITCH_ENV, "1")
    cc = compiler(nlp=True)
    if cc is None:
        pytest.skip("no C compiler")
    return cc
