"""Output folders and files: checked before any work, written atomically with the usual mode,
and one run's at a time.

An output folder holds one run: `claim` locks it for the run (a second run into it at once is
refused, not mixed in), refuses a folder that holds another run's results (another problem,
study or command), and once the run is done removes what the same run wrote there before and
did not write again (a renamed test's files, and its folder once empty). Its record, RECORD in
the folder, names the run and the files it wrote (every file goes through `atomic_open`, every
figure through crashnlp.results.drawing or crashnlp.results.plots, which note them, and a study notes the cases
it keeps); nothing else is ever removed: a user's own files, a run's folder nested in another's
(a simulation inside its fit's folder).
"""

from __future__ import annotations

import csv
import fcntl
import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from crashnlp.base.errors import InputError


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
        note_output(path)
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


RECORD = ".crashnlp-run.json"  # in an output folder: the run that wrote it and its files; locked while a run writes


@dataclass
class _Claim:
    run: str
    entries: set[str] = field(default_factory=set)  # the run's files, relative to its folder


_held: dict[Path, _Claim] = {}  # folders this process has claimed (resolved)


def run_name(command: str, name: str) -> str:
    """What a folder's record calls a run: the command and the problem's or study's name."""
    return f"{command} {name}"


def recorded_name(folder: Path, command: str) -> str | None:
    """The problem's or study's name the `command` run that wrote `folder` recorded (`run_name`),
    None where its record names no such run."""
    recorded, _, name = str(_read_record(folder / RECORD).get("run", "")).partition(" ")
    return name if recorded == command and name else None


def check_output(out: str | Path, run: str, option: str = "--out") -> Path:
    """check_writable, and refuse a folder that holds another run's results (its record names
    another `run` than this, e.g. "identify pickup-56kph"); read only, so --check may call it."""
    out = check_writable(out, option)
    _refuse_another(out, _read_record(out / RECORD).get("run"), run, option)
    return out


@contextmanager
def claim(out: Path, run: str, option: str | None = "--out") -> Iterator[Path]:
    """The output folder `out`, created if need be, for `run` to write in (see the module's
    docstring): InputError for a folder another run is writing in at the moment, or that holds
    the results of another. Leaving the block normally, what the earlier run of the same `run`
    wrote there and this one did not is removed; leaving it by an exception, nothing is removed,
    and the folders this claim made are removed again if nothing was written in them. A claim
    inside one of the same run (the command line's, around Result.save) is the outer one's."""
    key = out.resolve()
    held = _held.get(key)
    if held is not None:
        _refuse_another(out, held.run, run, option)
        yield out
        return
    made = [p for p in (out, *out.parents) if not p.exists()]
    out.mkdir(parents=True, exist_ok=True)
    fd = _lock(out, option)
    try:
        earlier = _read_record(out / RECORD)
        _refuse_another(out, earlier.get("run"), run, option)
        before = set(earlier.get("entries", ()))
        _held[key] = mine = _Claim(run)
        try:
            yield out
        except BaseException:
            _keep(out, fd, run, before | mine.entries, made)
            raise
        _remove(out, before - mine.entries)
        _keep(out, fd, run, mine.entries, made)
    finally:
        _held.pop(key, None)
        os.close(fd)


def note_output(path: Path) -> None:
    """Count `path` among the files of the run that has claimed the folder it lies in: a file
    written, a figure drawn, or one it keeps (a study's case finished by an earlier run)."""
    path = path.resolve()
    for folder, held in _held.items():
        if path.is_relative_to(folder) and path != folder:
            held.entries.add(path.relative_to(folder).as_posix())


def _lock(out: Path, option: str | None) -> int:
    """An open descriptor of out/RECORD, locked (flock) for this process; InputError if another
    holds it. A record removed between its opening and its locking is opened again."""
    path = out / RECORD
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise InputError(
                f"{_where(out, option)}: another crashnlp run is writing in it now ({RECORD} is locked); "
                "wait for it to finish, or give another folder"
            ) from None
        if path.exists() and path.stat().st_ino == os.fstat(fd).st_ino:
            return fd
        os.close(fd)


def _where(out: Path, option: str | None) -> str:
    return f"{option} {out}" if option else str(out)


def _read_record(path: Path) -> dict[str, Any]:
    """A folder's record ({} where there is none, or it is not one)."""
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) and isinstance(record.get("run"), str) else {}


def _refuse_another(out: Path, holder: str | None, run: str, option: str | None) -> None:
    if holder is not None and holder != run:
        raise InputError(
            f"{_where(out, option)}: holds the results of another run ({holder}), not of {run}; "
            "give another folder, or remove that one first"
        )


def _remove(out: Path, names: set[str]) -> None:
    """Remove the files an earlier run wrote and this one did not, and the folders inside `out`
    that this leaves empty (nothing else: never a folder with anything else in it)."""
    root = out.resolve()
    for name in sorted(names - {RECORD}):
        path = out / name
        inside = path.parent.resolve().is_relative_to(root) and path.name not in ("", ".", "..")
        if inside and not path.is_dir():  # a record edited to name ../x removes nothing outside
            path.unlink(missing_ok=True)
            for folder in path.parents:
                if folder == out:
                    break
                try:
                    folder.rmdir()
                except OSError:
                    break


def _keep(out: Path, fd: int, run: str, entries: set[str], made: list[Path]) -> None:
    """Write the record in place (under the lock), or where the run has no file there, remove it
    and the folders the claim made."""
    present = sorted(name for name in entries if (out / name).is_file())
    if present:
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps({"run": run, "entries": present}, indent=1).encode(), 0)
        return
    (out / RECORD).unlink(missing_ok=True)
    for folder in made:
        try:
            folder.rmdir()
        except OSError:
            return


def check_writable_file(path: str | Path, option: str = "--out", own: Path | None = None) -> Path:
    """Refuse, before any work, a file to write that is a folder, whose folder cannot be written,
    or that a run's record lists (a fit's result.json, a test's response.csv: written over, that
    run's folder no longer reads); `own`, the file the command writes when not told otherwise,
    may be written again."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {path}: is a folder; name the file to write")
    check_writable(path.parent, option)
    listed = None if own is not None and path.resolve() == own.resolve() else _listed_by(path)
    if listed is not None:
        raise InputError(f"{option} {path}: is a file of the run {listed[0]} in {listed[1]}; name another file")
    return path


def _listed_by(path: Path) -> tuple[str, Path] | None:
    """The run whose record lists `path` (or is `path`), and its folder; None for no run's file."""
    path = path.resolve()
    for folder in path.parents:
        record = _read_record(folder / RECORD)
        name = path.relative_to(folder).as_posix()
        if record and (name == RECORD or name in record.get("entries", ())):
            return record["run"], folder
    return None
