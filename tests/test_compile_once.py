"""One compile per library and machine, under the library's lock in the cache.

A fake compiler (the machine's, after a pause, writing a line per start) stands in for `cc`, so
that a compile is still running when another asker looks, and the starts can be counted. It
writes its output file before the pause, as a linker that has begun, so that a compile killed
meanwhile leaves what a real one leaves: its source and a partial library. The
functions are the smallest that go through the same paths as the model's and the NLP's.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import signal
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import casadi as ca
import pytest

from crashnlp.base.cache import CACHE_ENV, cache_dir
from crashnlp.numerics import compile_job, compiled
from crashnlp.optimize import oracle

pytestmark = pytest.mark.integration

PAUSE_ENV = "FAKE_CC_PAUSE"
FAKE_CC = """#!/bin/sh
echo "$$" >> "{log}"
for arg; do [ "$previous" = -o ] && echo partial > "$arg"; previous=$arg; done
sleep "${{{pause}:-0}}"
exec "{cc}" "$@"
"""


def fake_compiler(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, pause: float) -> Path:
    """CC set to the machine's compiler after `pause` seconds, into an empty cache of this test's
    own, nothing loaded; returns the file that gets a line per compile started."""
    cc = compiled.compiler()
    if cc is None:
        pytest.skip("no C compiler")
    log, script = tmp_path / "compiles.log", tmp_path / "fake-cc"
    script.write_text(FAKE_CC.format(log=log, pause=PAUSE_ENV, cc=shutil.which(cc)))
    script.chmod(0o755)
    monkeypatch.setenv("CC", str(script))
    monkeypatch.setenv(PAUSE_ENV, str(pause))
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setattr(compiled, "_loaded", {})
    return log


def starts(log: Path) -> int:
    return len(log.read_text().split()) if log.exists() else 0


def leftovers() -> list[str]:
    """The compiles' sources and partial libraries in the cache."""
    return sorted(p.name for p in cache_dir().iterdir() if p.suffix in (".c", ".tmp"))


def wait_for_partials(count: int) -> None:
    """Until `count` compiles have begun writing their partial library (the fake compiler's pause)."""
    deadline = time.monotonic() + 10
    while len([name for name in leftovers() if name.endswith(".tmp")]) < count and time.monotonic() < deadline:
        time.sleep(0.02)


def twice() -> ca.Function:
    x = ca.SX.sym("x")
    return ca.Function("twice", [x], [2 * x])


def test_askers_of_one_library_at_once_start_one_compile_and_all_load_it(tmp_path, monkeypatch):
    """Three askers (threads: each opens the lock afresh, as a study's worker processes do) of the
    same model function from an empty cache: one compiles, the others wait and load its library."""
    log = fake_compiler(tmp_path, monkeypatch, pause=0.5)
    with ThreadPoolExecutor(3) as pool:
        functions = list(pool.map(lambda _: compiled.compiled(twice()), range(3)))
    assert starts(log) == 1
    assert [f.class_name() for f in functions] == ["External"] * 3  # compiled, not the VM's
    assert [float(f(3.0)) for f in functions] == [6.0] * 3


def test_a_background_compile_runs_once_and_one_killed_holds_no_lock_nor_files(tmp_path, monkeypatch):
    """An NLP's library compiled behind a solve: a second asker while it runs starts none, at once
    (its solve stays in the VM). Killed (SIGKILL, no clean-up), the compile leaves no library and no
    lock held, so the next asker compiles it at once, not after a staleness timeout; its source and
    partial library are left, and that next compile removes them."""
    log = fake_compiler(tmp_path, monkeypatch, pause=30)
    monkeypatch.setattr(compile_job, "_compiles", [])  # this test's compiles only
    cc, library = os.environ["CC"], cache_dir() / "nlp-test-gauss-newton.so"
    functions = {"twice": twice()}
    oracle._compile_behind(cc, functions, library)
    t0 = time.monotonic()
    oracle._compile_behind(cc, functions, library)
    assert time.monotonic() - t0 < compiled.TRY_WAIT_S  # a compile holds the lock: no wait for it
    (job,) = compile_job._compiles
    wait_for_partials(1)
    assert starts(log) == 1 and len(oracle.compiles_running(cache_dir())) == 1
    os.killpg(job.pid, signal.SIGKILL)
    compile_job.stop_compiles([job])
    assert oracle.compiles_running(cache_dir()) == [] and not library.exists()
    assert leftovers() == sorted([library.with_suffix(".c").name, f".{library.name}.{job.pid}.tmp"])
    monkeypatch.setenv(PAUSE_ENV, "0")
    oracle._compile_behind(cc, functions, library)
    (again,) = compile_job._compiles
    assert again.wait(timeout=60) == 0
    compile_job.stop_compiles([again])
    assert starts(log) == 2 and library.exists() and leftovers() == []
    assert float(oracle._load(library, {"twice"})["twice"](3.0)) == 6.0


