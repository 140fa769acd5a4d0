"""Run IPOPT on an assembled NLP and say honestly how it went."""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal, TextIO

import casadi as ca
import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.numerics.nlp import SUCCESS, NLPBuilder
from crashnlp.optimize.oracle import SOLVER_OPTIONS, oracle
from crashnlp.problem.schema import Solver


@dataclass
class SolveResult:
    z: np.ndarray
    objective: float
    lam_g: np.ndarray
    lam_x: np.ndarray
    g: np.ndarray
    return_status: str
    iterations: int
    wall_s: float
    build_s: float
    profile: dict[str, tuple[int, float]] = field(default_factory=dict)  # IPOPT's functions: calls, seconds
    compiled: bool = False  # IPOPT called the compiled NLP functions (crashnlp.optimize.oracle)
    tail: float | None = None  # stopped in Gauss-Newton's slow tail (Watch): the distance still to go
    stopped: Stop | None = None  # why the Watch stopped Gauss-Newton short of convergence
    settled: bool = False  # the run settled a cycle (SETTLE_OPTIONS)

    @property
    def converged(self) -> bool:
        return self.return_status in SUCCESS

    @property
    def cycling(self) -> bool:
        return self.stopped == "cycle"


# Gauss-Newton's slow tail. Near a fit that leaves large residuals, or along a weakly determined
# direction, Gauss-Newton converges only linearly: on pickup-40kph every primal step is 0.91 of
# the one before, and it takes 113 iterations where the exact Hessian, started from where
# Gauss-Newton had got to, needs 1 or 2. The tail: TAIL_RUN ratios of successive steps in a
# row between TAIL_RATIO and 1 and within TAIL_SPREAD of each other, the last step below
# TAIL_STEP in the scaled variables, the constraints met to TAIL_VIOLATION. A contraction of
# 0.5 or slower gains a digit in 3.3 iterations or more; Newton gains them quadratically once
# this close. The ratio must be steady: steps that shrink unevenly are Gauss-Newton leaving a
# point, not closing in on it. The measurements behind these numbers: docs/design-notes.md.
TAIL_RATIO, TAIL_SPREAD, TAIL_RUN, TAIL_STEP, TAIL_VIOLATION = 0.5, 0.02, 3, 3e-2, 1e-4
TAIL_REACH, TAIL_NEWTON_ITER = 10.0, 20  # see `finishes`; Newton from the tail takes 2 to 4 iterations

# A cycle: the iterates go round a point instead of closing in on it. Where the crush crosses a
# kink of the force laws inside an integration step, the step's derivatives jump as the
# parameters move the crossing across a stage of the step; the dual infeasibility then stays
# put and IPOPT steps round and round the optimum. Seen as: after CYCLE_START iterations, for
# CYCLE_RUN iterations in a row each iterate lies within CYCLE_RETURN of its last step from one
# of the CYCLE_PERIOD iterates before the last (it came back), the steps no shorter over the last
# half of them than CYCLE_SHRINK of the half before (a converging run shortens them), and the
# constraints met to CYCLE_VIOLATION. Cycles are not always short: a corpus vehicle's joint fit
# (seed 2032, vehicle 1) went round 23 iterates at 4 RK4 steps per interval, so CYCLE_PERIOD
# looks 30 back (at 16 steps the same fit converges in 23 iterations).
CYCLE_START, CYCLE_RUN, CYCLE_PERIOD, CYCLE_RETURN, CYCLE_SHRINK, CYCLE_VIOLATION = 20, 8, 30, 0.3, 0.7, 1e-3

