"""From a validated problem to a Result, the one way: every check, then the steps.

    problem -> prepare_case: the checks a solve needs, then the Case (data, layout, model)
            -> solve_case: identification or design (one NLP), profile intervals, the Result

crashnlp.api, the command line and a study's workers all call these, so what one of them
refuses, all refuse. An input error names its `source` (a problem file, a study case; the
problem's name when none is given).
"""

from __future__ import annotations

from typing import TextIO

import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.case.case import Case, case_of
from crashnlp.case.checks import check_keys, named
from crashnlp.optimize.design import design
from crashnlp.optimize.fit import fitted_channels
from crashnlp.optimize.free import FreeParameters
from crashnlp.optimize.identify import Solution, identify
from crashnlp.optimize.outcome import result_of
from crashnlp.problem import Problem
from crashnlp.results.result import Result


def prepare_case(problem: Problem, source: str | None = None) -> Case:
    """The Case of a problem to solve, after every check: its keys (crashnlp.case.checks), the tests'
    data against its speed and mass (Case.check_data: a fit to data that contradict the problem is
    refused, not run), the estimate as the solve lays it out (FreeParameters: an initial
    value of another size than its entry is refused here, not once the output folder is held),
    no entry its model form does not read (check_read), profiles of estimated entries alone
    (check_profiled), and something to solve for (check_solvable)."""
    check_keys(problem, source)
    case = case_of(problem, source)
    with named(source or problem.name):
        case.check_data()
        check_read(case)
        free = FreeParameters(case.layout, case.base, case.problem.estimate)
        check_profiled(case, free.labels())
        check_solvable(case, free.size)
    return case


def check_profiled(case: Case, labels: list[str]) -> None:
    """Refuse an `uncertainty.profile` entry that is none of the estimated values' `labels` (as the
    solve lays them out, the values completed from the data counted): the profiles would refuse it
    only after the solve."""
    for label in case.problem.uncertainty.profile:
        if label not in labels:
            raise InputError(f"uncertainty.profile: {label} is not an estimated entry ({', '.join(labels)})")


def check_read(case: Case) -> None:
    """Refuse an estimate entry that no equation of the problem's model form reads: the data
    would not determine it, and every prediction of the fit would go without intervals; and an
    engine or a crush offset given that the form does not read (Case.refuse_unread_given)."""
    unread = case.model.unread(list(case.problem.estimate))
    if unread:
        raise InputError(
            f"estimate.{unread[0]}: model.form {case.problem.model.form} does not read it (no equation of the form "
            "depends on it); leave it out"
        )
    case.refuse_unread_given()


def check_solvable(case: Case, free: int) -> None:
    """Refuse a problem with nothing to solve for: an estimate of no parameter (`free`, the
    decision variables it lays out), or an identification with no test data to fit."""
    if free == 0:
        raise InputError(f"estimate: names no {'design variable' if case.problem.kind == 'design' else 'parameter to identify'}")
    if case.problem.kind == "identify" and not any(fitted_channels(test) for test in case.tests):
        raise InputError("tests: no test has data to fit")


def solve_case(
    case: Case,
    verbose: bool = False,
    progress: TextIO | None = None,
    warm: np.ndarray | None = None,
    ratings: bool = True,
) -> Result:
    """Identify or design, as the problem's `kind` says, then the profile intervals it asks for.

    `progress`: a stream for a line every ten IPOPT iterations; `warm`: a Result.z of the same
    shape; `ratings`: ISO/TS 18571 ratings of the fits."""
    if case.problem.kind == "design":
        solution = design(case, verbose=verbose, progress=progress, warm=warm)
    else:
        solution = identify(case, verbose=verbose, progress=progress, warm=warm)
        profile(solution)
    return result_of(solution, ratings)


def profile(solution: Solution) -> None:
    """The profile intervals the problem's `uncertainty.profile` names, put into the solution, on
    the executor its `uncertainty` section says; none for a solve that did not converge."""
    spec = solution.case.problem.uncertainty
    if not spec.profile or solution.covariance is None or solution.result is None or not solution.result.converged:
        return
    from crashnlp.engine.executors import make_executor  # the process pool's modules: only for profiles
    from crashnlp.optimize.profile import profiles

    executor = make_executor(spec.executor, spec.workers)
    try:
        solution.profiles = profiles(solution, executor)
    finally:
        executor.close()


def solve_problem(
    problem: Problem,
    source: str | None = None,
    verbose: bool = False,
    progress: TextIO | None = None,
    warm: np.ndarray | None = None,
    ratings: bool = True,
) -> Result:
    """prepare_case, then solve_case: a validated problem in, its Result out."""
    return solve_case(prepare_case(problem, source), verbose, progress, warm, ratings)
