"""The loading curve past the crush the fitted tests reached: its trend, and how well the trend predicts.

A fit determines the front end's force only over the crush the model went through in the
fitted tests (its reach). A value at a breakpoint past the reach, or a last segment the data
cover only in part, moves the force there as freely as the model's misfit pulls it: on the
shipped pickup fitted at 40 and 56 km/h, the value at 0.70 m (reached to 0.557 m) runs to its
3 MN bound, and a faster impact then meets a wall. A fit's identified model therefore bends its
loading curve, just past the reach, into a straight line along the curve's trend
(`trend_tail`, put into `model.spring.tail` by crashnlp.optimize.outcome): the slope of the
segment in which the reach lies, where the data cover at least half of it and at least half
the mean breakpoint spacing (the curve's own slope where the data end); where they cover less,
that slope is set by a few millimetres of crush and the model's misfit, and the least-squares
slope over the mean breakpoint spacing (across the segment before) stands in. The slope is
never negative: a falling force continued without end would reach zero and stop resisting
crush, which no front end does.

`trend_misses` measures the rule on the identified curve itself: from each breakpoint of the
reach's second half, the trend of the curve before it predicts the force one spacing on (the
first half holds the bumper's first peak, which says nothing of the structure behind it). Those misses, grown
in proportion to the distance past the reach, are the part of a prediction's interval that the
data cannot narrow (crashnlp.analysis.prediction).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Curve = Callable[[np.ndarray], np.ndarray]  # crush (m) -> loading force (N), vectorised
SAMPLES = 50  # points of the curve the trend's least squares use
CLEARANCE = 2.0  # smoothing widths between the reach and the tail's start: its hinge leaves the fit's range as it was
COVERED = 0.5  # the share of its segment the data must cover for the segment's own slope to be the trend


def spacing(breakpoints: np.ndarray) -> float:
    """The law's resolution in crush: the mean distance between its breakpoints (m)."""
    x = np.asarray(breakpoints, float)
    return float((x[-1] - x[0]) / (x.size - 1))


def trend_slope(curve: Curve, reach: float, window: float) -> float:
    """The least-squares slope of `curve` over [reach - window, reach] (N/m), not negative."""
    x = np.linspace(max(reach - window, 0.0), reach, SAMPLES)
    return max(float(np.polyfit(x, curve(x), 1)[0]), 0.0)


def trend_window(breakpoints: np.ndarray, reach: float) -> float:
    """The crush over which the trend at the reach is taken (m): the part of its segment the data
    cover, where that is at least COVERED of the segment and of the mean spacing (breakpoints
    placed where the curve bends can be close); else one mean spacing, across the segment before."""
    x = np.asarray(breakpoints, float)
    k = int(np.clip(np.searchsorted(x, reach, side="right") - 1, 0, x.size - 2))
    covered = reach - x[k]
    return covered if covered >= COVERED * max(x[k + 1] - x[k], spacing(x)) else spacing(x)


def tail_start(reach: float, eps: float) -> float:
    """Where the tail starts (m) for a curve reached to `reach` by the fitted tests, its kinks
    smoothed over `eps`: CLEARANCE smoothing widths past the reach. A value whose breakpoints lie
    past it shapes no force the fit went through."""
    return reach + CLEARANCE * eps


def trend_tail(curve: Curve, breakpoints: np.ndarray, reach: float, eps: float) -> tuple[float, float]:
    """The tail's start (`tail_start`, m) and slope (N/m) for a curve reached to `reach` by the
    fitted tests, along the trend over `trend_window`."""
    return tail_start(reach, eps), trend_slope(curve, reach, trend_window(breakpoints, reach))


def trend_misses(curve: Curve, breakpoints: np.ndarray, reach: float) -> np.ndarray:
    """The trend rule's misses on the curve inside the reach (N): at each breakpoint of the reach's
    second half (and from the third breakpoint on), the force one spacing on from the one before
    it, as the trend before that one predicts, against the curve's own. The first half holds the
    bumper's and crash boxes' first peak, which says nothing of how the structure behind them
    goes on. Empty when no breakpoint qualifies."""
    x = np.asarray(breakpoints, float)
    window = spacing(x)
    ends = x[(x <= reach) & (x >= max(x[0] + 2 * window, reach / 2) - 1e-12)]
    starts = ends - window
    slopes = np.array([trend_slope(curve, start, window) for start in starts])
    return curve(ends) - (curve(starts) + slopes * window) if ends.size else np.zeros(0)