# Wandering: the iterates left the start's basin. From a start near a fit (a study case warm-
# started from its neighbour's solution), IPOPT's first barrier (mu 0.1, adapted) pushes a start
# that sits on its constraints (the monotone crush, the pitch bound at many nodes) away from
# them, a long Gauss-Newton step opens the shooting defects, and IPOPT wanders for a hundred
# iterations at objectives far above the start's before it finds its way back. Seen as: after
# WANDER_START iterations, an objective above WANDER_RISE times the start's with the constraints
# violated by more than WANDER_VIOLATION. Gauss-Newton then starts over from the start with a
# barrier that starts at WANDER_OPTIONS' 1e-4 and only falls. Not the default for every warm start: on cases
# that do not wander it saves nothing and costs some (3 deg/40 -> 50 kN/m: 21 -> 42 iterations).
# From the cold start of a fit, a long way from the optimum, the objective may rise above the
# start's and come back (corpus v17), so the rule watches warm starts only.
WANDER_START, WANDER_RISE, WANDER_VIOLATION = 25, 2.0, 1e-3
WANDER_OPTIONS = {"mu_strategy": "monotone", "mu_init": 1e-4}
# A steady objective. Where a kink of the force laws is crossed inside an integration step, a fit
# can reach its objective and then sit there: the dual infeasibility held up by the derivatives'
# jump, the barrier at its floor, each line search cut 20 to 30 times at an unchanged iterate.
# IPOPT then stops at its own acceptable level once STEADY_OPTIONS hold for 8 iterations in a row:
# the objective changing by less than 1e-7 (relative where it is above 1) with the constraints met
# to 1e-6.
# Corpus vehicle 17 at 100 intervals takes 19 iterations with the stop and 73 to IPOPT's
# tolerance; on 96 fits of the shipped problems and the corpus, no parameter moved by more than
# 2.4e-5 of its standard error. Gauss-Newton's slow tail (TAIL_RATIO) is as steady: where `solve`
# watches for the tail it hands it to Newton first, and a Gauss-Newton run that does not watch
# may stop in it (docs/identification.md).
STEADY_OPTIONS = {
    "acceptable_tol": 1e20,
    "acceptable_obj_change_tol": 1e-7,
    "acceptable_constr_viol_tol": 1e-6,
    "acceptable_iter": 8,
}
# Settling a cycle that no finer integration can take away (the finest RK4 steps, or collocation):
# Gauss-Newton starts again from the cycle's iterate, warm, and IPOPT stops at its own acceptable
# level once SETTLE_OPTIONS hold for 15 iterations in a row: the objective steady to the fit's
# tolerance (relative) with the constraints met. The dual infeasibility is not asked to fall, since
# the derivatives' jump at the kink keeps it up. Going on round the cycle would move the parameters
# by a few millionths of their standard errors (docs/identification.md).
SETTLE_OPTIONS = {**STEADY_OPTIONS, "acceptable_obj_change_tol": 1e-5, "acceptable_iter": 15}
Stop = Literal["cycle", "wander"]
Look = Literal["tail", Stop]  # what the Watch looks for: the slow tail, and the stops


