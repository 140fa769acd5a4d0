"""The crashnlp cache folder: compiled functions (with a lock file each: crashnlp.numerics.compiled),
derived models (crashnlp.models.stored) and remembered unit conversions.

CRASHNLP_CACHE, default ~/.cache/crashnlp. Everything in it can be deleted at any
time: it is rebuilt on demand, and results never depend on it. A compile keeps it within
CRASHNLP_CACHE_MB (crashnlp.numerics.compiled).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

CACHE_ENV = "CRASHNLP_CACHE"


def cache_dir() -> Path:
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "crashnlp")


def write_atomic(path: Path, text: str) -> None:
    """Write `text` under a temporary name beside `path`, then rename it in place: a reader sees
    the whole file or none, and two writers of the same file the one or the other."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
