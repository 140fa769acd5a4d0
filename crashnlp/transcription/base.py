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
IMPACT_SUBSTEPS = 4  # RK4 steps across the first interval, where the front end engages
DYNAMICS = (".initial", ".impact", ".continuity", ".collocation")  # name endings of the dynamics constraints


def rk4(rhs: ca.Function, theta: ca.SX, h: float, substeps: int) -> ca.Function:
    """`substeps` RK4 steps over h of rhs(x, theta, x_max) as an SX Function (x, theta, x_max) -> x(h)."""
    x, xm = ca.SX.sym("x", NX), ca.SX.sym("xm")
    dt, xk = h / substeps, x
    for _ in range(substeps):
        k1 = rhs(xk, theta, xm)
        k2 = rhs(xk + dt / 2 * k1, theta, xm)
        k3 = rhs(xk + dt / 2 * k2, theta, xm)
        k4 = rhs(xk + dt * k3, theta, xm)
        xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function(f"rk4_{substeps}", [x, theta, xm], [xk])


@dataclass
class Trajectory:
    """States of one test in the NLP at its grid points (the nodes), where outputs
    are fitted and constraints enforced, whatever the transcription does inside."""

    times: np.ndarray
    states: ca.MX  # NX x (N+1)
    x_max: ca.MX  # 1 x (N+1), largest crush so far at each node


def per_row(scale: np.ndarray, cols: int) -> ca.DM:
    """A state-scale column repeated over `cols` columns (CasADi does not broadcast)."""
    return ca.repmat(ca.DM(scale), 1, cols)


class Transcription(ABC):
    """Adds a test's state variables and dynamics constraints to an NLP."""

    def __init__(self, model: PendulumModel, spec):
        self.model = model
        self.spec = spec

    def bind(self, theta: ca.SX, p: ca.SX) -> None:
        """Specialise the dynamics to one test: fixed parameters become constants
        (folded into the SX graphs), only theta stays symbolic. One right-hand
        side per phase: while loading the largest crush is the crush itself."""
        x, xm = ca.SX.sym("x", NX), ca.SX.sym("xm")
        self.theta = theta
        self.rhs = {
            "loading": ca.Function("rhs_loading", [x, theta, xm], [ca.cse(self.model.rhs(x, p, -x[0]))]),
            "unloading": ca.Function("rhs_unloading", [x, theta, xm], [self.model.rhs(x, p, xm)]),
        }

    def _peak_crush(self, x: ca.MX, theta: ca.MX, h: float) -> ca.MX:
        """Largest crush, from the split node (the last node before the stop): the vertex
        crush + v^2 / (2 a) of the crush parabola through the node, with its crush rate v and
        crush deceleration a. v may be negative: a model that stopped a little before the
        split node peaked just behind it (the stiff unloading line is very sensitive to where
        it starts), but at most one interval behind (v >= -a h), which keeps the peak near
        the node while a design moves its stop."""
        decel = ca.fmax(self.rhs["loading"](x, theta, 0)[2], 1.0)  # r'' > 0 while the crush slows
        rate = ca.fmax(-x[2], -decel * h)
        return -x[0] + rate**2 / (2 * decel)

    @property
    def intervals(self) -> int:
        return self.spec.intervals

    def discretize(
        self,
        nlp: NLPBuilder,
        name: str,
        theta: ca.MX,
        x0: ca.MX,
        horizon: float,
        split: int,
        guess: Callable[[np.ndarray], np.ndarray],
    ) -> Trajectory:
        """Variables and constraints of one test on [0, horizon]; loading up to node `split`.

        `theta` is the NLP's parameter vector; call `bind` first."""
        n = self.intervals
        times = np.linspace(0.0, horizon, n + 1)
        initial = guess(times)
        scale = np.maximum(np.abs(initial).max(axis=1), STATE_FLOOR)
        X = nlp.variable(f"{name}.x", (NX, n + 1), initial, scale=scale[:, None])
        nlp.constrain(f"{name}.initial", X[:, 0] - x0)
        x_max = self._peak_crush(X[:, split], theta, float(times[1] - times[0]))
        self._impact(nlp, name, X, theta, times, scale)
        for phase, (a, b) in (("loading", (1, split)), ("unloading", (split, n))):
            if b > a:
                segment = X[:, a : b + 1]
                self._add_dynamics(nlp, f"{name}.{phase}", segment, theta, x_max, times[a : b + 1], scale, guess, self.rhs[phase])
        # up to the split node the front end loads (largest crush = crush), then x_max holds
        node_loading = ca.DM((np.arange(n + 1) <= split).astype(float)).T
        node_x_max = node_loading * (-X[0, :]) + (1 - node_loading) * x_max
        return Trajectory(times, X, node_x_max)

    def _impact(self, nlp: NLPBuilder, name: str, X: ca.MX, theta: ca.MX, times: np.ndarray, scale: np.ndarray) -> None:
        """The first interval, by fine RK4 steps whatever the transcription: the front end
        engages over its first millimetre of crush, tens of microseconds at crash speed,
        which neither one RK4 step nor a collocation polynomial of an interval resolves."""
        step = rk4(self.rhs["loading"], self.theta, float(times[1] - times[0]), IMPACT_SUBSTEPS)
        (end,) = nlp.mapped(step, 1, X[:, 0], theta, 0.0)
        nlp.constrain(f"{name}.impact", (end - X[:, 1]) / ca.DM(scale))

    @abstractmethod
    def _add_dynamics(self, nlp, name, X, theta, x_max, times, scale, guess, rhs):
        """Variables inside the intervals of one phase and its dynamics constraints.

        X holds the phase's nodes (columns), rhs(x, theta, x_max) its dynamics."""
