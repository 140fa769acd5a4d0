"""The crashnlp cache folder: compiled functions (with a lock file each: crashnlp.numerics.compiled)
and remembered unit conversions.

CRASHNLP_CACHE, default ~/.cache/crashnlp. Everything in it can be deleted at any
time: it is rebuilt on demand, and results never depend on it.
"""

from __future__ import annotations

import os
from pathlib import Path

CACHE_ENV = "CRASHNLP_CACHE"


def cache_dir() -> Path:
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "crashnlp")
