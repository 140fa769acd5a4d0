"""Identification: fit the free parameters to the tests' data by one NLP."""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import TextIO

import casadi as ca
import numpy as np

from crashnlp.case import Case
from crashnlp.errors import InputError
from crashnlp.model.pendulum import OUTPUTS
from crashnlp.optimize.fit import Residual, add_fit_objective
from crashnlp.optimize.problem import OptimalControl
from crashnlp.optimize.solve import SolveResult, solve
from crashnlp.optimize.uncertainty import SensitivityEvaluator


@dataclass
class TestSolution:
    """Numeric outcome for one test: outputs at the NLP's grid points (SI)."""

    name: str
    times: np.ndarray
    outputs: dict[str, np.ndarray]
    split_time: float


@dataclass
class Solution:
    """What an NLP solve produced, judged honestly."""

    case: Case
    ocp: OptimalControl
    result: SolveResult | None
    status: str
    theta: np.ndarray
    tests: list[TestSolution]
    residuals: list[Residual] = field(default_factory=list)
    std_errors: np.ndarray | None = None
    correlation: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def parameters(self) -> dict:
        return self.ocp.free.named(self.theta)

    def full_parameters(self) -> np.ndarray:
        return self.ocp.free.full(self.theta)


def judge(result: SolveResult, theta0: np.ndarray, theta: np.ndarray, scale: np.ndarray) -> str:
    """'ok' only for a converged solve that moved; otherwise why not."""
    if not result.converged:
        return f"solver failed: {result.return_status}"
    if result.iterations == 0:
        return "no progress: IPOPT stopped at iteration 0"
    if theta0.size and np.max(np.abs(theta - theta0) / scale) < 1e-9:
        return "no progress: the parameters never left the initial guess"
    return "ok"


def evaluate(ocp: OptimalControl, z: np.ndarray) -> list[TestSolution]:
    """Outputs of every test at a solution vector."""
    zsym = ca.vertcat(*ocp.nlp.z)
    f = ca.Function("outs", [zsym], [tr.outputs for tr in ocp.transcripts])
    values = f(z)
    values = values if isinstance(values, (list, tuple)) else [values]
    out = []
    for tr, y in zip(ocp.transcripts, values):
        y = np.asarray(y)
        traj = tr.trajectory
        out.append(TestSolution(tr.test.name, traj.times, {k: y[i] for i, k in enumerate(OUTPUTS)}, float(traj.times[tr.split])))
    return out


def identify(case: Case, verbose: bool = False, progress: TextIO | None = sys.stdout, warm: np.ndarray | None = None) -> Solution:
    """Build and solve the identification NLP of a case."""
    ocp = OptimalControl(case)
    if ocp.free.size == 0:
        raise InputError(f"{case.name}: estimate names no parameter to identify")
    residuals = add_fit_objective(ocp)
    if not residuals:
        raise InputError(f"{case.name}: no test has data to fit")
    if warm is not None:
        ocp.set_guess(warm)
    z0 = ocp.nlp.bounds()["x0"]
    sensitivity = SensitivityEvaluator(ocp, residuals)
    theta0 = ocp.nlp.value("theta", z0).ravel()
    dead = sensitivity(z0).dead()
    if dead.any():
        names = ", ".join(np.asarray(ocp.free.labels())[dead])
        status = f"not identifiable: {names} cannot change the fit (zero derivative)"
        return Solution(case, ocp, None, status, theta0, evaluate(ocp, z0), residuals)
    result = solve(ocp.nlp, case.problem.solver, verbose, None if verbose else progress)
    # IPOPT relaxes bounds by a hair (bound_relax_factor); report values inside them
    theta = np.clip(ocp.nlp.value("theta", result.z).ravel(), ocp.free.lower, ocp.free.upper)
    status = judge(result, theta0, theta, ocp.free.scale)
    solution = Solution(case, ocp, result, status, theta, evaluate(ocp, result.z), residuals)
    cov = sensitivity(result.z).covariance()
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    solution.std_errors = std
    with np.errstate(invalid="ignore", divide="ignore"):
        solution.correlation = np.nan_to_num(cov / np.outer(std, std))
    return solution
