"""The base of every transcription: grid, loading/unloading phases, outputs at points.

The front end loads until its maximum crush and unloads after it. The NLP fixes
the node where that happens (`split`), so no history state or switch enters the
NLP: before it the largest crush is the current crush, after it the crush at
the split node (model-notes.md, numerical notes).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable

import casadi as ca
import numpy as np

from crashnlp.model.pendulum import NX, PendulumModel
from crashnlp.nlp import NLPBuilder

STATE_FLOOR = np.array([0.01, 0.01, 0.1, 0.01])  # smallest state scales: m, rad, m/s, rad/s


@dataclass
class Trajectory:
    """States of one test in the NLP: at the nodes and at every grid point."""

    node_times: np.ndarray
    nodes: ca.MX  # NX x (N+1)
    point_times: np.ndarray
    points: ca.MX  # NX x K, the nodes included
    point_x_max: ca.MX  # 1 x K, largest crush so far at each point
    state_block: str

    def node_columns(self) -> np.ndarray:
        """Indices of the nodes among the points."""
        return np.searchsorted(self.point_times, self.node_times)


def per_row(scale: np.ndarray, cols: int) -> ca.DM:
    """A state-scale column repeated over `cols` columns (CasADi does not broadcast)."""
    return ca.repmat(ca.DM(scale), 1, cols)


class Transcription(ABC):
    """Adds a test's state variables and dynamics constraints to an NLP."""

    def __init__(self, model: PendulumModel, spec):
        self.model = model
        self.spec = spec
        x, xm, loading = ca.SX.sym("x", NX), ca.SX.sym("xm"), ca.SX.sym("loading")
        p = model.p
        effective = loading * (-x[0]) + (1 - loading) * xm
        self.phase_rhs = ca.Function(
            "phase_rhs", [x, p, xm, loading], [model.rhs(x, p, effective)], ["x", "p", "xm", "loading"], ["xdot"]
        )

    @property
    def intervals(self) -> int:
        return self.spec.intervals

    def discretize(
        self,
        nlp: NLPBuilder,
        name: str,
        p: ca.MX,
        x0: ca.MX,
        horizon: float,
        split: int,
        guess: Callable[[np.ndarray], np.ndarray],
    ) -> Trajectory:
        """Variables and constraints of one test on [0, horizon]; loading up to node `split`."""
        n = self.intervals
        times = np.linspace(0.0, horizon, n + 1)
        scale = np.maximum(np.abs(guess(times)).max(axis=1), STATE_FLOOR)
        X = nlp.variable(f"{name}.x", (NX, n + 1), guess(times), scale=scale[:, None])
        nlp.constrain(f"{name}.initial", X[:, 0] - x0)
        loading = (np.arange(n) < split).astype(float)
        x_max = -X[0, split]
        inner_times, inner_states, inner_interval = self._add_dynamics(
            nlp, name, X, p, ca.repmat(x_max, 1, n), loading, times, scale, guess
        )
        # grid points: the nodes and whatever points inside the intervals the method has
        point_times = np.concatenate([times, inner_times])
        point_loading = np.concatenate([np.arange(n + 1) <= split, loading[inner_interval] > 0])
        order = np.argsort(point_times, kind="stable")
        points = ca.horzcat(X, inner_states)[:, order.tolist()] if len(inner_times) else X
        point_x_max = ca.horzcat(*[-points[0, i] if point_loading[k] else x_max for i, k in enumerate(order)])
        return Trajectory(times, X, point_times[order], points, point_x_max, f"{name}.x")

    @abstractmethod
    def _add_dynamics(self, nlp, name, X, p, xm, loading, times, scale, guess):
        """Dynamics constraints; returns the times, states and interval index of interior grid points."""