class Watch(ca.Callback):
    """IPOPT's iteration callback: a short line every `every` iterations when asked, and for a
    Gauss-Newton fit a stop in its slow tail, a cycle or a wander (TAIL_RATIO, CYCLE_START and
    WANDER_START above)."""

    def __init__(self, nx: int, ng: int, every: int = 10):
        ca.Callback.__init__(self)
        self.nx, self.ng, self.every = nx, ng, every
        self.start(np.zeros(ng), np.zeros(ng), None)
        self.construct("watch", {})

    def start(self, lbg: np.ndarray, ubg: np.ndarray, out: TextIO | None, looks: frozenset[Look] = frozenset()) -> None:
        """Before a run: the constraint bounds, where progress goes, and which of Gauss-Newton's
        slow tail, a cycle and a wander stop it."""
        self.lbg, self.ubg, self.out, self.looks = lbg, ubg, out, looks
        self.count = 0
        self.x: np.ndarray | None = None  # the last iterate
        self.steps: list[float] = []  # the primal steps' lengths, scaled variables
        self.iterates: list[np.ndarray] = []  # the last CYCLE_PERIOD + 1
        self.returns = 0  # iterates in a row that came back (CYCLE_START above)
        self.remaining: float | None = None  # set to hand over to Newton: the distance still to go
        self.start_objective: float | None = None
        self.stopped: Stop | None = None  # set to stop a cycle or a wander (CYCLE_START, WANDER_START above)

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name == "x":
            return ca.Sparsity.dense(self.nx)
        if name == "g":
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)  # the multipliers are not read: nlpsol skips empty inputs

    def eval(self, arg):
        count, self.count = self.count, self.count + 1
        printing = self.out is not None and count % self.every == 0
        if not (printing or self.looks):  # designs, profiles, most iterations: nothing to look at
            return [0]
        names = ca.nlpsol_out()

        def violation() -> float:
            g = np.asarray(arg[names.index("g")]).ravel()
            return float(np.max(np.maximum(self.lbg - g, g - self.ubg), initial=0.0))

        if printing:
            f = float(arg[names.index("f")])
            print(f"  iter {count:4d}  objective {f:11.5g}  constraint violation {violation():9.2e}", file=self.out)
        if self.looks:
            self._follow(arg[names.index("x")].full().ravel(), float(arg[names.index("f")]), violation)
        return [int(self.remaining is not None or self.stopped is not None)]

    def _follow(self, x: np.ndarray, f: float, violation: Callable[[], float]) -> None:
        """Gauss-Newton's steps: in its slow tail, `remaining` is the distance still to go; in a
        cycle or a wander, `stopped` says which (the constraint violation is computed only there)."""
        if self.start_objective is None:
            self.start_objective = f
        if self.x is not None:
            self.steps.append(float(np.abs(x - self.x).max(initial=0.0)))
        self.x = x
        if "cycle" in self.looks:
            judged = self.count >= CYCLE_START - CYCLE_RUN  # a cycle is seen from CYCLE_START on
            self.iterates, self.returns = followed(self.iterates, self.returns, x, judged)
        if "tail" in self.looks and slow_tail(self.steps) and violation() <= TAIL_VIOLATION:
            ratio = self.steps[-1] / self.steps[-2]
            self.remaining = self.steps[-1] * ratio / (1 - ratio)
        elif (
            "cycle" in self.looks
            and self.count >= CYCLE_START
            and cycle(self.returns, self.steps)
            and violation() <= CYCLE_VIOLATION
        ):
            self.stopped = "cycle"
        elif (
            "wander" in self.looks
            and self.count >= WANDER_START
            and f > WANDER_RISE * self.start_objective
            and violation() > WANDER_VIOLATION
        ):
            self.stopped = "wander"


def slow_tail(steps: list[float]) -> bool:
    """Whether the last primal steps shrink linearly, slowly and steadily (TAIL_RATIO above)."""
    if len(steps) <= TAIL_RUN or steps[-1] > TAIL_STEP or min(steps[-TAIL_RUN - 1 :]) <= 0:
        return False
    last = steps[-TAIL_RUN - 1 :]
    ratios = [b / a for a, b in zip(last, last[1:])]  # a few numbers: plain Python, no numpy calls
    return all(TAIL_RATIO <= r < 1 for r in ratios) and max(ratios) - min(ratios) <= TAIL_SPREAD


def followed(iterates: list[np.ndarray], returns: int, x: np.ndarray, judged: bool = True) -> tuple[list[np.ndarray], int]:
    """The last CYCLE_PERIOD + 1 iterates with `x`, and how many in a row came back (`came_back`);
    not `judged`, none (before a cycle could be seen, the window is only filled)."""
    iterates = [*iterates[-CYCLE_PERIOD:], x]
    return iterates, returns + 1 if judged and came_back(iterates) else 0


def came_back(iterates: list[np.ndarray]) -> bool:
    """Whether the last iterate lies within CYCLE_RETURN of its step from an earlier one than
    the one before it (CYCLE_START above)."""
    if len(iterates) < 3:
        return False
    x, step = iterates[-1], float(np.abs(iterates[-1] - iterates[-2]).max(initial=0.0))
    if step <= 0:
        return False
    distances = np.abs(np.stack(iterates[:-2]) - x).max(axis=1, initial=0.0)  # one call for the window
    return bool(distances.min() <= CYCLE_RETURN * step)


def cycle(returns: int, steps: list[float]) -> bool:
    """Whether the iterates go round a point: CYCLE_RUN of them in a row came back, with steps
    that do not shrink (CYCLE_START above)."""
    if returns < CYCLE_RUN or len(steps) < CYCLE_RUN:
        return False
    last, half = steps[-CYCLE_RUN:], CYCLE_RUN // 2
    return sum(last[half:]) >= CYCLE_SHRINK * sum(last[:half])


