"""What a compile may take: the cache's disk within its limit, and no more than half the memory
available.

The compiles are real (the machine's compiler, through tests/test_compile_once.py's fake one,
without its pause); the libraries a compile finds in the cache are files of known sizes.
"""

from __future__ import annotations

import os
from pathlib import Path

import casadi as ca
import pytest

from crashnlp.base import units
from crashnlp.base.cache import KEPT_IPOPT, KEPT_MODEL, KEPT_UNITS, KEPT_YAML, cache_dir
from crashnlp.base.errors import InputError
from crashnlp.models import stored as model_store
from crashnlp.numerics import compile_job, compiled
from crashnlp.optimize import oracle
from crashnlp.problem import ipopt
from crashnlp.problem.load import read_yaml
from tests.test_compile_once import fake_compiler, starts, twice

pytestmark = pytest.mark.integration

MB = 1_000_000


def cached_file(name: str, megabytes: float, age_s: float) -> Path:
    """A file of `megabytes` in the cache, last used `age_s` ago."""
    path = cache_dir() / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\0" * int(megabytes * MB))
    when = path.stat().st_mtime - age_s
    os.utime(path, (when, when))
    return path


def library_of(name: str, megabytes: float, age_s: float) -> Path:
    """A library of `megabytes` in the cache, with its list of names, last used `age_s` ago."""
    library = cached_file(f"{name}.so", megabytes, age_s)
    library.with_suffix(".names").write_text("nlp\n")
    return library


def test_a_compile_first_removes_the_least_recently_used_libraries_down_to_the_limit(tmp_path, monkeypatch):
    """Four libraries of 3 MB (12 MB) and a limit of 7 MB: the compile of a fifth removes the least
    recently used ones that no compile holds, until 7 MB are left: the oldest, `used` since, stays;
    the one a compile holds stays; the two next oldest go, with their lists of names."""
    fake_compiler(tmp_path, monkeypatch, pause=0)
    monkeypatch.setenv(compiled.LIMIT_ENV, "7")
    oldest, held, older, newest = (library_of(n, 3, age) for n, age in (("a", 400), ("b", 300), ("c", 200), ("d", 100)))
    compiled.used(oldest)
    lock = compiled.try_lock(held)
    assert lock is not None
    try:
        assert compiled.compiled(twice()).class_name() == "External"
    finally:
        os.close(lock)
    assert oldest.exists() and oldest.with_suffix(".names").exists() and held.exists()
    assert not older.exists() and not older.with_suffix(".names").exists() and not newest.exists()
    assert sum(p.stat().st_size for p in cache_dir().iterdir() if p.is_file()) <= 7 * MB


def test_a_compile_removes_kept_files_with_the_libraries_least_recently_used_first(tmp_path, monkeypatch):
    """The values of YAML files read before (crashnlp.problem.load.read_yaml) and stored models
    (crashnlp.models.stored) go as libraries do: a library, a model of 1 MB and a kept file of 3 MB,
    older than a second library, and a limit of 4 MB: all three go, the newer library stays; a kept
    file and a model written long ago but read since stay, used then."""
    fake_compiler(tmp_path, monkeypatch, pause=0)
    monkeypatch.setenv(compiled.LIMIT_ENV, "4")
    problem = tmp_path / "problem.yaml"
    problem.write_text("vehicle: {mass: 1500}\n")
    read_yaml(problem)
    (read,) = cache_dir().glob(KEPT_YAML.format(key="*"))
    os.utime(read, (0, 0))
    assert read_yaml(problem) == {"vehicle": {"mass": 1500}}
    x = ca.SX.sym("x")
    stored = cache_dir() / KEPT_MODEL.format(form="pendulum", key="1" * 20)
    stored.write_text(ca.Function("whole", [x], [2 * x]).serialize())
    os.utime(stored, (0, 0))
    assert float(model_store.read(stored)(3.0)) == 6.0
    oldest, model = library_of("a", 3, 400), cached_file(KEPT_MODEL.format(form="pendulum", key="0" * 20), 1, 350)
    kept, newer = cached_file(KEPT_YAML.format(key="0" * 32), 3, 300), library_of("b", 3, 100)
    assert compiled.compiled(twice()).class_name() == "External"
    assert not oldest.exists() and not model.exists() and not kept.exists()
    assert newer.exists() and read.exists() and stored.exists()
    assert sum(p.stat().st_size for p in cache_dir().iterdir() if p.is_file()) <= 4 * MB


