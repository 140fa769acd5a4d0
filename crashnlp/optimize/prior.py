"""The smoothness prior on the force-crush curve (`objective.regularization`).

Where the tests' crush does not reach a breakpoint, or barely does, the data do not determine
its value: a fit left alone can run it to a bound, and a prediction past the fitted crush then
meets a wall. The prior makes such a value follow the curve's trend. Its residuals are the
slope changes of the loading curve at the interior breakpoints (so unevenly spaced
breakpoints count by slope, not by value), made dimensionless by the curve's mean secant
slope (largest start value over the last breakpoint). It enters the least-squares objective
as one more channel of its own count, weight / k * sum(rows^2): being linear in the values,
the Gauss-Newton Hessian holds it exactly. The weight is the user's (default 0: no prior).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crashnlp.optimize.free import FreeParameters
from crashnlp.results.identified import SPRING_VALUES


@dataclass(frozen=True)
class SmoothnessPrior:
    """Rows of slope changes per unit of theta (SI): residual = sqrt(weight / k) * matrix @ theta."""

    matrix: np.ndarray  # k x theta

    @property
    def count(self) -> int:
        return self.matrix.shape[0]

    def information(self, weight: float) -> np.ndarray:
        """weight / k * L^T L: the curvature the prior adds to the Gauss-Newton Hessian (SI)."""
        return weight / max(self.count, 1) * self.matrix.T @ self.matrix


def smoothness_prior(free: FreeParameters, breakpoints: np.ndarray) -> SmoothnessPrior | None:
    """The prior on the estimated spring values; None when they are not estimated or too few."""
    entry = next((e for e in free.entries if e.path == SPRING_VALUES), None)
    n = len(breakpoints)
    if entry is None or n < 3 or entry.at.stop - entry.at.start != n:
        return None
    span = np.diff(breakpoints)
    slope = np.zeros((n - 1, n))  # segment slopes from the values
    slope[np.arange(n - 1), np.arange(n - 1)] = -1.0 / span
    slope[np.arange(n - 1), np.arange(1, n)] = 1.0 / span
    change = slope[1:] - slope[:-1]  # slope change at the interior breakpoints
    mean_slope = max(float(np.max(np.abs(entry.initial))), 1.0) / float(breakpoints[-1])
    matrix = np.zeros((n - 2, free.size))
    matrix[:, entry.at] = change / mean_slope
    return SmoothnessPrior(matrix)