# IPOPT's options for a least-squares fit (designs keep IPOPT's own); the measurements behind
# them, and the options screened beside them, are in docs/design-notes.md ("IPOPT options of a fit"):
# - tol 1e-5: near a fit that leaves residuals Gauss-Newton converges linearly (the KKT error
#   falls about 3x per iteration on the pickup); from 1e-5 to 1e-8 a quarter of the iterations
#   moved the shipped fits' parameters by less than 5e-6 of their standard errors.
# - tau_min 0.8: early steps go at most 80 % of the way to a bound, not 99 %. Gauss-Newton
#   sends weakly determined parameters (the unloading stiffness, spring values beyond the
#   largest crush) toward their bounds; a step to 99 % of a bound changes the dynamics so much
#   that the shooting defects open and the iterates wander for hundreds of iterations. Designs
#   take many times the iterations with it, so they keep 0.99.
# - IPOPT's own barrier rule (the quality function). LOQO's rule saves iterations on most fits,
#   but on fits held by a pitch bound far below the free fit's (the spring's breakpoints crossed
#   inside 9 mm RK4 steps) Gauss-Newton cycles with it where it converges with this one.
# - STEADY_OPTIONS (above): a fit whose objective has stopped moving stops.
FIT_OPTIONS: dict[str, Any] = {"tol": 1e-5, "tau_min": 0.8, **STEADY_OPTIONS}


def ipopt_options(spec: Solver, verbose: bool, fit: bool = False, formulation: dict[str, Any] | None = None) -> dict:
    """IPOPT's options: adaptive barrier, and MUMPS ordering by approximate minimum fill, which on
    the larger crash NLPs (collocation beyond 400 intervals, several tests) halves the iterations
    and the time per factorization against MUMPS's automatic choice; FIT_OPTIONS for a
    least-squares `fit`; the options the NLP's `formulation` asks for (its transcription's, for
    the Gauss-Newton Hessian: NLPBuilder.gauss_newton_options); the problem's own options win."""
    opts = {
        "print_level": 5 if verbose else 0,
        "sb": "yes",
        "max_iter": 1000,
        "tol": 1e-8,
        "mu_strategy": "adaptive",
        "mumps_pivot_order": 2,
    }
    if fit:
        opts.update(FIT_OPTIONS)
    opts.update(formulation or {})
    if spec.hessian == "limited-memory":
        opts["hessian_approximation"] = "limited-memory"
    opts.update(spec.ipopt)
    return opts


def hessian_kind(nlp: NLPBuilder, spec: Solver) -> str:
    """The Hessian IPOPT gets: `auto` is Gauss-Newton when the objective is a least-squares fit."""
    if spec.hessian == "auto":
        return "gauss-newton" if nlp.squares else "exact"
    if spec.hessian == "gauss-newton" and not nlp.squares:
        raise InputError("solver.hessian: gauss-newton needs a least-squares objective (objective.loss l2 with data)")
    return spec.hessian


@dataclass
class BuiltSolver:
    """An nlpsol Function with its iteration callback (which must live as long as it)."""

    function: ca.Function
    build_s: float
    watch: Watch
    compiled: bool = False

    def __call__(
        self, args: dict[str, np.ndarray], out: TextIO | None = None, looks: frozenset[Look] = frozenset()
    ) -> tuple[dict, dict]:
        """One IPOPT run: its solution and stats; progress lines to `out`; Gauss-Newton stopped
        at what it `looks` for (Watch)."""
        self.watch.start(args["lbg"], args["ubg"], out, looks)
        sol = self.function(**args)
        return sol, self.function.stats()


_solvers: dict[
    tuple[str, str], tuple[ca.Function, Watch]
] = {}  # (NLP key, options) -> nlpsol, reused by every solve of that shape


