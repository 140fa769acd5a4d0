"""What one IPOPT run, or a strategy's runs together, gave: the result type of
crashnlp.optimize.solve, kept apart so that the detectors and the strategy share it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from crashnlp.numerics.nlp import SUCCESS

# why the Watch (crashnlp.optimize.watch) stopped Gauss-Newton short: a cycle, a wander, a settle's cycle that does not settle
Stop = Literal["cycle", "wander", "unsettled"]


@dataclass
class SolveResult:
    z: np.ndarray
    objective: float
    lam_g: np.ndarray
    lam_x: np.ndarray
    g: np.ndarray
    return_status: str
    iterations: int
    wall_s: float
    build_s: float
    profile: dict[str, tuple[int, float]] = field(default_factory=dict)  # IPOPT's functions: calls, seconds
    compiled: bool = False  # IPOPT called the compiled NLP functions (crashnlp.optimize.oracle)
    tail: float | None = None  # stopped in Gauss-Newton's slow tail (crashnlp.optimize.watch): the distance still to go
    stopped: Stop | None = None  # why the Watch stopped Gauss-Newton short of convergence
    settled: bool = False  # the run settled a cycle (crashnlp.optimize.options.SETTLE_OPTIONS)
    unsettled: bool = False  # a cycle's settle went round; the exact Hessian finished from its iterate

    @property
    def converged(self) -> bool:
        return self.return_status in SUCCESS

    @property
    def cycling(self) -> bool:
        return self.stopped == "cycle"


def after(before: SolveResult, run: SolveResult) -> SolveResult:
    """A run's result, counting the iterations and time of the runs before it."""
    return dataclasses.replace(
        run,
        iterations=before.iterations + run.iterations,
        wall_s=before.wall_s + run.wall_s,
        build_s=before.build_s + run.build_s,
    )
