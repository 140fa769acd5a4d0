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

What is derived from a run (`deriving`: a report, an export, a simulation of its result) and
written inside its folder is listed in its record too, with the sha256 of what was written: the
next run into the folder replaces that run, and removes these files with it (a nested
simulation derived from it with all its files), naming them on stderr, so that nothing of an
old fit sits beside a new one unannounced. A derived file changed since crashnlp wrote it is
kept, and named.
"""

from __future__ import annotations

import csv
import fcntl
import hashlib
import json
import os
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from crashnlp.base.cache import cache_dir, replaced_atomically, temporary_file
from crashnlp.base.errors import InputError


@contextmanager
def atomic_open(path: Path, mode: str = "w", kind: OutputKind | None = None) -> Iterator[IO[Any]]:
    """An output file written in full or not at all (crashnlp.base.cache.replaced_atomically),
    noted as the run's once written (`note_output`), and as a file crashnlp wrote as `kind`
    (OutputKind.note) where it is one --out may name."""
    with replaced_atomically(path, mode) as fh:
        yield fh
    note_output(path)
    if kind is not None:
        kind.note(path)


def write_columns(
    path: Path, columns: dict[str, np.ndarray], comments: tuple[str, ...] = (), kind: OutputKind | None = None
) -> None:
    """A CSV of numeric columns (header: their names), nine significant digits, a zero as 0 (not
    -0: adding 0.0 makes -0.0 0.0); `comments` go first, each a line starting with "# " (what the
    columns are, a check of them); `kind`: as atomic_open's."""
    with atomic_open(path, kind=kind) as fh:
        fh.writelines(f"# {line}\n" for line in comments)
        writer = csv.writer(fh)
        writer.writerow(columns)
        for row in zip(*(np.asarray(c, dtype=float) + 0.0 for c in columns.values())):
            writer.writerow([f"{v:.9g}" for v in row])


def check_writable(out: str | Path, option: str | None = "--out") -> Path:
    """Refuse, before any work, an output folder that cannot be created or written; create nothing.
    Its errors name `option` and the folder (the folder alone for None: Result.save's).

    The nearest existing ancestor must be a folder in which a file can be made (a probe file,
    removed at once), which also catches read-only file systems and running as root.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{_where(out, option)}: exists and is not a folder")
    probe = out
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"{_where(out, option)}: {probe} is not a folder")
    try:
        fd, made = temporary_file(probe, ".crashnlp-probe.")
        try:
            os.close(fd)
        finally:
            os.unlink(made)
    except OSError as exc:
        raise InputError(f"{_where(out, option)}: cannot write in {probe} ({exc.strerror or exc})") from None
    return out


RECORD = ".crashnlp-run.json"  # in an output folder: the run that wrote it and its files; locked while a run writes


@dataclass
class _Claim:
    run: str
    entries: set[str] = field(default_factory=set)  # the run's files, relative to its folder


_held: dict[Path, _Claim] = {}  # folders this process has claimed (resolved)
_deriving: dict[Path, set[str]] = {}  # folders whose run this process derives files from (`deriving`), and the files


def run_name(command: str, name: str) -> str:
    """What a folder's record calls a run: the command and the problem's or study's name."""
    return f"{command} {name}"


def recorded_name(folder: Path, command: str) -> str | None:
    """The problem's or study's name the `command` run that wrote `folder` recorded (`run_name`),
    None where its record names no such run."""
    recorded, _, name = str(_read_record(folder / RECORD).get("run", "")).partition(" ")
    return name if recorded == command and name else None


def check_output(out: str | Path, run: str, option: str = "--out", entries: Iterable[str] = ()) -> Path:
    """check_writable, and refuse a folder that holds another run's results (its record names
    another `run` than this, e.g. "identify pickup-56kph") or something in the way of the files
    the run writes there (`entries`: check_entries); read only, so --check may call it."""
    out = check_writable(out, option)
    _refuse_another(out, _read_record(out / RECORD).get("run"), run, option)
    check_entries(out, entries, option)
    return out


def check_entries(out: Path, entries: Iterable[str], option: str | None = "--out") -> None:
    """Refuse, before any work, what in `out` stands where a run writes its files (`entries`, by
    name within it, "56kph/response.csv"): a folder where a file goes, a file where a folder goes.
    Found only as the run writes, it would end the run after its solve, half written."""
    for name in entries:
        path = out / name
        folders = [f for f in path.parents if f != out and f.is_relative_to(out)]
        entry = next((f for f in reversed(folders) if f.exists() and not f.is_dir()), None)
        if entry is not None:
            raise InputError(f"{_where(out, option)}: {entry} is a file where crashnlp writes a folder; remove or move it")
        if path.is_dir():
            raise InputError(f"{_where(out, option)}: {path} is a folder where crashnlp writes a file; remove or move it")


