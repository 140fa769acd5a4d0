"""Run IPOPT on an assembled NLP and say honestly how it went: the restart strategy of a fit
(Gauss-Newton, Newton from its slow tail, a restart after a wander, the settling of a cycle, the
exact Hessian after a failure). Its parts: the result type (crashnlp.optimize.solved), the
callback and its detectors (crashnlp.optimize.watch), IPOPT's option policy
(crashnlp.optimize.options), the solver cache (crashnlp.optimize.solvers)."""

from __future__ import annotations

import dataclasses
import sys
import time
from typing import TextIO

import numpy as np

from crashnlp.numerics.nlp import NLPBuilder
from crashnlp.optimize.options import SETTLE_OPTIONS, WANDER_OPTIONS, hessian_kind
from crashnlp.optimize.solved import SolveResult, after
from crashnlp.optimize.solvers import build_solver
from crashnlp.optimize.watch import Look
from crashnlp.problem.schema import Solver

TAIL_REACH, TAIL_NEWTON_ITER = 10.0, 20  # see `finishes`; Newton from the tail takes 2 to 4 iterations
AUTO_GAUSS_NEWTON_ITER = 300  # Gauss-Newton iterations `auto` allows before it starts over with the exact Hessian
# where IPOPT fails with the Gauss-Newton Hessian (a failed restoration or step computation),
# the exact one starts over from the initial guess instead of the fit failing
GAUSS_NEWTON_FAILURES = ("Restoration_Failed", "Error_In_Step_Computation")


def solve(
    nlp: NLPBuilder,
    spec: Solver,
    verbose: bool = False,
    progress: TextIO | None = sys.stdout,
    from_neighbour: bool = False,
    refinable: bool = False,
) -> SolveResult:
    """Solve; the returned status is IPOPT's own. `from_neighbour`: the NLP starts from a
    neighbouring problem's solution (a study's warm start), where a wander is watched for;
    `refinable`: the caller can refine the integration, so that a cycle ends the solve
    (`cycling`) instead of being settled.

    With `hessian: auto` a least-squares fit starts with the Gauss-Newton Hessian, cheap and
    fast near a good fit. The restarts, each with its rule (crashnlp.optimize.watch for what the
    watch sees, crashnlp.optimize.options for the options of each run):
    - Gauss-Newton's slow tail: the exact Hessian (structured and compiled like the rest, about
      twice a Gauss-Newton iteration's cost) finishes from there, warm-started, at most
      TAIL_NEWTON_ITER iterations; where Newton does not finish the same fit (`finishes`),
      Gauss-Newton runs again to the end, watched for a cycle only.
    - A failure of Gauss-Newton (GAUSS_NEWTON_FAILURES), or no convergence after
      AUTO_GAUSS_NEWTON_ITER iterations: the exact Hessian starts over from the initial guess,
      since a crawl can end far from where the exact Hessian converges from.
    - A cycle: the run stops there, since the exact Hessian sees the same kink. A `refinable`
      solve returns `cycling`, and the caller refines the integration
      (crashnlp.optimize.identify); any other settles it to IPOPT's acceptable level
      (SETTLE_OPTIONS), watched: where the settle's iterates go round with an objective or
      constraints its acceptable level refuses, it cannot settle, and the exact Hessian
      finishes warm from its iterate (`settled`).
    - A wander from a neighbour's solution: Gauss-Newton starts over from it with a small,
      monotone barrier (WANDER_OPTIONS).
    The result counts the iterations and time of every run. Measured: docs/design-notes.md,
    "Gauss-Newton's slow tail", "Fits that finish: measured" and "A cycle that does not
    settle"."""
    if spec.hessian != "auto" or hessian_kind(nlp, spec) != "gauss-newton":
        return _solve(nlp, spec, verbose, progress)
    limit = min(int(spec.ipopt.get("max_iter", 1000)), AUTO_GAUSS_NEWTON_ITER)
    gauss_newton = spec.model_copy(update={"ipopt": {**spec.ipopt, "max_iter": limit}})
    exact = spec.model_copy(update={"hessian": "exact"})
    looks: frozenset[Look] = frozenset({"tail", "cycle"})
    first = _solve(nlp, gauss_newton, verbose, progress, looks=looks | ({"wander"} if from_neighbour else set()))
    if first.stopped == "wander":
        near = gauss_newton.model_copy(update={"ipopt": {**WANDER_OPTIONS, **gauss_newton.ipopt}})
        first = after(first, _solve(nlp, near, verbose, progress, looks=looks))
    if first.tail is not None:
        newton = _solve(
            nlp, exact.model_copy(update={"ipopt": {**spec.ipopt, "max_iter": TAIL_NEWTON_ITER}}), verbose, progress, start=first
        )
        if finishes(first, newton):
            return after(first, newton)
        # Newton did not finish what Gauss-Newton began: Gauss-Newton all the way, as without the tail
        first = after(after(first, newton), _solve(nlp, gauss_newton, verbose, progress, looks=frozenset({"cycle"})))
    if first.cycling and not refinable:
        first = settled(nlp, gauss_newton, exact, first, verbose, progress)
    crawled = first.return_status == "Maximum_Iterations_Exceeded" and limit >= AUTO_GAUSS_NEWTON_ITER
    if first.converged or not (crawled or first.return_status in GAUSS_NEWTON_FAILURES):
        return first
    return after(first, _solve(nlp, exact, verbose, progress))


