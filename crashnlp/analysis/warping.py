"""The dynamic time warping of crashnlp.analysis.rating compiled to C (warping.c beside this file),
loaded with ctypes: the same paths to the bit as rating's numpy recurrence, in a sixth of its time.

The library is compiled once per machine, like the NLPs' (crashnlp.numerics.compiled: the cache
folder, a name hashed from the source, the compiler and its flags, a lock): the first rating that
finds it missing starts its compile, at nice 19 from its start (no run waits for it), and rates
in numpy meanwhile; a compile still running when the command ends finishes after it, with a line
that says so (crashnlp.numerics.compile_job). Compiled where the NLPs are (not with
CRASHNLP_COMPILE=0 or =model); without a compiler or a usable cache the numpy recurrence rates,
with the same numbers.
"""

from __future__ import annotations

import ctypes
import hashlib
import subprocess
from pathlib import Path

import numpy as np

from crashnlp.numerics import compile_job, compiled

SOURCE = Path(__file__).with_name("warping.c")
FLAGS = ("-O2", "-ffp-contract=off", "-fPIC", "-shared")  # no contraction into FMA: numpy's bits
WHAT = "the ISO 18571 rating's time warping"  # in the line that says a compile goes on after the command
_loaded: list[ctypes.CDLL] = []
_DOUBLES = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS")
_LONGS = np.ctypeslib.ndpointer(dtype=np.int64, flags="C_CONTIGUOUS")


def kernel() -> ctypes.CDLL | None:
    """The compiled warping, loaded; None while the cache holds none that is whole (its compile started
    then, unless one runs), without a compiler or with compiles switched off."""
    if _loaded:
        return _loaded[0]
    cc = compiled.compiler(nlp=True)
    if cc is None:
        return None
    source = SOURCE.read_text()
    library = _library(cc, source)
    try:
        lib = compiled.load_cached(library, lambda: ctypes.CDLL(str(library)))
        if lib is None:
            compiled.start_behind(cc, library, FLAGS, lambda: source, what=WHAT, nice=compile_job.BACKGROUND_NICE)
            return None
    except (OSError, RuntimeError, subprocess.CalledProcessError):  # no usable cache or compiler: numpy
        return None
    lib.warping_path.restype = ctypes.c_long
    lib.warping_path.argtypes = [_DOUBLES, _DOUBLES, ctypes.c_long, ctypes.c_long, _DOUBLES, _LONGS, _LONGS]
    _loaded.append(lib)
    return lib


def _library(cc: str, source: str) -> Path:
    """Where the library of `source` compiled by `cc` is kept: named by a hash of both and FLAGS."""
    key = hashlib.sha256("\0".join([source, cc, *FLAGS]).encode()).hexdigest()[:20]
    return compiled.cache_dir() / f"warping-{key}.so"


def warping_path(lib: ctypes.CDLL, x: np.ndarray, y: np.ndarray, band: int) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i of x, j of y) of the warping of equally long `x` and `y` within |i - j| <= `band`,
    from (0, 0) to the end (crashnlp.analysis.rating._warping_paths' rules)."""
    n = x.size
    cost = np.empty(n * (2 * band + 2) + 1)
    path_i, path_j = np.empty(2 * n, dtype=np.int64), np.empty(2 * n, dtype=np.int64)
    count = lib.warping_path(np.ascontiguousarray(x, float), np.ascontiguousarray(y, float), n, band, cost, path_i, path_j)
    return path_i[count - 1 :: -1], path_j[count - 1 :: -1]
