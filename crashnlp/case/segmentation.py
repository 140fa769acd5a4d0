"""Where a measured curve bends: breakpoints of its best piecewise-linear approximation.

The force-crush curve a crash test measures runs through plateaus and ramps: the bumper beam's
first peak, the rails' folds, the stack-up. A piecewise-linear law whose breakpoints sit where
those bend follows them with few breakpoints; evenly spaced ones put corners inside plateaus.

`bends` averages the curve over BANDS equal crush bands and splits them into segments that
minimise the squared misfit of a straight line fitted to each (the optimal segmentation by
dynamic programming, Bellman 1961), no segment shorter than MIN_SPACING times the even spacing,
so that two breakpoints never come so close that the data cannot tell their values apart. A
tie (a straight curve, where any split fits) goes to the most even split.

`misfit` says how closely a spring law with given breakpoints can follow the curve: the RMS
residual of the continuous piecewise-linear least-squares curve through them over the same band
means (crashnlp.case.completion chooses the number of breakpoints by it).
"""

from __future__ import annotations

import numpy as np

BANDS = 70  # crush bands the curve is averaged over (at least 4 per segment)
MIN_SPACING = 0.6  # the shortest segment, relative to the even spacing
EVEN_WEIGHT = 1e-6  # the tie-break toward even segments, relative to the curve's sum of squares


def bends(crush: np.ndarray, force: np.ndarray, top: float, count: int) -> list[float]:
    """`count` breakpoints from 0 to `top`, where the curve (`force` against `crush`) bends."""
    segments = count - 1
    bands = max(BANDS, 4 * segments)
    edges = np.linspace(0.0, top, bands + 1)
    at, means = band_means(crush, force, edges)
    shortest = max(2, int(np.ceil(MIN_SPACING * bands / segments)))
    spread = float(np.sum((means - np.mean(means)) ** 2))  # the curve's own sum of squares
    cost = line_misfits(at, means) + EVEN_WEIGHT * spread * _shares(bands) ** 2
    return [float(edges[c]) for c in _split(cost, segments, shortest)]


def misfit(crush: np.ndarray, force: np.ndarray, top: float, breakpoints: list[float]) -> float:
    """RMS residual of the continuous piecewise-linear curve through `breakpoints` that fits the
    curve's BANDS band means from 0 to `top` by least squares (the curve's unit)."""
    at, means = band_means(crush, force, np.linspace(0.0, top, BANDS + 1))
    hats = np.column_stack([np.interp(at, breakpoints, unit) for unit in np.eye(len(breakpoints))])
    values = np.linalg.lstsq(hats, means, rcond=None)[0]
    return float(np.sqrt(np.mean((hats @ values - means) ** 2)))


def band_means(crush: np.ndarray, force: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean crush and mean force in each crush band; a band without samples takes its
    centre and the force its neighbours' line gives there."""
    band = np.clip(np.searchsorted(edges, crush, side="right") - 1, 0, len(edges) - 2)
    counts = np.bincount(band, minlength=len(edges) - 1)
    seen = counts > 0
    at = 0.5 * (edges[1:] + edges[:-1])
    at[seen] = np.bincount(band, crush, len(edges) - 1)[seen] / counts[seen]
    means = np.bincount(band, force, len(edges) - 1)[seen] / counts[seen]
    return at, np.interp(at, at[seen], means)


def line_misfits(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """cost[i, j]: the squared misfit of the least-squares line through points i to j - 1
    (infinite for fewer than two), from prefix sums."""
    s = [np.concatenate([[0.0], np.cumsum(v)]) for v in (np.ones_like(x), x, y, x * x, x * y, y * y)]
    n, sx, sy, sxx, sxy, syy = (a[None, :] - a[:, None] for a in s)
    with np.errstate(divide="ignore", invalid="ignore"):
        vx, cxy = sxx - sx * sx / n, sxy - sx * sy / n
        cost = syy - sy * sy / n - cxy * cxy / vx
    return np.where(n >= 2, np.maximum(cost, 0.0), np.inf)


def _shares(bands: int) -> np.ndarray:
    """shares[i, j]: the share of all bands that bands i to j - 1 make."""
    i = np.arange(bands + 1)
    return (i[None, :] - i[:, None]) / bands


def _split(cost: np.ndarray, segments: int, shortest: int) -> list[int]:
    """The band edges 0 = c_0 < ... < c_segments = len(cost) - 1 minimising the sum of
    cost[c_k, c_k+1], every segment at least `shortest` bands long. Each segment count's best
    ends are found for every end at once (a matrix of start x end): the first cheapest start
    wins, and where none is finite, the first start allowed."""
    bands = cost.shape[0] - 1
    best = np.full((segments + 1, bands + 1), np.inf)
    came_from = np.zeros((segments + 1, bands + 1), dtype=int)
    best[0, 0] = 0.0
    edge = np.arange(bands + 1)
    for k in range(1, segments + 1):
        first = (k - 1) * shortest  # the first start allowed; a start s serves the ends j >= s + shortest
        allowed = (edge[:, None] >= first) & (edge[None, :] - edge[:, None] >= shortest)
        total = np.where(allowed, best[k - 1][:, None] + cost, np.inf)[:, k * shortest :]
        cheapest = np.argmin(total, axis=0)
        low = total[cheapest, np.arange(total.shape[1])]
        came_from[k, k * shortest :] = np.where(np.isposinf(low), first, cheapest)
        best[k, k * shortest :] = low
    cuts = [bands]
    for k in range(segments, 0, -1):
        cuts.append(int(came_from[k, cuts[-1]]))
    return cuts[::-1]
