"""Identification: fit the free parameters to the tests' data by one NLP."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from functools import partial
from typing import TextIO

import numpy as np

from crashnlp.case.case import Case
from crashnlp.case.completion import measured_pulse, repaired_start
from crashnlp.models.simulation import response_of_outputs
from crashnlp.models.tail import tail_start
from crashnlp.numerics.nlp import ACCEPTABLE
from crashnlp.optimize.fit import FitObjective, Residual, add_fit_objective
from crashnlp.optimize.ocp import OptimalControl
from crashnlp.optimize.options import SETTLE_OPTIONS, STEADY_OPTIONS
from crashnlp.optimize.solve import solve
from crashnlp.optimize.solved import SolveResult, after
from crashnlp.optimize.uncertainty import Covariance, SensitivityEvaluator, sensitivity_function
from crashnlp.optimize.verify import Verification, verify
from crashnlp.problem.schema import MultipleShootingSpec
from crashnlp.results.identified import UNLOADING_STIFFNESS, shaping_nothing_short_of
from crashnlp.results.response import Response


@dataclass
class Solution:
    """What an NLP solve produced, judged honestly."""

    case: Case
    ocp: OptimalControl
    result: SolveResult | None
    status: str
    theta: np.ndarray
    tests: list[Response]  # outputs and states at the NLP's grid points
    residuals: list[Residual] = field(default_factory=list)
    covariance: Covariance | None = None
    verification: Verification | None = None
    profiles: dict[str, dict] = field(default_factory=dict)  # profile-likelihood intervals by label (crashnlp.optimize.profile)
    notes: list[str] = field(default_factory=list)  # what was done to the problem on the way (one line each)
    regularization: dict = field(default_factory=dict)  # the smoothness prior's weight

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def parameters(self) -> dict:
        return self.ocp.free.named(self.theta)

    @property
    def std_errors(self) -> np.ndarray | None:
        return None if self.covariance is None else self.covariance.std

    @property
    def correlation(self) -> np.ndarray | None:
        return None if self.covariance is None else self.covariance.correlation

    def at_bound(self, rtol: float = 1e-6) -> np.ndarray:
        """Free parameters at one of their bounds (bool per entry of theta)."""
        free, tol = self.ocp.free, rtol * self.ocp.free.scale
        return (np.abs(self.theta - free.lower) <= tol) | (np.abs(self.theta - free.upper) <= tol)

    def bound_pull(self) -> np.ndarray:
        """How far past its bound each parameter's unconstrained optimum lies, in standard errors
        (0 off the bounds, nan where the data do not determine the value): |lam| [H^-1]_ii / 2 /
        std, from the bound's multiplier and the objective's curvature. Above 1.96 the bound, not
        the data, decides the value."""
        if self.result is None or self.covariance is None:
            return np.zeros(self.theta.size)
        block = self.ocp.nlp.blocks["theta"]
        lam = self.result.lam_x[block.offset : block.offset + block.shape[0]] / block.scale.ravel()
        beyond = np.abs(lam) * np.diag(self.covariance.hessian_inverse) / 2
        with np.errstate(invalid="ignore", divide="ignore"):
            pull = np.where(self.covariance.identified, np.nan_to_num(beyond / self.covariance.std), np.nan)
        return np.where(self.at_bound(), pull, 0.0)

    def full_parameters(self) -> np.ndarray:
        return self.ocp.free.full(self.theta)

    @property
    def reach(self) -> float:
        """The largest front-end crush the model went through in the fitted tests (m): how far
        the data determine its loading curve."""
        return max(float(np.max(t["crush"])) for t in self.tests)

    @property
    def breakpoints(self) -> np.ndarray:
        """The loading curve's crush breakpoints at the solution (m)."""
        return self.full_parameters()[self.case.layout.index("model.spring.crush_breakpoints")]

    def unreached(self) -> np.ndarray:
        """Per estimated entry, whether the fitted tests never reach it: a spring value whose
        breakpoints lie past the tail's start (crashnlp.models.tail.tail_start) of the reach, and
        the unloading stiffness where no fitted test's model unloads (its crush never falls within
        the record: a record that ends mid-crash)."""
        labels = self.ocp.free.labels()
        start = tail_start(self.reach, self.case.problem.model.smoothing.crush)
        out = shaping_nothing_short_of(labels, self.breakpoints, start)
        if all(np.isnan(t.loading_end) for t in self.tests):
            out |= np.array([label == UNLOADING_STIFFNESS for label in labels], bool)
        return out


def judge(result: SolveResult, theta0: np.ndarray, theta: np.ndarray, scale: np.ndarray) -> str:
    """'ok' only for a converged solve that moved; otherwise why not."""
    if not result.converged:
        return f"solver failed: {result.return_status}"
    if result.iterations == 0:
        return "no progress: IPOPT stopped at iteration 0"
    if theta0.size and np.max(np.abs(theta - theta0) / scale) < 1e-9:
        return "no progress: the parameters never left the initial guess"
    return "ok"