def test_a_compile_removes_what_killed_compiles_left_and_not_a_running_compiles_files(tmp_path, monkeypatch):
    """The files of a compile killed by SIGKILL (a library not compiled again) are removed by the
    next compile of another library, its partial record too (killed while it wrote it); those of a
    compile still running are not."""
    fake_compiler(tmp_path, monkeypatch, pause=30)
    monkeypatch.setattr(compile_job, "_compiles", [])
    cc, killed, running = os.environ["CC"], cache_dir() / "nlp-killed.so", cache_dir() / "nlp-running.so"
    oracle._compile_behind(cc, {"twice": twice()}, killed)
    wait_for_partials(1)
    (job,) = compile_job._compiles
    os.killpg(job.pid, signal.SIGKILL)
    compile_job.stop_compiles([job])
    record = compile_job.partial(compile_job.record_of(killed), job.pid)
    record.write_text("")
    assert leftovers() == sorted([killed.with_suffix(".c").name, f".{killed.name}.{job.pid}.tmp", record.name])
    oracle._compile_behind(cc, {"twice": twice()}, running)
    wait_for_partials(1)
    (behind,) = compile_job._compiles
    running_files = sorted([running.with_suffix(".c").name, f".{running.name}.{behind.pid}.tmp"])
    assert leftovers() == running_files
    monkeypatch.setenv(PAUSE_ENV, "0")
    assert compiled.compiled(twice()).class_name() == "External"  # compiled inline, meanwhile
    assert leftovers() == running_files
    compile_job.stop_compiles([behind])
    assert leftovers() == []


def test_a_look_at_the_lock_does_not_stop_a_compile_that_tries_it(tmp_path, monkeypatch):
    """`compiling` (and so `compiles_running`) looks at a library's lock by taking it for an instant;
    a background compile that tries the lock in that instant is started all the same. The look is
    stretched to 0.1 s (its flock sleeps once it has the lock, as a looker descheduled there would),
    and the compile tries in the middle of it."""
    fake_compiler(tmp_path, monkeypatch, pause=0)
    monkeypatch.setattr(compile_job, "_compiles", [])
    cc, library = os.environ["CC"], cache_dir() / "nlp-test-gauss-newton.so"
    flock, held = fcntl.flock, threading.Event()

    def stretched(fd: int, operation: int) -> None:
        flock(fd, operation)
        if threading.current_thread().name == "look":
            held.set()
            time.sleep(0.1)

    monkeypatch.setattr(fcntl, "flock", stretched)
    look = threading.Thread(target=compiled.compiling, args=(library,), name="look")
    look.start()
    assert held.wait(timeout=10)
    oracle._compile_behind(cc, {"twice": twice()}, library)
    look.join()
    (job,) = compile_job._compiles  # started, not given up
    assert job.wait(timeout=60) == 0
    compile_job.stop_compiles([job])
    assert library.exists()


def damage(path: Path, how: str) -> None:
    """Cut `path` to a third (a copy or a disk that stopped short) or overwrite its middle third
    with random bytes."""
    data = path.read_bytes()
    third = len(data) // 3
    if how == "truncated":
        path.write_bytes(data[:third])
    else:
        path.write_bytes(data[:third] + os.urandom(third) + data[2 * third :])


