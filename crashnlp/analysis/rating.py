"""ISO/TS 18571 objective rating of a model curve against a reference curve.

The rating of the `objective-rating-metrics` package (class ISO18571 with its defaults,
unrounded), transcribed to numpy: the package's dynamic time warping (dtwalign) imports numba,
1.4 s and ~250 MB in every process; the warping runs in C once that is compiled
(crashnlp.analysis.warping), with the same paths. tests/test_rating.py holds the three equal.
ISO/TS 18571 rates signals sampled at 10 kHz, so both curves are linearly resampled to a 10 kHz
grid over the span of `t` when `t` is sampled otherwise.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from crashnlp.analysis import warping

ISO_DT = 1e-4  # s, the 10 kHz sampling ISO/TS 18571 assumes
MAX_SHIFT = 0.2  # largest time shift tried, and the one that rates phase 0, as a share of the samples
DTW_BAND = 0.1  # half-width of the warping band, as a share of the samples
A0, B0, K_Z = 0.05, 0.5, 2.0  # inner and outer corridor half-widths (share of max |reference|), exponent
EPS_M, K_M, E_S, K_P = 0.5, 1, 2.0, 1  # magnitude and slope errors that rate 0, exponents
WEIGHTS = {"corridor": 0.4, "phase": 0.2, "magnitude": 0.2, "slope": 0.2}
CORR_TOL = 1e-8  # the fast correlations' error is below CORR_TOL / 2 ...
SURE_VARIANCE = 1e-3  # ... when both overlaps vary this much (share of the whole curve's variation)


def iso18571(t: np.ndarray, reference: np.ndarray, model: np.ndarray) -> dict[str, float]:
    """Corridor, phase, magnitude, slope and overall ratings (each 0..1, 1 = identical curves).

    `t` [s] is the common, increasing time grid of `reference` and `model` (same units).
    """
    return iso18571_each([(t, reference, model)])[0]


def iso18571_each(curves: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> list[dict[str, float]]:
    """`iso18571` of each (t, reference, model), the same numbers, their dynamic time warpings
    run side by side in numpy (`_numpy_warping_paths`: one numpy operation a diagonal for all of
    them, where each curve's own took as long) or one after another in C (a fit's four channels
    rated in 113 ms with numpy's, 16 ms with the C's, measured at a load of 6)."""
    return _ratings_each([_at_iso_rate(*curve) for curve in curves])


def _ratings_each(curves: list[tuple[np.ndarray, np.ndarray]]) -> list[dict[str, float]]:
    """The five ratings of each (reference, model) at 10 kHz; magnitude and slope on the curves
    overlapped at the shift that correlates them best."""
    shifts = [_best_shift(ref, mod) for ref, mod in curves]
    overlaps = [_overlap(ref, mod, shift) for (ref, mod), shift in zip(curves, shifts)]
    paths = _warping_paths([(mod_s, ref_s) for ref_s, mod_s in overlaps]) if curves else []
    out = []
    for (ref, mod), shift, (ref_s, mod_s), path in zip(curves, shifts, overlaps, paths):
        rating = {
            "corridor": _corridor(ref, mod),
            "phase": _phase(ref.size, abs(shift)),
            "magnitude": _magnitude(ref_s, mod_s, path),
            "slope": _slope(ref_s, mod_s),
        }
        rating["overall"] = sum(WEIGHTS[k] * rating[k] for k in WEIGHTS)
        out.append({k: float(v) for k, v in rating.items()})
    return out


def _at_iso_rate(t: np.ndarray, reference: np.ndarray, model: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference and model at 10 kHz (ISO_DT), linearly resampled where `t` is sampled otherwise;
    refused where the three do not fit together."""
    t, ref, mod = (np.asarray(a, dtype=float) for a in (t, reference, model))
    if not (t.shape == ref.shape == mod.shape) or t.size < 10:
        raise ValueError("t, reference and model need the same length (at least 10 samples)")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t must be increasing")
    if np.max(np.abs(np.diff(t) - ISO_DT)) > 1e-3 * ISO_DT:
        grid = t[0] + ISO_DT * np.arange(int(np.floor((t[-1] - t[0]) / ISO_DT + 1e-9)) + 1)
        ref, mod = np.interp(grid, t, ref), np.interp(grid, t, mod)
    return ref, mod


