"""Output folders and files: checked before any work, written atomically with the usual mode."""

from __future__ import annotations

import csv
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import numpy as np

from crashnlp.errors import InputError


def umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def public_mode(fd: int) -> None:
    """Give a file made by `tempfile.mkstemp` (mode 0600) the mode `open` would: 0666 less the umask."""
    os.fchmod(fd, 0o666 & ~umask())


def atomic_temp(folder: Path) -> tuple[int, str]:
    """A temporary file in `folder` with the usual mode, to be renamed over its target (`os.replace`)."""
    fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
    public_mode(fd)
    return fd, tmp


@contextmanager
def atomic_open(path: Path, mode: str = "w") -> Iterator[IO[Any]]:
    """A file written in full or not at all: a temporary file beside `path`, renamed over it
    when the block ends (a reader never sees half a file), with the usual mode."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = atomic_temp(path.parent)
    try:
        newline = None if "b" in mode else ""  # csv writes its own line ends
        with open(fd, mode, newline=newline) as fh:
            yield fh
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_columns(path: Path, columns: dict[str, np.ndarray], comments: tuple[str, ...] = ()) -> None:
    """A CSV of numeric columns (header: their names), nine significant digits; `comments` go
    first, each a line starting with "# " (what the columns are, a check of them)."""
    with atomic_open(path) as fh:
        fh.writelines(f"# {line}\n" for line in comments)
        writer = csv.writer(fh)
        writer.writerow(columns)
        for row in zip(*(np.asarray(c, dtype=float) for c in columns.values())):
            writer.writerow([f"{v:.9g}" for v in row])


def check_writable(out: str | Path, option: str = "--out") -> Path:
    """Refuse, before any work, an output folder that cannot be created or written; create nothing.

    The nearest existing ancestor must be a folder in which a file can be made (a probe file,
    removed at once), which also catches read-only file systems and running as root.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{option} {out}: exists and is not a folder")
    probe = out
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"{option} {out}: {probe} is not a folder")
    try:
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as exc:
        raise InputError(f"{option} {out}: cannot write in {probe} ({exc.strerror or exc})") from None
    return out


def check_writable_file(path: str | Path, option: str = "--out") -> Path:
    """Refuse, before any work, a file to write that is a folder or whose folder cannot be written."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {path}: is a folder; name the file to write")
    check_writable(path.parent, option)
    return path
