"""The transcribed optimal-control problem shared by identification and design.

For every test: a trajectory from the chosen transcription, the model outputs
at every grid point, and the problem's constraints on them. The objective is
added by the caller (a fit to data, or a design goal).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from crashnlp.case import Case, TestCase
from crashnlp.model.pendulum import NX, OUTPUTS
from crashnlp.nlp import NLPBuilder
from crashnlp.optimize.parameters import FreeParameters
from crashnlp.simulate import Response, simulate
from crashnlp.transcription import Trajectory, make_transcription


@dataclass
class Transcript:
    """One test in the NLP."""

    test: TestCase
    trajectory: Trajectory
    outputs: ca.MX  # len(OUTPUTS) x nodes
    split: int

    def output(self, name: str) -> ca.MX:
        """A named output at every node (row)."""
        return self.outputs[OUTPUTS.index(name), :]


def _interpolator(response: Response):
    def guess(t: np.ndarray) -> np.ndarray:
        return np.vstack([np.interp(t, response.time, response.states[i]) for i in range(NX)])

    return guess


def split_node(test: TestCase, guess: Response, times: np.ndarray) -> int:
    """Node where loading ends: the last node before the data's first velocity zero, else
    before the guess's largest crush.

    The last node before, not the nearest: after the split the front end may still
    load (the unloading law follows the loading curve above the largest crush),
    while before it the crush may not decrease, which would force a model that
    stops a little earlier than the data to keep crushing."""
    velocity = test.data.channels.get("velocity") if test.data is not None else None
    if velocity is not None and np.any(velocity.values < 0):
        t_stop = float(velocity.time[np.argmax(velocity.values < 0)])
    else:
        t_stop = float(guess.time[np.argmax(guess["crush"])])
    return int(np.clip(np.searchsorted(times, t_stop, side="right") - 1, 1, len(times) - 1))


class OptimalControl:
    """Variables, dynamics and constraints of all tests of a case."""

    def __init__(self, case: Case, splits: dict[str, int] | None = None):
        self.case = case
        problem = case.problem
        self.nlp = NLPBuilder()
        self.free = FreeParameters(case.layout, case.base, problem.estimate)
        self.theta = self.nlp.variable(
            "theta", self.free.size, self.free.initial, self.free.lower, self.free.upper, self.free.scale
        )
        self.transcription = make_transcription(case.model, problem.transcription)
        p0 = self.free.full(self.free.initial)
        self.transcripts = [
            self._transcribe(test, p0, case.fit_window(test)[1], (splits or {}).get(test.name)) for test in case.tests
        ]
        self._constraints()

    def _transcribe(self, test: TestCase, p0: np.ndarray, horizon: float, split: int | None) -> Transcript:
        model = self.case.model
        p_test = self.case.test_parameters(test, p0)
        fine = np.linspace(0.0, horizon, 4 * self.transcription.intervals + 1)
        guess = simulate(model, p_test, test.speed, fine, self.case.problem.simulation)
        times = np.linspace(0.0, horizon, self.transcription.intervals + 1)
        split = split_node(test, guess, times) if split is None else split
        theta_sx = ca.SX.sym("theta", self.free.size)
        p_sx = self.free.full(theta_sx, test.overrides)
        self.transcription.bind(theta_sx, p_sx)
        p = self.free.full(self.theta, test.overrides)
        x0 = model.initial_state(p, test.speed)
        traj = self.transcription.discretize(self.nlp, test.name, self.theta, x0, horizon, split, _interpolator(guess))
        k = len(traj.times)
        x, xm = ca.SX.sym("x", NX), ca.SX.sym("xm")
        outputs = ca.Function("outputs", [x, theta_sx, xm], [model.outputs(x, p_sx, xm)])
        (y,) = self.nlp.mapped(outputs, k, traj.states, self.theta, traj.x_max)
        return Transcript(test, traj, y, split)

    def _constraints(self) -> None:
        spec = self.case.problem.constraints
        for tr in self.transcripts:
            for name, (lo, hi) in spec.bounds.items():
                y = tr.output(name)
                if lo is not None:
                    self.nlp.constrain(f"{tr.test.name}.bound.{name}.lower", y, lo, np.inf)
                if hi is not None:
                    self.nlp.constrain(f"{tr.test.name}.bound.{name}.upper", y, -np.inf, hi)
            if spec.monotone_crush:
                crush = tr.output("crush")[:, : tr.split + 1]
                self.nlp.constrain(f"{tr.test.name}.monotone_crush", ca.diff(crush, 1, 1), 0.0, np.inf)
        if spec.monotone_spring:
            values = self.free.full(self.theta)[self.case.layout.index("model.spring.values")]
            self.nlp.constrain("monotone_spring", ca.diff(values), 0.0, np.inf)

    def set_guess(self, z: np.ndarray) -> bool:
        """Warm start from a solution vector of an NLP of the same shape; False if it is not."""
        z = np.asarray(z, dtype=float).ravel()
        sizes = [len(b) for b in self.nlp.z0]
        if z.size != sum(sizes):
            return False
        self.nlp.z0 = np.split(z, np.cumsum(sizes)[:-1])
        return True