def evaluate(ocp: OptimalControl, z: np.ndarray) -> list[Response]:
    """Outputs and states of every test at a solution vector."""
    values = [
        np.asarray(v) for v in ocp.nlp.evaluate([x for tr in ocp.transcripts for x in (tr.outputs, tr.trajectory.states)], z)
    ]
    p = ocp.free.full(ocp.nlp.value("theta", z).ravel())
    out = []
    for k, tr in enumerate(ocp.transcripts):
        y, states = values[2 * k], values[2 * k + 1]
        model, pt = ocp.case.model, ocp.case.test_parameters(tr.test, p)
        permanent = np.asarray(model.permanent_set(states[: model.nx], pt)).ravel()
        out.append(response_of_outputs(model, tr.trajectory.times, y, permanent, states))
    return out


def finish(case: Case, ocp: OptimalControl, result: SolveResult, theta0: np.ndarray, residuals: list[Residual]) -> Solution:
    """The solution of a finished solve: judged, and checked by forward simulation."""
    # IPOPT relaxes bounds by a hair (bound_relax_factor); report values inside them
    theta = np.clip(ocp.nlp.value("theta", result.z).ravel(), ocp.free.lower, ocp.free.upper)
    status = judge(result, theta0, theta, ocp.free.scale)
    tests = evaluate(ocp, result.z)
    solution = Solution(case, ocp, result, status, theta, tests, residuals)
    solution.verification = verify(case, ocp.free.full(theta), tests)
    if solution.ok and solution.verification.problem:
        solution.status = solution.verification.problem
    return solution


def repair_start(case: Case) -> tuple[Case, str | None]:
    """A start that leaves spring values with a zero derivative although the data reach them,
    replaced by crashnlp.case.completion.repaired_start: the case from the new start (Case.with_start),
    and the one line that says so; the case itself and None when its start serves.

    A breakpoint value moves the force from the breakpoint before it on, so it has a zero
    derivative when the start's crush stops short of that breakpoint; the data reach it when
    their crush goes past it (an `estimate` entry's own `initial` still wins over it)."""
    simulated = case.simulate()
    breakpoints = case.base[case.layout.index("model.spring.crush_breakpoints")][:-1]
    for test in case.tests:
        measured = measured_pulse(case.problem, test)
        model = float(np.max(simulated[test.name]["displacement"]))  # the data's travel is the CG's
        if measured is not None and np.any((breakpoints > model) & (breakpoints < measured.max_displacement)):
            return case.with_start(repaired_start(case.problem, case.tests)), (
                f"{case.name}: the initial values stop test {test.name} at a max displacement of {model * 1e3:.0f} mm, "
                f"the data's is {measured.max_displacement * 1e3:.0f} mm; spring values and unloading stiffness restarted "
                "from the measured force-crush curve"
            )
    return case, None


def fit_ocp(case: Case, prior_weight: float | None = None) -> tuple[OptimalControl, FitObjective]:
    """The identification NLP of a case and its objective (the prior at `prior_weight`, else
    the problem's); the covariance's sensitivities are an extra of the NLP, so that they are
    compiled with its functions (crashnlp.optimize.oracle)."""
    ocp = OptimalControl(case)
    fit = add_fit_objective(ocp, prior_weight)
    ocp.nlp.extras["sens"] = partial(sensitivity_function, ocp.nlp, fit.residuals)  # its module keys the library
    return ocp, fit


# Multiple shooting integrates each interval in `substeps` RK4 steps. Where the fit's iterates
# cycle (crashnlp.optimize.watch: a kink of the force laws crossed inside a step), or where the
# forward simulation of its optimum departs from the NLP's trajectory (crashnlp.optimize.verify:
# a stiff breakpoint crossed inside a step, which the NLP integrates a few mm/s off and the
# plastic unloading from the largest crush then carries to the rebound), the fit is solved again
# from where it got to with REFINE times the steps, up to MAX_SUBSTEPS. A step's quadrature error
# across a kink falls with the step squared, so a refinement cuts it sixteenfold; each multiplies
# the integration's cost by REFINE, so a fit is refined at most twice, then reports how it ended
# (the fits that were refined, and where they finished: docs/design-notes.md, "The 4-degree row").
REFINE, MAX_SUBSTEPS = 4, 16


def identify(case: Case, verbose: bool = False, progress: TextIO | None = sys.stdout, warm: np.ndarray | None = None) -> Solution:
    """Build and solve the identification NLP of a case; a start that falls short of the
    measured crush is repaired from the data first (crashnlp.case.completion), and says so; a solve
    whose iterates cycle, or whose optimum the forward simulation departs from, is refined
    (REFINE above), and says so."""
    case, note = repair_start(case) if warm is None else (case, None)
    notes = [note] if note else []
    _say(note, progress)
    ocp, fit = fit_ocp(case)
    from_neighbour = warm is not None and ocp.set_guess(warm)
    theta0 = ocp.nlp.value("theta", ocp.nlp.bounds()["x0"]).ravel()
    result = solve(ocp.nlp, case.problem.solver, verbose, None if verbose else progress, from_neighbour, _refinable(case))
    while True:
        departed = None
        if not result.cycling:
            solution = _finished(case, ocp, fit, result, theta0)
            if not (_departs(solution) and _refinable(case)):
                break
            departed = solution
        case, note = _refined(case, result, departed)
        notes.append(note)
        _say(note, progress)
        ocp, fit = fit_ocp(case)
        ocp.set_guess(result.z)
        result = after(
            result, solve(ocp.nlp, case.problem.solver, verbose, None if verbose else progress, refinable=_refinable(case))
        )
    if result.converged and (result.settled or result.unsettled or result.return_status == ACCEPTABLE):
        notes.append(note := _settled(case) if result.settled else _unsettled(case) if result.unsettled else _steady(case))
        _say(note, progress)
    solution.notes = notes
    return solution