def test_a_compile_removes_the_units_tables_and_ipopt_options_least_recently_used_first(tmp_path, monkeypatch):
    """The conversions pint made (crashnlp.base.units) and IPOPT's options (crashnlp.problem.ipopt)
    go as the other kept files do: a library of 3 MB, the table of another pint version and the
    options of another CasADi installation (1 MB each), older than a second library of 3 MB, and a
    limit of 4 MB: the first three go, the newer library stays; this installation's table and
    options, written long ago but read since, stay, used then."""
    fake_compiler(tmp_path, monkeypatch, pause=0)
    monkeypatch.setenv(compiled.LIMIT_ENV, "4")
    units._remembered.cache_clear()
    ipopt.ipopt_options.cache_clear()
    try:
        speed = units.to_si("56 km/h", "m/s")
        options = ipopt.ipopt_options()
        (table,) = cache_dir().glob(KEPT_UNITS.format(version="*"))
        for path in (table, ipopt.options_file()):
            os.utime(path, (0, 0))
        units._remembered.cache_clear()  # as in a new process: read from the cache
        ipopt.ipopt_options.cache_clear()
        assert units.to_si("56 km/h", "m/s") == speed and ipopt.ipopt_options() == options
    finally:
        units._remembered.cache_clear()
        ipopt.ipopt_options.cache_clear()
    oldest, stale_table = library_of("a", 3, 400), cached_file(KEPT_UNITS.format(version="0.1"), 1, 350)
    stale_options, newer = cached_file(KEPT_IPOPT.format(key="0" * 16), 1, 300), library_of("b", 3, 100)
    assert compiled.compiled(twice()).class_name() == "External"
    assert not oldest.exists() and not stale_table.exists() and not stale_options.exists()
    assert newer.exists() and table.exists() and ipopt.options_file().exists()
    assert sum(p.stat().st_size for p in cache_dir().iterdir() if p.is_file()) <= 4 * MB


def test_a_cache_within_its_limit_keeps_every_library(tmp_path, monkeypatch):
    fake_compiler(tmp_path, monkeypatch, pause=0)
    monkeypatch.delenv(compiled.LIMIT_ENV, raising=False)
    kept = [library_of(n, 3, age) for n, age in (("a", 400), ("b", 300))]
    assert compiled.compiled(twice()).class_name() == "External"
    assert all(library.exists() for library in kept)


@pytest.mark.parametrize("value", ["lots", "-1", "nan"])
def test_a_limit_that_is_not_a_size_is_refused_naming_the_variable(monkeypatch, value):
    monkeypatch.setenv(compiled.LIMIT_ENV, value)
    with pytest.raises(InputError, match=f"^{compiled.LIMIT_ENV}={value}: "):
        compiled.cache_limit()


def test_a_compile_that_needs_more_than_half_the_available_memory_is_not_started(tmp_path, monkeypatch, capsys):
    """With 2 kB of memory available, the model function's compile (its C times the memory gcc takes
    per byte) does not start: the function stays in CasADi's virtual machine, one line says why,
    once a process; the NLP's background compile is not started either, and the solve's functions
    are not offered for compiling again in this process (`refused`)."""
    log = fake_compiler(tmp_path, monkeypatch, pause=0)
    monkeypatch.setattr(compile_job, "_compiles", [])
    monkeypatch.setattr(compiled, "_too_large", set())
    monkeypatch.setattr(compiled, "available_memory", lambda: 2000.0)
    for _ in range(2):
        assert compiled.compiled(twice()).class_name() != "External"
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("crashnlp: twice-") and "is not compiled" in line and "virtual machine" in line
    library = cache_dir() / "nlp-test-gauss-newton.so"
    with pytest.raises(compiled.TooLarge):  # the solve's caller stays in the VM (oracle.COMPILE_ERRORS)
        oracle._compile_behind(os.environ["CC"], {"twice": twice()}, library)
    assert compiled.refused(library) and compile_job._compiles == [] and starts(log) == 0
    assert not library.with_suffix(".c").exists()
    monkeypatch.setattr(compiled, "_too_large", set())  # another process, with memory enough: compiled
    monkeypatch.setattr(compiled, "available_memory", lambda: 1e12)
    assert compiled.compiled(twice()).class_name() == "External"


def test_the_available_memory_is_read_from_the_machine():
    available = compiled.available_memory()
    assert available is None or 0 < available < 1e15