@contextmanager
def claim(out: Path, run: str, option: str | None = "--out") -> Iterator[Path]:
    """The output folder `out`, created if need be, for `run` to write in (see the module's
    docstring): InputError for a folder another run is writing in at the moment, that holds
    the results of another, or that cannot be made or written (check_writable: a file in its
    place). Leaving the block normally, what the earlier run of the same `run` wrote there and
    this one did not is removed; leaving it by an exception, nothing is removed,
    and the folders this claim made are removed again if nothing was written in them. A claim
    inside one of the same run (the command line's, around Result.save) is the outer one's."""
    key = out.resolve()
    held = _held.get(key)
    if held is not None:
        _refuse_another(out, held.run, run, option)
        yield out
        return
    made = [p for p in (out, *out.parents) if not p.exists()]
    check_writable(out, option)
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
            _keep(out, fd, run, before | mine.entries, made, _derived_of(earlier))
            raise
        _remove(out, before - mine.entries)
        _remove_derived(out, _derived_of(earlier), mine.entries)
        _keep(out, fd, run, mine.entries, made)
    finally:
        _held.pop(key, None)
        os.close(fd)


@contextmanager
def deriving(folder: Path, target: Path) -> Iterator[None]:
    """Around the writing of `target` (a file or a folder) from the run in `folder`: a report, an
    export, a simulation of its result. Where `target` lies inside `folder` and a run's record is
    there, the files written in the block are listed in that record as derived from its run, each
    with the sha256 of what was written, for the next run into `folder`, which replaces it, to
    remove (`claim`). A file written outside the folder is the user's to keep; a folder this
    process has claimed counts the file among the run's own. InputError for a folder another
    run is writing in now."""
    key = folder.resolve()
    if not target.resolve().is_relative_to(key) or key in _held or not _read_record(folder / RECORD):
        yield
        return
    fd = _lock(folder, None)
    try:
        names: set[str] = set()
        _deriving[key] = names
        yield
        record = _read_record(folder / RECORD)
        entries = set(record.get("entries", ()))
        derived = _derived_of(record) | {n: file_sha256(folder / n) for n in names - entries if (folder / n).is_file()}
        _write_record(fd, {**record, "derived": dict(sorted(derived.items()))})
    finally:
        _deriving.pop(key, None)
        os.close(fd)


def note_output(path: Path) -> None:
    """Count `path` among the files of the run that has claimed the folder it lies in: a file
    written, a figure drawn, or one it keeps (a study's case finished by an earlier run); and
    among those derived from the run of a folder it lies in (`deriving`)."""
    path = path.resolve()
    for folder, held in _held.items():
        if path.is_relative_to(folder) and path != folder:
            held.entries.add(path.relative_to(folder).as_posix())
    for folder, names in _deriving.items():
        if path.is_relative_to(folder) and path != folder:
            names.add(path.relative_to(folder).as_posix())


def file_sha256(path: Path) -> str:
    """The sha256 of a file's bytes, in hex."""
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


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


def _derived_of(record: dict[str, Any]) -> dict[str, str]:
    """A record's derived files (`deriving`): name -> sha256 ({} for none, or not a mapping of text)."""
    derived = record.get("derived")
    if not isinstance(derived, dict):
        return {}
    return {k: v for k, v in derived.items() if isinstance(k, str) and isinstance(v, str)}


def _inside(out: Path, name: str) -> bool:
    """Whether out/name lies inside `out` (a record edited to name ../x or /x names nothing there)."""
    path = out / name
    return path.parent.resolve().is_relative_to(out.resolve()) and path.name not in ("", ".", "..")


def _remove(out: Path, names: set[str]) -> None:
    """Remove the named files inside `out` (an earlier run's that this one did not write), and the
    folders inside `out` that this leaves empty (nothing else: never a folder with anything else in it)."""
    for name in sorted(names - {RECORD}):
        path = out / name
        if _inside(out, name) and not path.is_dir():
            path.unlink(missing_ok=True)
            _prune(path, out)


def _prune(path: Path, out: Path) -> None:
    """Remove the folders between `path` and `out` (not `out`) that are empty, innermost first."""
    for folder in path.parents:
        if folder == out:
            break
        try:
            folder.rmdir()
        except OSError:
            break


def _remove_derived(out: Path, derived: dict[str, str], written: set[str]) -> None:
    """Remove the files derived from the run this one replaces (`deriving`), and say so on
    stderr: each that still holds what crashnlp wrote, and a run nested in `out` (a simulation
    of the replaced result) every file of which derived from it as it is now, with its record.
    A file changed since, or a nested run written again since, is kept and named."""
    removed, kept = [], []
    nested: dict[Path, set[str]] = {}  # a nested run's folder -> its files derived from the replaced run, as written
    for name, digest in sorted(derived.items()):
        path = out / name
        if name in written or not _inside(out, name) or not path.is_file():
            continue
        same = file_sha256(path) == digest
        run = next((f for f in path.parents if f != out and f.is_relative_to(out) and (f / RECORD).is_file()), None)
        if run is not None:
            nested.setdefault(run, set()).update({path.relative_to(run).as_posix()} if same else set())
        elif same:
            _remove(out, {name})
            removed.append(name)
        else:
            kept.append(name)
    for folder, as_written in nested.items():
        name = f"{folder.relative_to(out).as_posix()}/"
        own = set(_read_record(folder / RECORD).get("entries", ()))
        if own and own <= as_written and _remove_run(folder, out, as_written - own):
            removed.append(name)
        else:
            kept.append(name)
    if removed:
        print(f"crashnlp: {out}: removed {', '.join(removed)}: derived from the run replaced", file=sys.stderr)
    if kept:
        print(f"crashnlp: {out}: kept {', '.join(kept)}: derived from the run replaced, but changed since", file=sys.stderr)