def _corridor(ref: np.ndarray, mod: np.ndarray) -> float:
    """Mean score of the points: 1 inside the inner corridor, 0 outside the outer, between them
    falling with the K_Z power of the distance to the outer."""
    scale = np.max(np.abs(ref))
    inner, outer = A0 * scale, B0 * scale
    diff = np.abs(ref - mod)
    score = ((outer - diff) / (outer - inner)) ** K_Z
    score[diff < inner] = 1
    score[diff > outer] = 0
    return score.sum() / diff.size


def _phase(n: int, shift: int) -> float:
    """1 for no shift, 0 at MAX_SHIFT of the samples, linear (K_P) between."""
    limit = n * MAX_SHIFT
    if shift == 0:
        return 1.0
    if shift >= limit:
        return 0.0
    return ((limit - shift) / limit) ** K_P


def _magnitude(ref: np.ndarray, mod: np.ndarray, path: tuple[np.ndarray, np.ndarray]) -> float:
    """1 - (relative L1 error after dynamic time warping along `path`, the pairs (i of mod, j of
    ref)) / EPS_M, at least 0."""
    i, j = path
    ref_w = ref[j]
    error = np.abs(mod[i] - ref_w).sum() / np.abs(ref_w).sum()
    if error == 0:
        return 1.0
    if error > EPS_M:
        return 0.0
    return ((EPS_M - error) / EPS_M) ** K_M


def _slope(ref: np.ndarray, mod: np.ndarray) -> float:
    """1 - (relative L1 error of the smoothed derivatives) / E_S, at least 0."""
    d_ref, d_mod = _smoothed_derivative(ref), _smoothed_derivative(mod)
    error = np.abs(d_mod - d_ref).sum() / np.abs(d_ref).sum()
    if error <= 0:
        return 1.0
    if error >= E_S:
        return 0.0
    return (E_S - error) / E_S


def _smoothed_derivative(v: np.ndarray) -> np.ndarray:
    """Central differences averaged over 9 points, over 1, 3, 5 and 7 points toward the ends
    (as the package does it: taken from the first or last points, not centred)."""
    raw = np.gradient(v, ISO_DT)
    out = np.zeros_like(raw)
    for k, width in enumerate((1, 3, 5, 7)):
        out[k] = 1 / width * np.sum(raw[:width])
        out[-k - 1] = 1 / width * np.sum(raw[-width:])
    out[4:-4] = np.convolve(raw, np.ones(9) / 9, mode="valid")
    return out


def _overlap(ref: np.ndarray, mod: np.ndarray, shift: int) -> tuple[np.ndarray, np.ndarray]:
    """The overlapping parts when `mod` is moved `shift` samples earlier (later if negative)."""
    if shift > 0:
        return ref[:-shift], mod[shift:]
    if shift < 0:
        return ref[-shift:], mod[:shift]
    return ref, mod


def _best_shift(ref: np.ndarray, mod: np.ndarray) -> int:
    """The shift of `mod` (samples, > 0 earlier) that correlates best with `ref`, as the package
    picks it: among equal correlations the smallest shift, earlier before later; 0 when the
    unshifted correlation is undefined (nan).

    Fast correlations pick the candidates; np.corrcoef, the package's, decides among them, so
    rounding cannot pick another shift than the package does.
    """
    best, best_shift = _corrcoef(ref, mod, 0), 0
    if np.isnan(best):
        return 0
    for shift in _candidate_shifts(ref, mod):
        value = _corrcoef(ref, mod, shift)
        if value > best:
            best, best_shift = value, shift
    return best_shift


def _corrcoef(ref: np.ndarray, mod: np.ndarray, shift: int) -> float:
    """The package's correlation of the overlap at `shift` (np.corrcoef: nan if one is constant)."""
    return float(np.corrcoef(*_overlap(ref, mod, shift))[0, 1])


