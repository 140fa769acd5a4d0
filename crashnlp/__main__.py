"""The `crashnlp` console command (and `python -m crashnlp`): crashnlp.cli.main in a process of its own.

Three things only a process started for one command may do, which a library imported into
someone else's process (tests, notebooks, crashnlp.cli.main called from Python) must not:

- OpenBLAS, loaded by numpy and again by CasADi's IPOPT, starts a thread per core in each
  unless OPENBLAS_NUM_THREADS says otherwise. A command's dense matrices are small (a fit's
  weighted Jacobian has a dozen columns; IPOPT's sparse factorization is MUMPS's), and the
  threads cost their start and their wake-ups more than they save: the command sets the
  variable to 1 before numpy loads, unless the user has set it; its child processes (figures,
  study workers, compiles) inherit it.
- Python's cyclic garbage collector runs every 700 net allocations of container objects (its
  default threshold), each run going through the young objects: some 120 runs in a warm
  identify, most of them while the modules load. The command runs it every GC_YOUNG instead,
  and once the command's modules are loaded it moves what is alive into the collector's
  permanent generation (gc.freeze): the modules, classes and functions live as long as the
  process, and the oldest generation's collections no longer go through them.
- Python's teardown at exit (a last garbage collection, every module's objects freed one by
  one, the libraries' destructors) frees what the system frees at once when the process ends.
  Once the command has returned, its exit handlers run (atexit, as at a normal exit) and its
  output is flushed, the process ends with os._exit. Where a thread that is no daemon still
  runs, the exit is Python's own, which waits for it.

Measured in docs/design-notes.md, "A lighter command: the process around it".
"""

from __future__ import annotations

import atexit
import gc
import os
import sys
import threading
from contextlib import suppress
from typing import NoReturn

BLAS_THREADS_ENV = "OPENBLAS_NUM_THREADS"
GC_YOUNG = 10_000  # allocations between two collections of the youngest generation (Python's default: 700)


def run() -> NoReturn:
    """Run the command of sys.argv and end the process with its exit status."""
    os.environ.setdefault(BLAS_THREADS_ENV, "1")
    gc.set_threshold(GC_YOUNG)
    from crashnlp.cli import main  # after the variable: it imports numpy

    gc.freeze()
    end(main())


def end(code: int) -> NoReturn:
    """End the process with `code`: the exit handlers, the output flushed, then os._exit; or
    sys.exit where a thread that is no daemon still runs (Python's exit waits for it)."""
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and t.is_alive() and not t.daemon]
    if others:
        sys.exit(code)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with suppress(OSError, ValueError):  # a closed pipe (crashnlp ... | head) or stream
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    run()