def _remove_run(folder: Path, out: Path, extra: set[str]) -> bool:
    """Remove the run in `folder` (inside `out`): the files its record lists, those derived from
    it that are as written, its record, and the `extra` files in it; False, removing nothing,
    where another run holds it."""
    try:
        fd = _lock(folder, None)
    except InputError:
        return False
    try:
        record = _read_record(folder / RECORD)
        _remove(folder, set(record.get("entries", ())) | extra)
        _remove_derived(folder, _derived_of(record), set())
        (folder / RECORD).unlink(missing_ok=True)
    finally:
        os.close(fd)
    _prune(folder / RECORD, out)
    return True


def _write_record(fd: int, record: dict[str, Any]) -> None:
    """Write a record in place, through its locked descriptor."""
    os.ftruncate(fd, 0)
    os.pwrite(fd, json.dumps(record, indent=1).encode(), 0)


def _keep(out: Path, fd: int, run: str, entries: set[str], made: list[Path], derived: dict[str, str] | None = None) -> None:
    """Write the record in place (under the lock), with the files `derived` from the run still
    there, or where the run has no file there, remove it and the folders the claim made."""
    present = sorted(name for name in entries if (out / name).is_file())
    kept = {name: digest for name, digest in (derived or {}).items() if (out / name).is_file()}
    if present or kept:
        _write_record(fd, {"run": run, "entries": present} | ({"derived": kept} if kept else {}))
        return
    (out / RECORD).unlink(missing_ok=True)
    for folder in made:
        try:
            folder.rmdir()
        except OSError:
            return


def file_option(text: str, option: str = "--out") -> Path:
    """The file an option names; a name that ends in a separator names a folder (Path drops the
    separator, so a missing folder `new/dir/` would be written as a file `dir`): refused."""
    if text.endswith(("/", os.sep)):
        raise InputError(f"{option} {text}: a folder; name the file to write")
    return Path(text)


def check_writable_file(path: str | Path, option: str = "--out", own: Path | None = None, kind: OutputKind | None = None) -> Path:
    """Refuse, before any work, a file to write that is a folder, whose folder cannot be written,
    or that a run's record lists (a fit's result.json, a test's response.csv: written over, that
    run's folder no longer reads); `own`, the file the command writes when not told otherwise,
    may be written again. Given the `kind` of file the command writes, an existing file other
    than `own` is written over only where crashnlp wrote it as that kind, unchanged since
    (`OutputKind.wrote`): anything else there (a test's data, a problem file, a user's own, an
    edited export) is refused."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {path}: is a folder; name the file to write")
    check_writable(path.parent, option)
    if own is not None and path.resolve() == own.resolve():
        return path
    listed = _listed_by(path)
    if listed is not None:
        raise InputError(f"{option} {path}: is a file of the run {listed[0]} in {listed[1]}; name another file")
    if kind is not None and path.exists() and not kind.wrote(path):
        raise InputError(
            f"{option} {path}: exists, and is no {kind.what} crashnlp wrote (or it was changed since); name another file,"
            " or remove it first"
        )
    return path


WRITTEN = "written"  # the cache's folder of the files crashnlp wrote to an --out it may write over again (OutputKind)


@dataclass(frozen=True)
class OutputKind:
    """A kind of file a command writes to --out (a report, an LS-DYNA export, a pulse, a curve CSV):
    what to call it. Each one written is noted in the crashnlp cache by the sha256 of its bytes
    (`note`), so that --out writes over a file only where crashnlp wrote it as this kind and it is
    unchanged since (`wrote`): an edited file, a deck the curves were pasted into, a user's own
    file of the same name are refused. With the cache deleted, crashnlp's earlier files are too."""

    what: str

    def wrote(self, path: Path) -> bool:
        """Whether the file at `path` is, byte for byte, one crashnlp wrote as this kind."""
        try:
            return self._noted(file_sha256(path)).exists()
        except OSError:
            return False

    def note(self, path: Path) -> None:
        """Note the file just written at `path` as this kind's (none where the cache cannot be
        written: the file is then refused as any other)."""
        with suppress(OSError):
            noted = self._noted(file_sha256(path))
            noted.parent.mkdir(parents=True, exist_ok=True)
            noted.touch()

    def _noted(self, sha256: str) -> Path:
        return cache_dir() / WRITTEN / f"{self.what.replace(' ', '-')}-{sha256}"


def _listed_by(path: Path) -> tuple[str, Path] | None:
    """The run whose record lists `path` (or is `path`), and its folder; None for no run's file."""
    path = path.resolve()
    for folder in path.parents:
        record = _read_record(folder / RECORD)
        name = path.relative_to(folder).as_posix()
        if record and (name == RECORD or name in record.get("entries", ())):
            return record["run"], folder
    return None
