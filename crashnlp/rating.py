"""ISO/TS 18571 objective rating of a model curve against a reference curve.

Uses the `objective-rating-metrics` package (ISO18571 class). ISO/TS 18571 rates signals
sampled at 10 kHz, so both curves are linearly resampled to a 10 kHz grid over the span of `t`
when `t` is sampled otherwise.

The package's dynamic time warping (dtwalign) is compiled by numba on first use, several
seconds in every new process; its compiled functions are cached on disk under the crashnlp
cache (numba's own cache, keyed on the source and the machine), so only the first process
on a machine pays.
"""

from __future__ import annotations

import os
from functools import cache

import numpy as np

ISO_DT = 1e-4  # s, the 10 kHz sampling ISO/TS 18571 assumes


def iso18571(t: np.ndarray, reference: np.ndarray, model: np.ndarray) -> dict[str, float]:
    """Corridor, phase, magnitude, slope and overall ratings (each 0..1, 1 = identical curves).

    `t` [s] is the common, increasing time grid of `reference` and `model` (same units).
    """
    t, ref, mod = (np.asarray(a, dtype=float) for a in (t, reference, model))
    if not (t.shape == ref.shape == mod.shape) or t.size < 10:
        raise ValueError("t, reference and model need the same length (at least 10 samples)")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t must be increasing")
    if np.max(np.abs(np.diff(t) - ISO_DT)) > 1e-3 * ISO_DT:
        grid = t[0] + ISO_DT * np.arange(int(np.floor((t[-1] - t[0]) / ISO_DT + 1e-9)) + 1)
        ref, mod, t = np.interp(grid, t, ref), np.interp(grid, t, mod), grid
    rating = _library()(np.column_stack([t, ref]), np.column_stack([t, mod]), dt=ISO_DT)
    return {
        "corridor": float(rating.corridor_rating(ndigits=-1)),
        "phase": float(rating.phase_rating(ndigits=-1)),
        "magnitude": float(rating.magnitude_rating(ndigits=-1)),
        "slope": float(rating.slope_rating(ndigits=-1)),
        "overall": float(rating.overall_rating(ndigits=-1)),
    }


@cache
def _library():
    """The ISO18571 class, its numba functions cached on disk (numba reads NUMBA_CACHE_DIR once,
    when it is first imported, which happens here)."""
    from crashnlp.compiled import cache_dir

    os.environ.setdefault("NUMBA_CACHE_DIR", str(cache_dir() / "numba"))
    from dtwalign import backtrack, cost, window
    from objective_rating_metrics.rating import ISO18571

    for module in (backtrack, cost, window):
        for value in vars(module).values():
            if hasattr(value, "enable_caching") and hasattr(value, "py_func"):
                value.enable_caching()
    return ISO18571
