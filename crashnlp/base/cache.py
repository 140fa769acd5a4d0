"""The crashnlp cache folder: compiled functions (with a lock file and a sha256 record each:
crashnlp.numerics.compiled), derived models (crashnlp.models.stored), remembered unit conversions
(crashnlp.base.units), the installed IPOPT's options (crashnlp.problem.ipopt) and the values of the
YAML files (problems, studies) read before (crashnlp.problem.load), and the sha256 of each file a
report or an export wrote (crashnlp.results.files.OutputKind: what --out may write over again).

CRASHNLP_CACHE, default ~/.cache/crashnlp. Everything in it can be deleted at any
time: it is rebuilt on demand, and results never depend on it (with the written files' sha256
gone, --out refuses crashnlp's earlier reports and exports as a user's own files). A compile keeps it within
CRASHNLP_CACHE_MB, removing the least recently used libraries and kept files (KEPT: YAML values,
stored models, unit conversions, IPOPT's options; crashnlp.numerics.compiled).
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from functools import cache
from pathlib import Path
from typing import IO, Any

CACHE_ENV = "CRASHNLP_CACHE"
NAME_TRIES = 100  # random temporary names tried before giving up (each clashes with odds 2^-64)
PREFIX_CHARS = 64  # of a temporary name's prefix (a target's own name): a long one would pass the system's limit
KEPT_YAML = "yaml-{key}.json"  # the values of a YAML text read before (crashnlp.problem.load), under a hash of it
KEPT_MODEL = "model-{form}-{key}.casadi"  # a model's expressions derived before (crashnlp.models.stored)
KEPT_UNITS = "units-pint-{version}.json"  # the conversions pint made before (crashnlp.base.units), by pint's version
KEPT_IPOPT = "ipopt-options-{key}.json"  # the installed IPOPT's options (crashnlp.problem.ipopt), by installation
# what the cache's limit removes without a lock, least recently used first (crashnlp.numerics.compiled):
# files written whole or not at all, made again by the next process that needs one that is gone
KEPT = (
    KEPT_YAML.format(key="*"),
    KEPT_MODEL.format(form="*", key="*"),
    KEPT_UNITS.format(version="*"),
    KEPT_IPOPT.format(key="*"),
)


def cache_dir() -> Path:
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "crashnlp")


def used(path: Path) -> None:
    """Mark the cached file `path` as used now (its modification time): the cache's limit removes
    the least recently used files first (crashnlp.numerics.compiled)."""
    with suppress(OSError):
        os.utime(path)


def temporary_file(folder: Path, prefix: str = "") -> tuple[int, str]:
    """A new file in `folder`, open for reading and writing, under a random name no other file has
    (O_EXCL), made with the mode `open` gives a new file (0666 less the umask): to be renamed over
    its target (`os.replace`). Not tempfile's: its files are 0600, and its import costs a command
    milliseconds."""
    flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
    for _ in range(NAME_TRIES):
        path = os.path.join(folder, f"{prefix[:PREFIX_CHARS]}{os.urandom(8).hex()}.tmp")
        try:
            return os.open(path, flags, 0o666), path
        except FileExistsError:
            continue
    raise FileExistsError(f"{folder}: no free temporary name in {NAME_TRIES} tries")


@contextmanager
def replaced_atomically(path: Path, mode: str = "w") -> Iterator[IO[Any]]:
    """A file written in full or not at all: a temporary file beside `path`, renamed over it when
    the block ends (a reader sees the whole file or none, and of two writers the one or the other)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = temporary_file(path.parent, f".{path.name}.")
    try:
        newline = None if "b" in mode else ""  # csv writes its own line ends
        with open(fd, mode, newline=newline) as fh:
            yield fh
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_atomic(path: Path, text: str) -> None:
    """Write `text` to `path` in full or not at all (`replaced_atomically`)."""
    with replaced_atomically(path) as fh:
        fh.write(text)


@cache
def installed_version(package: str, distribution: str) -> str:
    """The installed version of `distribution` (which installs the import package `package`), for
    the names of cache files that depend on it: from the name of its dist-info folder beside the
    package (pint-0.25.3.dist-info), since importing importlib.metadata costs more than reading a
    problem; importlib.metadata's answer where no such folder is there to read."""
    spec = importlib.util.find_spec(package)
    if spec is not None and spec.origin is not None:
        prefix = f"{distribution.lower()}-"
        site = Path(spec.origin).parent.parent
        found = [p.name for p in site.glob("*.dist-info") if p.name.lower().startswith(prefix)]
        if len(found) == 1:
            return found[0][len(prefix) :].removesuffix(".dist-info")
    from importlib.metadata import version

    return version(distribution)


def files_digest(paths: Iterable[Path], root: Path | None = None) -> str:
    """One sha256 (hex) of files' names and contents, in the order given: what the keys of cached
    things derived from code take (the models, a study's cases, the NLP libraries), so that other
    code finds none of them. A name is the path relative to `root`, or the file's name."""
    digest = hashlib.sha256()
    for path in paths:
        name = path.relative_to(root).as_posix() if root is not None else path.name
        digest.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()