def settled(
    nlp: NLPBuilder, gauss_newton: Solver, exact: Solver, cycled: SolveResult, verbose: bool, progress: TextIO | None
) -> SolveResult:
    """A cycle settled: Gauss-Newton warm from the `cycled` run's iterate, to IPOPT's acceptable
    level (SETTLE_OPTIONS), watched for a cycle that does not settle (crashnlp.optimize.watch);
    where one goes round, the exact Hessian finishes warm from the settle's iterate. Such a cycle
    swings the objective or opens the constraints from one iterate to the next, and each lap
    breaks the run of steady iterates the settle stops at, so that the settle runs to its limit;
    the exact Hessian started there converges (docs/design-notes.md, "A cycle that does not
    settle")."""
    settle = gauss_newton.model_copy(update={"ipopt": {**SETTLE_OPTIONS, **gauss_newton.ipopt}})
    run = after(cycled, _solve(nlp, settle, verbose, progress, start=cycled, looks=frozenset({"settle"})))
    if run.stopped != "unsettled":
        return dataclasses.replace(run, settled=True)
    return dataclasses.replace(after(run, _solve(nlp, exact, verbose, progress, start=run)), unsettled=True)


def finishes(tail: SolveResult, newton: SolveResult) -> bool:
    """Whether Newton, started in Gauss-Newton's tail, finished the same fit: converged, and
    to a lower objective or within TAIL_REACH times the distance the tail had still to go.
    Started from a tail, Newton can also converge to another KKT point, far away and at a
    higher objective: that is not the fit Gauss-Newton was closing in on."""
    if not newton.converged or tail.tail is None:
        return False
    moved = float(np.max(np.abs(newton.z - tail.z), initial=0.0))
    return newton.objective <= tail.objective or moved <= TAIL_REACH * tail.tail


def _solve(
    nlp: NLPBuilder,
    spec: Solver,
    verbose: bool,
    progress: TextIO | None,
    start: SolveResult | None = None,
    looks: frozenset[Look] = frozenset(),
) -> SolveResult:
    """One IPOPT run from the NLP's initial guess, or warm from `start`'s iterate and
    multipliers; Gauss-Newton stopped at what it `looks` for (Watch)."""
    built = build_solver(nlp, spec, verbose, warm=start is not None)
    args = nlp.bounds()
    if start is not None:
        args.update(x0=start.z, lam_x0=start.lam_x, lam_g0=start.lam_g)
    t0 = time.perf_counter()
    sol, stats = built(args, None if verbose else progress, looks)
    wall = time.perf_counter() - t0
    return SolveResult(
        z=np.asarray(sol["x"]).ravel(),
        objective=float(sol["f"]),
        lam_g=np.asarray(sol["lam_g"]).ravel(),
        lam_x=np.asarray(sol["lam_x"]).ravel(),
        g=np.asarray(sol["g"]).ravel(),
        return_status=str(stats.get("return_status", "unknown")),
        iterations=int(stats.get("iter_count", 0)),
        wall_s=wall,
        build_s=built.build_s,
        compiled=built.compiled,
        tail=built.watch.remaining,
        stopped=built.watch.stopped,
        profile={
            k[len("t_wall_") :]: (int(stats.get("n_call_" + k[len("t_wall_") :], 0)), float(v))
            for k, v in stats.items()
            if k.startswith("t_wall_nlp_")
        },
    )
