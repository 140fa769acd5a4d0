"""One compile per library and machine, under the library's lock in the cache.

A fake compiler (the machine's, after a pause, writing a line per start) stands in for `cc`, so
that a compile is still running when another asker looks, and the starts can be counted. The
functions are the smallest that go through the same paths as the model's and the NLP's.
"""

from __future__ import annotations

import os
import shutil
import signal
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


def test_a_background_compile_runs_once_and_one_killed_holds_no_lock(tmp_path, monkeypatch):
    """An NLP's library compiled behind a solve: a second asker while it runs starts none (its
    solve stays in the VM). Killed (SIGKILL, no clean-up), the compile leaves no library and no
    lock held, so the next asker compiles it at once, not after a staleness timeout."""
    log = fake_compiler(tmp_path, monkeypatch, pause=30)
    monkeypatch.setattr(compile_job, "_compiles", [])  # this test's compiles only
    cc, library = os.environ["CC"], cache_dir() / "nlp-test-gauss-newton.so"
    functions = {"twice": twice()}
    oracle._compile_behind(cc, functions, library)
    oracle._compile_behind(cc, functions, library)
    (job,) = compile_job._compiles
    deadline = time.monotonic() + 10
    while starts(log) < 1 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert starts(log) == 1 and len(oracle.compiles_running(cache_dir())) == 1
    os.killpg(job.pid, signal.SIGKILL)
    compile_job.stop_compiles([job])
    assert oracle.compiles_running(cache_dir()) == [] and not library.exists()
    monkeypatch.setenv(PAUSE_ENV, "0")
    oracle._compile_behind(cc, functions, library)
    (again,) = compile_job._compiles
    assert again.wait(timeout=60) == 0
    compile_job.stop_compiles([again])
    assert starts(log) == 2 and library.exists()
    assert float(oracle._load(library)["twice"](3.0)) == 6.0