@pytest.mark.parametrize("how", ["truncated", "garbled", "unrecorded and truncated"])
def test_a_damaged_model_library_is_compiled_again_and_loaded(tmp_path, monkeypatch, how):
    """A model function's library damaged in the cache, with or without the record its compile
    writes (a cache from before records has none), is not loaded: the next process that needs it
    compiles it again and loads that."""
    log = fake_compiler(tmp_path, monkeypatch, pause=0)
    compiled.compiled(twice())
    (library,) = cache_dir().glob("twice-*.so")
    compiled._loaded.clear()  # the next process: this one's copy unloaded (it is mapped from the file)
    if how.startswith("unrecorded"):
        compile_job.record_of(library).unlink()
    damage(library, how.split()[-1])
    again = compiled.compiled(twice())
    assert again.class_name() == "External" and float(again(3.0)) == 6.0
    assert starts(log) == 2 and compiled.intact(library)


def test_a_whole_library_without_a_record_is_loaded_as_it_is(tmp_path, monkeypatch):
    """A cache from before records (or one that cannot be written, read-only) keeps its libraries:
    one whose ELF file is whole is loaded, not compiled again (every run had stayed in the VM)."""
    log = fake_compiler(tmp_path, monkeypatch, pause=0)
    compiled.compiled(twice())
    (library,) = cache_dir().glob("twice-*.so")
    compiled._loaded.clear()
    compile_job.record_of(library).unlink()
    again = compiled.compiled(twice())
    assert again.class_name() == "External" and float(again(3.0)) == 6.0
    assert starts(log) == 1 and compiled.intact(library) is None and compiled.whole_elf(library)


def test_a_library_its_record_vouches_for_that_does_not_load_is_left_and_not_compiled_again(tmp_path, monkeypatch):
    """A whole library that fails to load (a cache on a noexec mount) was removed and compiled again
    on every run: it is left, and the process stays in the VM without compiling it again."""
    log = fake_compiler(tmp_path, monkeypatch, pause=0)
    compiled.compiled(twice())
    (library,) = cache_dir().glob("twice-*.so")
    compiled._loaded.clear()

    def refused(*args):
        raise RuntimeError("failed to map segment from shared object")

    monkeypatch.setattr(compiled.ca, "external", refused)
    for _ in range(2):
        assert compiled.compiled(twice()).class_name() != "External"
    assert starts(log) == 1 and library.exists() and compiled.intact(library)


@pytest.mark.parametrize(
    ("how", "suffix"),
    [("truncated", ".so"), ("garbled", ".so"), ("truncated", ".names"), ("unrecorded and cut a name short", ".names")],
)
def test_a_damaged_nlp_library_is_removed_and_compiled_again_behind(tmp_path, monkeypatch, how, suffix):
    """An NLP's library, or the names of its Functions beside it, damaged in the cache is not
    loaded but removed with its companions, so that the next compile behind a solve writes it again;
    without a record to vouch for the names (a cache from before records), a list that lacks a
    Function the solver needs is damage too (every fit had ended in KeyError: 'nlp')."""
    fake_compiler(tmp_path, monkeypatch, pause=0)
    monkeypatch.setattr(compile_job, "_compiles", [])
    monkeypatch.setattr(oracle, "_loaded", {})
    cc, library = os.environ["CC"], cache_dir() / "nlp-test-gauss-newton.so"
    x = ca.SX.sym("x")
    functions = {"twice": twice(), "half": ca.Function("half", [x], [x / 2])}
    oracle._compile_behind(cc, functions, library)
    assert compile_job._compiles.pop().wait(timeout=60) == 0
    if how.startswith("unrecorded"):
        compile_job.record_of(library).unlink()
        library.with_suffix(suffix).write_text("twice\n")
    else:
        damage(library.with_suffix(suffix), how)
    assert oracle._load(library, {"twice", "half"}) is None
    assert sorted(p.name for p in cache_dir().glob("nlp-test-*")) == [library.with_suffix(".lock").name]
    oracle._compile_behind(cc, functions, library)
    assert compile_job._compiles.pop().wait(timeout=60) == 0
    loaded = oracle._load(library, {"twice", "half"})
    assert loaded is not None and [float(loaded[name](3.0)) for name in ("twice", "half")] == [6.0, 1.5]