def _departs(solution: Solution) -> bool:
    """Whether a converged solve's forward simulation departs from its NLP trajectory
    (crashnlp.optimize.verify), which a finer integration can take away."""
    check = solution.verification
    return solution.result is not None and solution.result.converged and check is not None and check.departs


def _say(note: str | None, progress: TextIO | None) -> None:
    if note and progress is not None:
        print(note, file=progress)


def _refinable(case: Case) -> bool:
    """Whether the case's integration steps can be refined: multiple shooting below MAX_SUBSTEPS
    (collocation has no step to refine). Only then does its solve stop at a cycle."""
    spec = case.problem.transcription
    return isinstance(spec, MultipleShootingSpec) and spec.substeps * REFINE <= MAX_SUBSTEPS


def _refined(case: Case, stopped: SolveResult, departed: Solution | None = None) -> tuple[Case, str]:
    """The case with REFINE times the RK4 steps per shooting interval, and the line that says
    why: the solve `stopped` at a cycle (which it does only where its case is `_refinable`), or
    its optimum's forward simulation `departed` from the NLP."""
    spec = case.problem.transcription
    assert isinstance(spec, MultipleShootingSpec) and _refinable(case)
    steps = spec.substeps * REFINE
    if departed is None:
        why = f"IPOPT's iterates cycled after {stopped.iterations} iterations"
        where = "(a kink of the force laws crossed inside a step)"
    else:
        assert departed.verification is not None and departed.verification.problem is not None
        why = departed.verification.problem
        where = "(the NLP's integration too coarse where the force law bends)"
    return case.with_transcription(spec.model_copy(update={"substeps": steps})), (
        f"{case.name}: {why} at {spec.substeps} RK4 step(s) per interval {where}; solved again from there with {steps}"
    )


def _settled(case: Case) -> str:
    """The line that says a cycle no finer integration could take away was settled
    (crashnlp.optimize.options.SETTLE_OPTIONS)."""
    return (
        f"{case.name}: IPOPT's iterates circled the optimum at {_where(case)} (a kink of the force laws crossed inside a "
        f"step); stopped at IPOPT's acceptable level: {_steady_for(case, SETTLE_OPTIONS)}"
    )


def _unsettled(case: Case) -> str:
    """The line that says a cycle no finer integration could take away did not settle, and the exact
    Hessian finished the fit from it (crashnlp.optimize.solve.settled)."""
    return (
        f"{case.name}: IPOPT's iterates circled the optimum at {_where(case)} (a kink of the force laws crossed inside a"
        " step) without settling; the exact Hessian finished the fit from there"
    )


def _where(case: Case) -> str:
    """Where a case's solve crosses the force laws' kinks: its RK4 steps per interval, or its grid."""
    spec = case.problem.transcription
    return f"{spec.substeps} RK4 steps per interval" if isinstance(spec, MultipleShootingSpec) else "its collocation grid"


def _steady(case: Case) -> str:
    """The line that says a fit stopped at IPOPT's acceptable level with its objective steady
    (crashnlp.optimize.options.STEADY_OPTIONS)."""
    return (
        f"{case.name}: {_steady_for(case, STEADY_OPTIONS)}: stopped at IPOPT's acceptable level, short of its"
        " tolerance (as where a kink of the force laws, crossed inside an integration step, holds the dual"
        " infeasibility up)"
    )


def _steady_for(case: Case, defaults: dict[str, float]) -> str:
    """How steady IPOPT's acceptable level asked the objective to be: the run's `defaults`, with
    the problem's own solver.ipopt options winning, as they do in the run."""
    options = {**defaults, **case.problem.solver.ipopt}
    return (
        f"the objective steady to {options['acceptable_obj_change_tol']:g} over {options['acceptable_iter']} iterations,"
        " the constraints met"
    )


def _finished(case: Case, ocp: OptimalControl, fit: FitObjective, result: SolveResult, theta0: np.ndarray) -> Solution:
    """`finish`, with the covariance (the prior's information in it; the values the fitted tests
    never reach left out of it) and the prior's weight."""
    solution = finish(case, ocp, result, theta0, fit.residuals)
    information = fit.prior.information(fit.weight) if fit.prior is not None else None
    sensitivity = SensitivityEvaluator(ocp, fit.residuals)(result.z)
    solution.covariance = sensitivity.without(solution.unreached()).covariance(information)
    solution.regularization = {"weight": fit.weight}
    return solution
