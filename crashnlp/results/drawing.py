"""Figures drawn by processes of their own, started before the solve.

matplotlib takes about a third of a second to import, as long as the solve of a
shipped problem, and drawing the figures of an identification as long again. A
process forked as the command starts (before CasADi and the problem)
imports matplotlib alone on the other core while this one reads the problem and
solves (or simulates). Once the result files are written this one sends it the
figures as plain data (crashnlp.results.result.figure_jobs), and it draws them on every core, in processes
forked from it. The command still waits for them, so the figures exist when it
returns; where there is no fork (Windows) they are drawn in this process.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING

from crashnlp.results.files import note_output

if TYPE_CHECKING:
    from crashnlp.results.plots import Job


class FigureProcess:
    """Use as a context: `draw(jobs, folder)` once the result files are written; leaving
    the context without drawing (an error, an interrupt) kills the process."""

    def __init__(self) -> None:
        self.pid: int | None = None
        self.pipe: int | None = None

    def __enter__(self) -> FigureProcess:
        if hasattr(os, "fork"):
            read, write = os.pipe()
            pid = os.fork()
            if pid == 0:
                os.close(write)
                os._exit(_child(read))
            os.close(read)
            self.pid, self.pipe = pid, write
        return self

    def draw(self, jobs: list[Job], folder: Path) -> None:
        """Figure jobs (crashnlp.results.plots.draw) of the files in `folder`; returns when they are drawn."""
        if self.pid is None:
            from crashnlp.results.plots import draw

            draw(jobs)
            return
        for _, args in jobs:  # drawn in the other process, written in this one's output folder
            note_output(args[0])
        self._send(pickle.dumps(jobs))
        if self._wait() != 0:
            raise RuntimeError(f"the figures of {folder} were not drawn (see above)")

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if self.pid is not None:  # left without its figures (bad input, an error, an interrupt)
            os.kill(self.pid, signal.SIGKILL)  # it has written nothing; do not wait for matplotlib
            self._send(None)
            self._wait()

    def _send(self, message: bytes | None) -> None:
        """Send `message` (None: nothing) and close the pipe."""
        if self.pipe is not None:
            if message is not None:
                with os.fdopen(self.pipe, "wb", closefd=False) as pipe:
                    pipe.write(message)
            os.close(self.pipe)
            self.pipe = None

    def _wait(self) -> int:
        assert self.pid is not None
        _, status = os.waitpid(self.pid, 0)
        self.pid = None
        return os.waitstatus_to_exitcode(status)


def _child(pipe: int) -> int:
    """Import matplotlib, then draw what the parent sends (nothing: it gave up)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # an interrupt is the parent's to handle
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    jobs: list = []
    return _reported(lambda: jobs.extend(_receive(pipe))) or _on_every_core(jobs)


def _receive(pipe: int) -> list:
    """The figure jobs the parent sends, matplotlib imported while it solves."""
    from crashnlp.results import plots  # noqa: F401

    message = b""
    while chunk := os.read(pipe, 65536):
        message += chunk
    return pickle.loads(message) if message else []


def _on_every_core(jobs: list) -> int:
    """Draw the jobs over this process and forks of it, one per core, dealt round-robin (the
    fit figures, the heaviest, first): 0 when all were drawn."""
    from crashnlp.results.plots import draw

    lanes = max(1, min(len(jobs), os.cpu_count() or 1))
    forks = []
    for lane in range(1, lanes):
        pid = os.fork()
        if pid == 0:
            os._exit(_reported(draw, jobs[lane::lanes]))
        forks.append(pid)
    failed = _reported(draw, jobs[0::lanes])
    for pid in forks:
        failed |= os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) != 0
    return int(failed)


def _reported(fn, *args) -> int:
    """Run fn(*args): 0, or 1 after saying in one line why it failed (the parent says which
    figures were not drawn)."""
    try:
        fn(*args)
        return 0
    except Exception as exc:  # noqa: BLE001 - reported in one line
        print(f"crashnlp: figures: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
