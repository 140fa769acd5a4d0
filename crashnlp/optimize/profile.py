"""Profile-likelihood intervals: fix one parameter at a time, re-optimise the rest.

For each chosen parameter the NLP is solved again with that entry held at
values stepping away from the optimum, 0.75 standard errors apart, each solve
warm-started from the previous one (one IPOPT solver per chain: only its
bounds change). The two sides of every parameter are independent chains and
run in parallel on the executor given (crashnlp.engine): a step after the fit,
on its solution, as pyPESTO's parameter_profile(problem, result, optimizer, engine).

Threshold: near the optimum the objective f = sum w e^2 rises along a profile
as delta^2 / [H^-1]_ii (H = J^T W J). The interval ends where the rise reaches
1.96^2 var_i / [H^-1]_ii, with var_i the sandwich variance, so that in the
quadratic limit the profile interval is the sandwich interval, and away from
it the profile follows the model's nonlinearity and the bounds (a side that
never reaches the threshold within the profiled range or a bound is open:
None). Each point keeps its solve's IPOPT status, and an end resting on a solve
IPOPT did not finish (one of the points walked up to it, all of them for an open
end) names the statuses under `unsolved`: its objective is not the profile's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crashnlp.base.outputs import Z95
from crashnlp.case.case import Case
from crashnlp.engine.executors import Executor
from crashnlp.engine.schedule import map_all
from crashnlp.numerics.nlp import SUCCESS
from crashnlp.optimize.identify import Solution, fit_ocp
from crashnlp.optimize.solvers import build_solver
from crashnlp.problem.schema import Problem

STEP = 0.75  # standard errors between profile points


@dataclass(frozen=True)
class Chain:
    """One side of one parameter's profile: plain data, so it can travel to a worker."""

    problem: Problem
    z: np.ndarray  # the optimum's decision vector
    index: int  # entry of theta
    values: tuple[float, ...]  # SI, stepping away from the optimum


def walk(chain: Chain) -> list[tuple[float, float, str]]:
    """(value, objective, IPOPT status) along a chain, each solve warm-started from the last."""
    ocp, _ = fit_ocp(Case(chain.problem))  # the identification's shape: its compiled library serves
    built = build_solver(ocp.nlp, chain.problem.solver)
    bounds = ocp.nlp.bounds()
    block = ocp.nlp.blocks["theta"]
    k, scale = block.offset + chain.index, float(block.scale.ravel()[chain.index])
    z, out = chain.z, []
    for value in chain.values:
        lbx, ubx = bounds["lbx"].copy(), bounds["ubx"].copy()
        lbx[k] = ubx[k] = value / scale
        z = z.copy()
        z[k] = value / scale
        sol, stats = built({**bounds, "x0": z, "lbx": lbx, "ubx": ubx})
        status = str(stats.get("return_status"))
        z = np.asarray(sol["x"]).ravel()
        out.append((value, float(sol["f"]), status))
    return out


def _crossing(theta: float, f0: float, points: list[tuple[float, float, str]], threshold: float) -> tuple[float | None, int]:
    """Where the profile's rise first reaches the threshold (linear in the signed root), or None,
    and how many of the points it rests on: those walked up to it (all of them for None)."""
    previous_value, previous_root = theta, 0.0
    for n, (value, f, _) in enumerate(points, 1):
        root = np.sqrt(max(f - f0, 0.0))
        if root >= np.sqrt(threshold):
            w = (np.sqrt(threshold) - previous_root) / (root - previous_root)
            return float(previous_value + w * (value - previous_value)), n
        previous_value, previous_root = value, root
    return None, len(points)


def _unsolved(points: list[tuple[float, float, str]]) -> list[str]:
    """The IPOPT statuses, each once, of the points' solves that did not succeed (SUCCESS)."""
    return sorted({status for _, _, status in points if status not in SUCCESS})


def profiles(solution: Solution, executor: Executor) -> dict[str, dict]:
    """Profile intervals of the parameters the problem's `uncertainty.profile` names, their
    chains run on `executor` (which the caller closes)."""
    spec = solution.case.problem.uncertainty
    if not spec.profile or solution.covariance is None or solution.result is None:
        return {}
    labels = solution.ocp.free.labels()
    free = solution.ocp.free
    # the profiles re-optimise the objective the fit minimised: the prior at the weight it chose
    problem = solution.case.problem.with_values({"objective.regularization": solution.regularization.get("weight", 0.0)})
    chains, keys = [], []
    for label in spec.profile:  # each an estimated entry: crashnlp.optimize.pipeline.check_profiled
        i = labels.index(label)
        std, h = solution.covariance.std[i], solution.covariance.hessian_inverse[i, i]
        if not np.isfinite(std) or h <= 0:
            continue
        for side in (-1, 1):
            steps = solution.theta[i] + side * STEP * std * np.arange(1, spec.points + 1)
            steps = steps[(steps >= free.lower[i]) & (steps <= free.upper[i])]
            if steps.size:
                chains.append(Chain(problem, solution.result.z, i, tuple(float(v) for v in steps)))
                keys.append((label, side))
    walked = {keys[i]: result for i, result in map_all(executor, walk, chains)}
    out = {}
    for label in spec.profile:
        i = labels.index(label)
        std, h = solution.covariance.std[i], solution.covariance.hessian_inverse[i, i]
        threshold = Z95**2 * std**2 / h if np.isfinite(std) and h > 0 else np.inf
        ends: dict[str, float | None] = {}
        unsolved: dict[str, list[str]] = {}
        profile: list[tuple[float, float, str]] = []
        for side, key in ((-1, "lower"), (1, "upper")):
            points = walked.get((label, side), [])
            if isinstance(points, BaseException):
                raise points
            ends[key], rests_on = _crossing(solution.theta[i], solution.result.objective, points, threshold)
            if failed := _unsolved(points[:rests_on]):
                unsolved[key] = failed
            profile += points
        profile.sort()
        out[label] = {
            "estimate": float(solution.theta[i]),
            "threshold": float(threshold),
            **ends,
            "points": [[v, f] for v, f, _ in profile],
            "statuses": [status for _, _, status in profile],
            "unsolved": unsolved,
        }
    return out