def _candidate_shifts(ref: np.ndarray, mod: np.ndarray) -> list[int]:
    """Shifts 1, -1, 2, -2, ... (the package's order) whose fast correlation is within
    CORR_TOL of the best, or is uncertain (a near-constant overlap)."""
    count = int(np.floor(ref.size * MAX_SHIFT) + 1) - 1
    shifts = np.stack([np.arange(1, count + 1), -np.arange(1, count + 1)], axis=1).ravel()
    rho, sure = _shifted_correlations(ref, mod, shifts)
    top = np.max(rho[sure], initial=-np.inf)
    return shifts[~sure | (rho >= top - CORR_TOL)].tolist()


def _shifted_correlations(ref: np.ndarray, mod: np.ndarray, shifts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Correlation coefficient of the overlap at each shift, from running sums, and whether it is
    accurate to CORR_TOL / 2 (the rounding error is below samples x 1e-16 / SURE_VARIANCE, some
    1e-10 for a crash; 1e-14 seen)."""
    n = ref.size
    a, b = ref - ref.mean(), mod - mod.mean()
    cross = np.correlate(b, a, mode="full")[n - 1 + shifts]  # sum of a[t] b[t + shift]
    length = n - np.abs(shifts)
    a_lo, b_lo = np.maximum(-shifts, 0), np.maximum(shifts, 0)  # first overlapping sample
    sum_a, var_a = _window_moments(a, a_lo, length)
    sum_b, var_b = _window_moments(b, b_lo, length)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = (cross - sum_a * sum_b / length) / np.sqrt(var_a * var_b)
    sure = (var_a > SURE_VARIANCE * np.sum(a * a)) & (var_b > SURE_VARIANCE * np.sum(b * b)) & np.isfinite(rho)
    return rho, sure


def _window_moments(v: np.ndarray, start: np.ndarray, length: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sum and length x variance of v[start:start + length], for each pair."""
    s1 = np.concatenate([[0.0], np.cumsum(v)])
    s2 = np.concatenate([[0.0], np.cumsum(v * v)])
    total = s1[start + length] - s1[start]
    return total, s2[start + length] - s2[start] - total * total / length


def _warping_paths(pairs: list[tuple[np.ndarray, np.ndarray]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Index pairs of the dynamic time warping of each pair of equally long x and y that dtwalign
    finds: squared differences, steps (1, 0), (0, 1), (1, 1) of weight 1, |i - j| <= the pair's
    band (DTW_BAND of its samples). Compiled (crashnlp.analysis.warping) where its library is in
    the cache, else `_numpy_warping_paths`: the same paths."""
    bands = [int(np.ceil(DTW_BAND * x.size)) - 1 for x, _ in pairs]
    lib = warping.kernel()
    if lib is None:
        return _numpy_warping_paths(pairs, bands)
    return [warping.warping_path(lib, x, y, band) for (x, y), band in zip(pairs, bands)]


def _numpy_warping_paths(pairs: list[tuple[np.ndarray, np.ndarray]], bands: list[int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """`_warping_paths` in numpy, the pairs' `bands` given. The pairs share one cost array, laid out
    for the longest and widest of them, each held to its own matrix and band by infinite costs
    outside them: each cell of a pair gets the numbers its own warping gives."""
    sizes = [x.size for x, _ in pairs]
    n, band = max(sizes), max(bands)
    cost = np.full((2 * n + 1, len(pairs), band + 3), np.inf)  # diagonal + 2, pair, cell + 1
    for p, ((x, y), own) in enumerate(zip(pairs, bands)):
        _local_costs(x, y, n, band, own, cost[2:, p, 1:-1])
    _cumulative_cost(cost, band)
    return [_backtrack(cost[:, p], size, band) for p, size in enumerate(sizes)]


def _cumulative_cost(cost: np.ndarray, band: int) -> None:
    """Least cost from (0, 0) to each cell of the band, in place of the local costs of `cost`
    (diagonal + 2, pair, cell + 1), by anti-diagonals: a diagonal needs only the two before it,
    so each is a few numpy operations on one row of all pairs. Row k + 2 holds diagonal i + j = k,
    column q + 1 its cell i = (k - band) // 2 + q; cells outside the matrix or band are inf, and
    so are the columns around each pair's cells, kept so (a nan of one pair stays its own)."""
    cost[0, :, 1 - (-band) // 2] = 0.0  # the diagonal step into (0, 0) starts from nothing
    flat = cost.reshape(cost.shape[0], -1)  # each row one array: its pairs' cells with the columns around them
    # Cells (i - 1, j) and (i, j - 1) of a cell of diagonal k are on row k - 1 at its column and
    # the next when (k - band) is even, else at the column before and its own.
    odd = (band + 1) % 2  # the first k with (k - band) odd
    ups, lefts = list(flat[1:-1, 1:-1]), list(flat[1:-1, 2:])
    ups[odd::2], lefts[odd::2] = list(flat[1:-1, :-2])[odd::2], list(flat[1:-1, 1:-1])[odd::2]
    low = np.empty(flat.shape[1] - 2)
    for up, left, diag, out, row in zip(ups, lefts, flat[:-2, 1:-1], flat[2:, 1:-1], cost[2:]):
        np.minimum(up, left, out=low)
        np.minimum(low, diag, out=low)
        np.add(low, out, out=out)
        row[:, 0] = row[:, -1] = np.inf


def _local_costs(x: np.ndarray, y: np.ndarray, n: int, band: int, own: int, out: np.ndarray) -> None:
    """(x[i] - y[j]) ** 2 into `out`, laid out as the cells of _cumulative_cost for `n` samples
    and `band` (inf off x's and y's matrix and off their `own` band). Every other diagonal, the
    cells' x and y are sliding windows over x and over y reversed (padded with inf and -inf to
    `n` and beyond), one step further each: views, not copies."""
    width, pad = band + 1, band // 2 + 2
    xs = sliding_window_view(np.concatenate([np.full(pad, np.inf), x, np.full(n - x.size + pad, np.inf)]), width)
    ys = sliding_window_view(np.concatenate([np.full(n - y.size + pad, -np.inf), y[::-1], np.full(pad, -np.inf)]), width)
    for k0 in (0, 1):
        rows = out[k0::2]  # diagonals k = k0 + 2m, whose column 0 is i = first + m
        first = (k0 - band) // 2 + pad
        last_y = n - 1 - k0 + first  # y[k - i] sits at ys[last_y - m]
        np.subtract(xs[first : first + len(rows)], ys[last_y - len(rows) + 1 : last_y + 1][::-1], out=rows)
        np.square(rows, out=rows)
        # i - j of column q is 2q - band, less one where (k - band) is odd: past the band, inf
        rows[:, np.abs(2 * np.arange(width) - band - (k0 - band) % 2) > own] = np.inf


def _backtrack(cost: np.ndarray, n: int, band: int) -> tuple[np.ndarray, np.ndarray]:
    """The path back from (n - 1, n - 1) to (0, 0) through the cheapest of the cells above, left
    and diagonal, the first of them on ties (dtwalign's order). Cell (i, j) of diagonal k = i + j
    is at column c = i - (k - band) // 2 + 1 of row k + 2; its cells above and left are on row
    k + 1, at columns c and c + 1 when (k - band) is even, else c - 1 and c; its diagonal one at
    column c of row k."""
    at = cost.item
    i = j = n - 1
    path = [(i, j)]
    while i > 0 or j > 0:
        if i == 0 or j == 0:  # on the first row or column the only way back is along it
            i, j = max(i - 1, 0), max(j - 1, 0)
        else:
            k = i + j
            c, odd = i - (k - band) // 2 + 1, (k - band) % 2
            up, left, diag = at(k + 1, c - odd), at(k + 1, c + 1 - odd), at(k, c)
            if up <= left and up <= diag:
                i -= 1
            elif left <= diag:
                j -= 1
            else:
                i, j = i - 1, j - 1
        path.append((i, j))
    steps = np.array(path[::-1])
    return steps[:, 0], steps[:, 1]
