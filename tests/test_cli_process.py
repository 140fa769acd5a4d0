"""The console command's process (crashnlp.__main__): what it sets before numpy loads, and its
end by os._exit, which must still run the exit handlers, flush the output, wait for a thread that
is no daemon and pass the exit status on."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from builders import ROOT

from crashnlp.__main__ import BLAS_THREADS_ENV, GC_YOUNG

pytestmark = pytest.mark.integration  # processes of their own
PICKUP = ROOT / "problems/pickup-56kph.yaml"


def python(code: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120, env=env)


def test_the_end_runs_the_exit_handlers_flushes_and_passes_the_status(tmp_path):
    """An atexit handler runs, a partial line left in the buffer of a pipe arrives, and the
    status is the command's; a thread that is no daemon finishes its work before the end."""
    mark = tmp_path / "handler"
    late = tmp_path / "thread"
    code = (
        "import atexit, sys, threading, time; from pathlib import Path; from crashnlp.__main__ import end;"
        f" atexit.register(lambda: Path({str(mark)!r}).write_text('ran'));"
        f" threading.Thread(target=lambda: (time.sleep(0.3), Path({str(late)!r}).write_text('done'))).start();"
        " sys.stdout.write('no newline'); sys.stderr.write('err'); end(3)"
    )
    proc = python(code)
    assert (proc.returncode, proc.stdout, proc.stderr) == (3, "no newline", "err")
    assert mark.read_text() == "ran" and late.read_text() == "done"


def test_the_end_with_daemon_threads_alone_is_at_once(tmp_path):
    """A daemon thread does not hold the process (as at Python's own exit), and os._exit is taken:
    an object's finalizer, which Python's teardown would run, does not run."""
    code = (
        "import threading, time; from crashnlp.__main__ import end;"
        " threading.Thread(target=time.sleep, args=(60,), daemon=True).start();"
        " Held = type('Held', (), {'__del__': lambda self: print('teardown')}); held = Held();"
        " print('before'); end(0)"
    )
    proc = python(code)
    assert (proc.returncode, proc.stdout) == (0, "before\n")


@pytest.mark.parametrize(("given", "expected"), [(None, "1"), ("2", "2")])
def test_the_command_runs_with_one_blas_thread_unless_the_user_set_them(given, expected):
    """The variable is set before numpy loads (numpy then starts no OpenBLAS thread: the process
    has one thread when the command ends), and a value the user gave is kept; the collector's
    youngest generation is collected every GC_YOUNG allocations, and what the loaded modules hold
    is in its permanent generation."""
    env = {k: v for k, v in os.environ.items() if k != BLAS_THREADS_ENV}
    if given is not None:
        env[BLAS_THREADS_ENV] = given
    code = (
        "import atexit, os, sys; sys.argv = ['crashnlp', 'schema'];"
        " atexit.register(lambda: print('numpy' in sys.modules, os.environ['OPENBLAS_NUM_THREADS'],"
        " len(os.listdir('/proc/self/task')), __import__('gc').get_threshold()[0], __import__('gc').get_freeze_count(),"
        " file=sys.stderr));"
        " from crashnlp.__main__ import run; run()"
    )
    proc = python(code, env)
    loaded, value, threads, young, frozen = proc.stderr.split()
    assert (proc.returncode, loaded, value, int(young)) == (0, "True", expected, GC_YOUNG)
    assert int(frozen) > 10_000
    if given is None and Path("/proc/self/task").is_dir():
        assert threads == "1"


def test_a_command_through_the_console_entry_writes_what_main_writes(tmp_path):
    """`python -m crashnlp simulate --no-figures` ends with its last line and its files written,
    and the same files as crashnlp.cli.main in this process; bad input is one line and exit 2."""
    from crashnlp.cli import main

    out, here = tmp_path / "console", tmp_path / "main"
    proc = subprocess.run(
        [sys.executable, "-m", "crashnlp", "simulate", str(PICKUP), "--no-figures", "--out", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0 and proc.stdout.splitlines()[-1] == f"wrote {out}/", proc.stderr
    assert main(["simulate", str(PICKUP), "--no-figures", "--out", str(here)]) == 0
    written = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    assert written and written == sorted(p.relative_to(here) for p in here.rglob("*") if p.is_file())
    for name in written:
        if name.suffix == ".csv":
            assert (out / name).read_bytes() == (here / name).read_bytes(), name
    bad = subprocess.run(
        [sys.executable, "-m", "crashnlp", "identify", str(tmp_path / "none.yaml")], capture_output=True, text=True
    )
    assert (bad.returncode, bad.stdout) == (2, "") and bad.stderr.count("\n") == 1 and "none.yaml" in bad.stderr


def test_a_reader_of_stdout_that_leaves_ends_the_command_quietly():
    """`crashnlp schema | head -1` whose reader left before the command wrote: no line on stderr
    (it said "crashnlp: error: Broken pipe", exit 1) and the status of a writer ended by SIGPIPE."""
    read, write = os.pipe()
    os.close(read)  # the reader has left before the command writes its first line
    proc = subprocess.run(
        [sys.executable, "-m", "crashnlp", "schema"], cwd=ROOT, stdout=write, stderr=subprocess.PIPE, timeout=60
    )
    os.close(write)
    assert (proc.returncode, proc.stderr) == (141, b"")  # crashnlp.cli.PIPE_CLOSED


def test_the_version_is_the_packages():
    """`crashnlp --version` prints the package's version and ends with 0, before any command."""
    from crashnlp import __version__

    proc = subprocess.run([sys.executable, "-m", "crashnlp", "--version"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert (proc.returncode, proc.stdout, proc.stderr) == (0, f"crashnlp {__version__}\n", "")
