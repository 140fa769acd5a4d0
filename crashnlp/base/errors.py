"""The errors the command line turns into one line and an exit status.

- `InputError`: the user's input (problem, data, study file, an option): exit 2, nothing written.
- `RunError`: a failure the user cannot cause (solver, integrator, cluster, the file system): exit 1.
- `Interrupted`: SIGINT or SIGTERM ended the run: exit 130 or 143.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad input (problem file, data file, study file): one line naming where and what."""


def unreadable(path: object, exc: BaseException) -> InputError:
    """The one line for a file crashnlp wrote that does not read back as it writes it (broken,
    cut short or edited): the file, and what failed on it."""
    why = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    return InputError(f"{path}: does not read as crashnlp writes it ({why})")


class RunError(RuntimeError):
    """A failure that is not the input's (cluster unreachable, a worker lost, a disk full): exit 1."""


class Interrupted(BaseException):
    """The run was stopped by a signal; `code` is the exit status (128 + signal number)."""

    def __init__(self, signame: str, code: int, detail: str = ""):
        super().__init__(signame)
        self.signame = signame
        self.code = code
        self.detail = detail  # appended to the line the user sees, e.g. "; run again to resume"
