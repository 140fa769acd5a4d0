"""The base of every transcription: grid, impact interval, outputs at points.

The model carries its own history (the largest crush so far is its last state,
crashnlp.models.form.HISTORY), so one right-hand side serves the whole horizon: where
loading ends is the model's own crush-rate zero, found by the NLP, never fixed from the
data (docs/model.md, the history state).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from crashnlp.models.form import CrashModel
from crashnlp.numerics.integrators import rk4
from crashnlp.numerics.nlp import DYNAMICS, NLPBuilder

IMPACT_SUBSTEPS = 4  # RK4 steps across the first interval, where the front end engages


@dataclass
class Trajectory:
    """States of one test in the NLP at its grid points (the nodes), where outputs
    are fitted and constraints enforced, whatever the transcription does inside."""

    times: np.ndarray
    states: ca.MX  # states x (N+1): the initial state, then the node variables
    nodes: ca.MX  # states x N: the node variables after the initial state


def per_row(scale: ca.MX, cols: int) -> ca.MX:
    """A state-scale column repeated over `cols` columns (CasADi does not broadcast)."""
    return ca.repmat(scale, 1, cols)


class Transcription(ABC):
    """Adds a test's state variables and dynamics constraints to an NLP."""

    def __init__(self, model: CrashModel, spec):
        self.model = model
        self.spec = spec

    def dynamics(self, q: ca.SX, p: ca.SX) -> ca.Function:
        """The model's right-hand side rhs(x, q), with p the full parameter vector as an
        expression of the column q (free parameters and the test's fixed values)."""
        x = ca.SX.sym("x", self.model.nx)
        return ca.Function("rhs", [x, q], [ca.cse(self.model.rhs(x, p))])

    @property
    def intervals(self) -> int:
        return self.spec.intervals

    def discretize(
        self,
        nlp: NLPBuilder,
        name: str,
        rhs: ca.Function,
        theta: ca.MX,
        start: ca.Function,
        speed: ca.MX,
        horizon: float,
        guess: Callable[[np.ndarray], np.ndarray],
    ) -> Trajectory:
        """Variables and constraints of one test on [0, horizon]; rhs(x, theta) from `dynamics`,
        start(theta, speed) the state just after impact.

        The first node is that state itself, not a variable held to it: held only to IPOPT's
        tolerance, its crush would be +-1e-12, and where the front end carries a force at zero
        crush (spring.values[0] > 0) that sign would switch the contact force on or off, a jump
        in the objective for a change of 1e-12 in any variable. The forward simulation starts
        from the same exact state.
        The defects are divided by the state scales (an NLP parameter, from the guess)."""
        n = self.intervals
        times = np.linspace(0.0, horizon, n + 1)
        initial = guess(times)
        numeric = np.maximum(np.abs(initial).max(axis=1), self.model.state_floor)
        X = nlp.variable(f"{name}.x", (self.model.nx, n), initial[:, 1:], scale=numeric[:, None])
        scale = nlp.parameter(f"{name}.state_scale", numeric)
        h = float(times[1] - times[0])
        # the first interval, by fine RK4 steps whatever the transcription: the front end
        # engages over its first millimetre of crush, tens of microseconds at crash speed,
        # which neither one RK4 step nor a collocation polynomial of an interval resolves
        q, v0 = ca.SX.sym("q", rhs.sparsity_in(1)), ca.SX.sym("v0")
        impact = ca.Function("impact", [q, v0], [rk4(rhs, h, IMPACT_SUBSTEPS)(start(q, v0), q)])
        (end,) = nlp.mapped(impact, 1, theta, speed)
        nlp.constrain(DYNAMICS, (end - X[:, 0]) / scale, test=name, detail="impact")
        if n > 1:
            self._add_dynamics(nlp, name, X, theta, times[1:], scale, numeric, guess, rhs)
        return Trajectory(times, ca.horzcat(start(theta, speed), X), X)

    @abstractmethod
    def _add_dynamics(self, nlp, name, X, theta, times, scale, scale_values, guess, rhs):
        """Variables inside the intervals and their dynamics constraints.

        X holds the nodes (columns) from the end of the impact interval, rhs(x, theta)
        the dynamics, scale the state scales (a column parameter, for the defects) and
        scale_values their numbers (for new variables)."""
