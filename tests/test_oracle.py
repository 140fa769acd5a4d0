"""The compiled NLP: one library per problem shape, the same bits as CasADi's virtual machine.

These tests compile (tests/conftest.py turns NLP compilation off for the others), on the
shipped pickup problem cut to 30 intervals: one library, compiled behind a first solve.
"""

from __future__ import annotations

import os
import shutil
import time

import numpy as np
import pytest
from builders import ROOT

from crashnlp.case.case import Case
from crashnlp.numerics import compile_job, compiled
from crashnlp.numerics.compiled import compiler
from crashnlp.optimize.identify import identify
from crashnlp.problem import load_problem

pytestmark = pytest.mark.integration


def switched_on(monkeypatch: pytest.MonkeyPatch, folder) -> None:
    """NLP compilation on, into `folder` as the crashnlp cache."""
    if compiler() is None:
        pytest.skip("no C compiler")
    monkeypatch.setenv("CRASHNLP_CACHE", str(folder))
    monkeypatch.setenv("CRASHNLP_COMPILE", "1")


@pytest.fixture(scope="module")
def shared(tmp_path_factory):
    """A cache holding the library of the test problem's shape, compiled behind a first solve
    (`compile: auto`, in the virtual machine) and waited for; that solve, the sources left in
    the cache once the library is there, and the next solve (which loads it). (`compile: now` is
    what tests/test_shipped.py, test_api.py and test_study.py compile by.)"""
    folder = tmp_path_factory.mktemp("cache")
    with pytest.MonkeyPatch.context() as mp:
        switched_on(mp, folder)
        before = identify(pickup("auto"), progress=None)
        deadline = time.monotonic() + 180
        while not libraries(folder) and time.monotonic() < deadline:
            time.sleep(0.5)
        assert len(libraries(folder)) == 1, "the background compile did not finish"
        left = list(folder.glob("nlp-*.c"))
        yield folder, before, left, identify(pickup("auto"), progress=None)


@pytest.fixture
def cache(shared, monkeypatch):
    """The shared cache, switched on; and the solve that loaded its library."""
    switched_on(monkeypatch, shared[0])
    return shared[0], shared[3]


def pickup(compile: str, **values) -> Case:
    problem = load_problem(ROOT / "problems" / "pickup-56kph.yaml")
    return Case(problem.with_values({"transcription.intervals": 30, "solver.compile": compile, **values}))


def in_the_vm(monkeypatch: pytest.MonkeyPatch, **values):
    """The same NLP (numbers as parameters) solved in CasADi's virtual machine: no compiler."""
    with monkeypatch.context() as mp:
        mp.setenv("CRASHNLP_COMPILE", "model")
        return identify(pickup("auto", **values), progress=None)


def libraries(folder) -> list[str]:
    """The compiled libraries (solver and covariance functions) of each NLP shape."""
    return sorted(p.name for p in folder.glob("nlp-*-gauss-newton*.so"))


@pytest.mark.slow
def test_compiled_solve_gives_the_bits_of_the_virtual_machine(cache, monkeypatch):
    folder, built = cache
    vm = in_the_vm(monkeypatch)
    assert vm.result.converged and built.result.converged and vm.result.iterations > 5
    assert built.result.compiled and not vm.result.compiled
    assert len(libraries(folder)) == 1
    assert np.array_equal(vm.result.z, built.result.z)
    assert np.array_equal(vm.result.lam_g, built.result.lam_g)
    assert vm.result.objective == built.result.objective


def test_one_library_serves_other_fixed_values(cache, monkeypatch):
    folder, first = cache
    (library,) = libraries(folder)
    # stiffer and better damped front suspension: other numbers, the same shape, so the
    # same library (the data, the speed and the scales are parameters just as well)
    changes = {"vehicle.suspension.k_front": "80 kN/m", "vehicle.suspension.c_front": "10 kN*s/m"}
    other = identify(pickup("auto", **changes), progress=None)
    assert libraries(folder) == [library]
    assert other.result is not None and other.result.compiled and other.result.converged
    vm = in_the_vm(monkeypatch, **changes)
    assert np.array_equal(vm.result.z, other.result.z)
    assert np.max(np.abs(first.theta - other.theta) / first.ocp.free.scale) > 1e-3  # really another problem


@pytest.mark.slow
def test_auto_solves_now_and_compiles_behind_for_the_next_run(shared):
    _, before, left, after = shared
    assert before.result.converged and not before.result.compiled
    assert not left, "the source is left behind"
    assert after.result.compiled
    assert np.array_equal(before.result.z, after.result.z)


def test_a_cache_that_cannot_be_written_leaves_the_virtual_machine(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    switched_on(monkeypatch, blocker / "cache")
    solved = identify(pickup("auto"), progress=None)
    assert solved.result.converged and not solved.result.compiled
    assert blocker.read_text() == "not a folder"


def test_a_truncated_library_is_solved_around_and_removed(shared, tmp_path, monkeypatch):
    """The library of the shape cut short in the cache (once the dynamic loader's SIGBUS): the run
    solves in the virtual machine, to the bits of the compiled solve, and removes it, so that its
    compile behind the run writes it again."""
    folder = tmp_path / "cache"
    shutil.copytree(shared[0], folder)
    (name,) = libraries(folder)
    os.truncate(folder / name, 10000)
    switched_on(monkeypatch, folder)
    monkeypatch.setattr(compile_job, "_compiles", [])  # this test's compile only
    solved = identify(pickup("auto"), progress=None)
    started = len(compile_job._compiles)
    compile_job.stop_compiles()
    assert solved.result.converged and not solved.result.compiled
    assert np.array_equal(solved.result.z, shared[3].result.z)
    assert started == 1
    assert not (folder / name).exists() or compiled.intact(folder / name)