def build_solver(nlp: NLPBuilder, spec: Solver, verbose: bool = False, warm: bool = False) -> BuiltSolver:
    """nlpsol over the NLP's functions (crashnlp.optimize.oracle): compiled when the cache
    holds them; one solver per NLP shape and options in a process (study workers and profiles
    solve many NLPs of one shape); `warm`: IPOPT starts from the given multipliers too."""
    t0 = time.perf_counter()
    hessian = hessian_kind(nlp, spec)
    o = oracle(nlp, hessian, spec.compile, spec.expand)
    formulation = nlp.gauss_newton_options if hessian == "gauss-newton" else {}
    ipopt = ipopt_options(spec, verbose, fit=bool(nlp.squares), formulation=formulation)
    if warm:
        ipopt = {**WARM_OPTIONS, **ipopt}
    opts: dict[str, Any] = {"ipopt": ipopt, "print_time": False, **SOLVER_OPTIONS}
    key = (o.key, json.dumps([o.compiled, opts], sort_keys=True, default=str))
    if key not in _solvers:
        b = nlp.bounds()
        watch = Watch(len(b["x0"]), len(b["lbg"]))
        _solvers[key] = (ca.nlpsol("crashnlp", "ipopt", o.nlp, {**opts, **o.derivatives, "iteration_callback": watch}), watch)
    function, watch = _solvers[key]
    return BuiltSolver(function, time.perf_counter() - t0, watch, o.compiled)


AUTO_GAUSS_NEWTON_ITER = 300  # Gauss-Newton iterations `auto` allows before it starts over with the exact Hessian
# where IPOPT fails with the Gauss-Newton Hessian (a failed restoration or step computation),
# the exact one starts over from the initial guess instead of the fit failing
GAUSS_NEWTON_FAILURES = ("Restoration_Failed", "Error_In_Step_Computation")
# Newton from where Gauss-Newton's tail began: IPOPT takes the iterate and its multipliers as
# they are, with a barrier already at its floor.
WARM_OPTIONS = {
    "warm_start_init_point": "yes",
    "mu_init": 1e-9,
    "warm_start_bound_push": 1e-9,
    "warm_start_mult_bound_push": 1e-9,
    "warm_start_slack_bound_push": 1e-9,
}


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
    fast near a good fit (15 to 30 iterations on the shipped problems). Where it converges only
    linearly (a large residual or a weakly determined direction: its slow tail, TAIL_RATIO
    above), the exact Hessian (structured and compiled like the rest,
    about twice a Gauss-Newton iteration's cost) finishes from there, warm-started; where
    Newton does not finish the same fit (`finishes`), Gauss-Newton runs again to the end,
    watched for a cycle only. Where Gauss-Newton fails (GAUSS_NEWTON_FAILURES) or
    has not converged after AUTO_GAUSS_NEWTON_ITER iterations, IPOPT starts over with the exact Hessian from the
    initial guess, since a crawl can end far from where the exact Hessian converges from. Where
    Gauss-Newton's iterates cycle (CYCLE_START above), the run stops there: the exact Hessian
    sees the same kink. A `refinable` solve returns `cycling`, and the caller refines the
    integration (crashnlp.optimize.identify); any other settles it (SETTLE_OPTIONS above), to
    IPOPT's acceptable level. Where they wander from a neighbour's solution (WANDER_START
    above), Gauss-Newton starts over from it with a small, monotone barrier (WANDER_OPTIONS). The
    result counts the iterations and time of every run."""
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
        settle = gauss_newton.model_copy(update={"ipopt": {**SETTLE_OPTIONS, **gauss_newton.ipopt}})
        first = dataclasses.replace(after(first, _solve(nlp, settle, verbose, progress, start=first)), settled=True)
    crawled = first.return_status == "Maximum_Iterations_Exceeded" and limit >= AUTO_GAUSS_NEWTON_ITER
    if first.converged or not (crawled or first.return_status in GAUSS_NEWTON_FAILURES):
        return first
    return after(first, _solve(nlp, exact, verbose, progress))


def finishes(tail: SolveResult, newton: SolveResult) -> bool:
    """Whether Newton, started in Gauss-Newton's tail, finished the same fit: converged, and
    to a lower objective or within TAIL_REACH times the distance the tail had still to go.
    Started from a tail, Newton can also converge to another KKT point, far away and at a
    higher objective: that is not the fit Gauss-Newton was closing in on."""
    if not newton.converged or tail.tail is None:
        return False
    moved = float(np.max(np.abs(newton.z - tail.z), initial=0.0))
    return newton.objective <= tail.objective or moved <= TAIL_REACH * tail.tail


def after(before: SolveResult, run: SolveResult) -> SolveResult:
    """A run's result, counting the iterations and time of the runs before it."""
    return dataclasses.replace(
        run,
        iterations=before.iterations + run.iterations,
        wall_s=before.wall_s + run.wall_s,
        build_s=before.build_s + run.build_s,
    )


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
