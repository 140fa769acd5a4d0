"""The transcribed optimal-control problem shared by identification and design.

For every test: a trajectory from the chosen transcription, the model outputs
at every grid point, and the problem's constraints on them. The objective is
added by the caller (a fit to data, or a design goal).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from crashnlp.case.case import Case, TestCase
from crashnlp.models.form import OUTPUTS
from crashnlp.models.simulation import simulate
from crashnlp.numerics.nlp import NLPBuilder
from crashnlp.optimize.free import FreeParameters
from crashnlp.optimize.oracle import compilable
from crashnlp.optimize.oracle import symbolic as is_symbolic
from crashnlp.results.response import Response
from crashnlp.transcription import Trajectory, make_transcription

MONOTONE_TOLERANCE = 1e-4  # m: reloading allowed between two nodes by monotone_crush


@dataclass
class Transcript:
    """One test in the NLP."""

    test: TestCase
    trajectory: Trajectory
    outputs: ca.MX  # len(OUTPUTS) x nodes

    def output(self, name: str) -> ca.MX:
        """A named output at every node (row)."""
        return self.outputs[OUTPUTS.index(name), :]

    def history(self) -> ca.MX:
        """The front end's history state, the largest crush so far, at every node (the last row)."""
        return self.trajectory.states[-1, :]


def _interpolator(response: Response, nx: int):
    def guess(t: np.ndarray) -> np.ndarray:
        return np.vstack([np.interp(t, response.time, response.states[i]) for i in range(nx)])

    return guess


class OptimalControl:
    """Variables, dynamics and constraints of all tests of a case."""

    def __init__(self, case: Case):
        self.case = case
        problem = case.problem
        # numbers as parameters where the NLP may be compiled, and serial maps where it will be
        # (its library then serves every thread setting)
        self.nlp = NLPBuilder(threads=1 if compilable(problem) else None, symbolic=is_symbolic(problem))
        self.free = FreeParameters(case.layout, case.base, problem.estimate)
        self.theta = self.nlp.variable(
            "theta", self.free.size, self.free.initial, self.free.lower, self.free.upper, self.free.scale
        )
        self.transcription = make_transcription(case.model, problem.transcription)
        p0 = self.free.full(self.free.initial)
        self.transcripts = [self._transcribe(test, p0, case.fit_window(test)[1]) for test in case.tests]
        self._constraints()

    def _transcribe(self, test: TestCase, p0: np.ndarray, horizon: float) -> Transcript:
        """One test's trajectory and outputs. With symbolic numbers (an NLP that may be compiled)
        the interval functions take q = [theta; the test's full parameter vector], the fixed
        values an NLP parameter, so that a study changing them keeps the NLP's shape; else
        q = theta and the fixed values are constants folded into them."""
        model = self.case.model
        fine = np.linspace(0.0, horizon, 4 * self.transcription.intervals + 1)
        guess = simulate(model, self.case.test_parameters(test, p0), test.speed, fine, self.case.problem.simulation)
        theta_sx = ca.SX.sym("theta", self.free.size)
        fixed_sx = ca.SX.sym("fixed", self.free.base.size) if self.nlp.symbolic else None
        q_sx = ca.vertcat(theta_sx, fixed_sx) if fixed_sx is not None else theta_sx
        p_sx = self.free.full(theta_sx, test.overrides, fixed_sx)
        fixed = self._fixed(f"{test.name}.parameters", self.case.test_parameters(test))
        q = ca.vertcat(self.theta, fixed) if fixed is not None else self.theta
        v0 = ca.SX.sym("v0")
        start = ca.Function("start", [q_sx, v0], [model.initial_state(p_sx, v0)])
        speed = self.nlp.parameter(f"{test.name}.speed", test.speed)
        rhs = self.transcription.dynamics(q_sx, p_sx)
        traj = self.transcription.discretize(self.nlp, test.name, rhs, q, start, speed, horizon, _interpolator(guess, model.nx))
        x = ca.SX.sym("x", model.nx)
        outputs = ca.Function("outputs", [x, q_sx], [model.outputs(x, p_sx)])
        at_start = ca.Function("outputs_at_start", [q_sx, v0], [model.outputs(start(q_sx, v0), p_sx)])
        (y0,) = self.nlp.mapped(at_start, 1, q, speed)
        (y,) = self.nlp.mapped(outputs, len(traj.times) - 1, traj.nodes, q)
        return Transcript(test, traj, ca.horzcat(y0, y))

    def _fixed(self, name: str, values: np.ndarray) -> ca.MX | None:
        """A full parameter vector as an NLP parameter, or None where the numbers are constants."""
        return self.nlp.parameter(name, values) if self.nlp.symbolic else None

    def _constraints(self) -> None:
        spec = self.case.problem.constraints
        for tr in self.transcripts:
            for name, (lo, hi) in spec.bounds.items():
                y = tr.output(name)
                if lo is not None:
                    self.nlp.constrain("bound", y, lo, np.inf, test=tr.test.name, detail=f"{name}.lower")
                if hi is not None:
                    self.nlp.constrain("bound", y, -np.inf, hi, test=tr.test.name, detail=f"{name}.upper")
            if spec.monotone_crush:
                growth = self._unloaded_depth_growth(tr)
                self.nlp.constrain("monotone_crush", growth, -MONOTONE_TOLERANCE, np.inf, test=tr.test.name)
        if spec.monotone_spring:
            shared = self._fixed("parameters", self.case.base)
            values = self.free.full(self.theta, fixed=shared)[self.case.layout.index("model.spring.values")]
            self.nlp.constrain("monotone_spring", ca.diff(values), 0.0, np.inf)

    @staticmethod
    def _unloaded_depth_growth(tr: Transcript) -> ca.MX:
        """Growth of the depth unloaded below the largest crush, x_max - crush, from node to
        node (m). Bounded below by -MONOTONE_TOLERANCE: once the front end has begun to
        unload it does not load again, and while it loads the depth stays ~0 (the crush
        is its own largest value). The switch stays the model's own; no node is fixed."""
        return ca.diff(tr.history() - tr.output("crush"), 1, 1)

    def set_guess(self, z: np.ndarray) -> bool:
        """Warm start from a solution vector of an NLP of the same shape; False if it is not."""
        z = np.asarray(z, dtype=float).ravel()
        sizes = [len(b) for b in self.nlp.z0]
        if z.size != sum(sizes):
            return False
        self.nlp.z0 = np.split(z, np.cumsum(sizes)[:-1])
        return True
