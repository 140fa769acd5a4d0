"""Figures drawn by a process of their own, started before the solve.

matplotlib takes about a third of a second to import, as long as the solve of a
shipped problem. A process forked when the command has read its problem imports it
on the other core while this one solves, then draws the figures of the result this
one sends it once the result files are written. The command still waits for it, so the figures exist
when it returns; where there is no fork (Windows) they are drawn in this process.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
from pathlib import Path
from types import TracebackType

from crashnlp.result import Result


class FigureProcess:
    """Use as a context: `draw(result, folder)` once the result files are written; leaving
    the context without drawing (an error, an interrupt) stops the process."""

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

    def draw(self, result: Result, folder: Path) -> None:
        """The figures of `result` into `folder` (where its files are); returns when they are written."""
        if self.pid is None:
            from crashnlp.results import write_figures

            write_figures(result, folder)
            return
        self._send(pickle.dumps((folder.resolve(), result)))
        if self._wait() != 0:
            raise RuntimeError(f"the figures of {folder} were not drawn (see above)")

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if self.pid is not None:
            self._send(b"")
            self._wait()

    def _send(self, message: bytes) -> None:
        if self.pipe is not None:
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
    """Import matplotlib, then draw what the parent names (nothing: it gave up)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # an interrupt is the parent's to handle
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        from crashnlp import plots  # noqa: F401 - matplotlib, while the parent solves
        from crashnlp.results import write_figures

        message = b""
        while chunk := os.read(pipe, 65536):
            message += chunk
        if message:
            folder, result = pickle.loads(message)
            write_figures(result, folder)
        return 0
    except Exception as exc:  # noqa: BLE001 - reported in one line; the parent says it failed
        print(f"crashnlp: figures: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
