"""Run IPOPT on an assembled NLP and say honestly how it went."""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from dataclasses import dataclass, field
from typing import Any, TextIO

import casadi as ca
import numpy as np

from crashnlp.errors import InputError
from crashnlp.nlp import SUCCESS, NLPBuilder
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

    @property
    def converged(self) -> bool:
        return self.return_status in SUCCESS


class Progress(ca.Callback):
    """IPOPT iteration callback: a short line every `every` iterations."""

    def __init__(self, nx: int, ng: int, lbg: np.ndarray, ubg: np.ndarray, out: TextIO, every: int = 10):
        ca.Callback.__init__(self)
        self.nx, self.ng, self.lbg, self.ubg, self.out, self.every = nx, ng, lbg, ubg, out, every
        self.count = 0
        self.construct("progress", {})

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
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if name in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        if self.count % self.every == 0:
            g = np.asarray(arg[ca.nlpsol_out().index("g")]).ravel()
            viol = float(np.max(np.maximum(self.lbg - g, g - self.ubg), initial=0.0))
            f = float(arg[ca.nlpsol_out().index("f")])
            print(f"  iter {self.count:4d}  objective {f:11.5g}  constraint violation {viol:9.2e}", file=self.out)
        self.count += 1
        return [0]


# IPOPT's options for a least-squares fit (designs keep IPOPT's own):
# - tol 1e-5: near a fit that leaves residuals Gauss-Newton converges linearly (the KKT error
#   falls about 3x per iteration on the pickup); from 1e-5 to 1e-8 a quarter of the iterations
#   moved the shipped fits' parameters by less than 5e-6 of their standard errors.
# - tau_min 0.8: early steps go at most 80 % of the way to a bound, not 99 %. Gauss-Newton
#   sends weakly determined parameters (the unloading stiffness, spring values beyond the
#   largest crush) toward their bounds; at 99 % in one step (corpus vehicle v08: 38 -> 198 MN/m
#   of 200) the dynamics changed so much that the shooting defects opened and the iterates
#   wandered for hundreds of iterations. Corpus: 150 s -> 28 s (v06 907 -> 32 iterations, v08
#   320 -> 19), the shipped fits and the pickup's noisy replicates within 3 iterations of before,
#   at the same optima. Designs took 8 times the iterations with it, so they keep 0.99.
FIT_OPTIONS = {"tol": 1e-5, "tau_min": 0.8}


def ipopt_options(spec: Solver, verbose: bool, fit: bool = False) -> dict:
    """IPOPT's options: adaptive barrier, and MUMPS ordering by approximate minimum fill, which on
    the larger crash NLPs (collocation beyond 400 intervals, several tests) halves the iterations
    and the time per factorization against MUMPS's automatic choice; FIT_OPTIONS for a
    least-squares `fit`; the problem's own options win."""
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
    """An nlpsol Function with what must live as long as it (the progress callback)."""

    function: ca.Function
    build_s: float
    callback: Progress | None = None
    compiled: bool = False


_solvers: dict[tuple[str, str], ca.Function] = {}  # (NLP key, options) -> nlpsol, reused by every solve of that shape


def build_solver(nlp: NLPBuilder, spec: Solver, verbose: bool = False, progress: TextIO | None = None) -> BuiltSolver:
    """nlpsol over the NLP's functions (crashnlp.optimize.oracle): compiled when the cache
    holds them; one solver per NLP shape and options in a process, without a progress
    callback (study workers and profiles solve many NLPs of one shape)."""
    t0 = time.perf_counter()
    o = oracle(nlp, hessian_kind(nlp, spec), spec.compile, spec.expand)
    ipopt = ipopt_options(spec, verbose, fit=bool(nlp.squares))
    opts: dict[str, Any] = {"ipopt": ipopt, "print_time": False, **SOLVER_OPTIONS}
    if progress is not None:
        b = nlp.bounds()
        callback = Progress(len(b["x0"]), len(b["lbg"]), b["lbg"], b["ubg"], progress)
        function = ca.nlpsol("crashnlp", "ipopt", o.nlp, {**opts, **o.derivatives, "iteration_callback": callback})
        return BuiltSolver(function, time.perf_counter() - t0, callback, o.compiled)
    key = (o.key, json.dumps([o.compiled, opts], sort_keys=True, default=str))
    if key not in _solvers:
        _solvers[key] = ca.nlpsol("crashnlp", "ipopt", o.nlp, {**opts, **o.derivatives})
    return BuiltSolver(_solvers[key], time.perf_counter() - t0, None, o.compiled)


AUTO_GAUSS_NEWTON_ITER = 300  # Gauss-Newton iterations `auto` allows before it starts over with the exact Hessian


def solve(
    nlp: NLPBuilder,
    spec: Solver,
    verbose: bool = False,
    progress: TextIO | None = sys.stdout,
) -> SolveResult:
    """Solve; the returned status is IPOPT's own.

    With `hessian: auto` a least-squares fit starts with the Gauss-Newton Hessian, cheap and
    fast near a good fit (15 to 30 iterations on the shipped problems); where it has not
    converged after AUTO_GAUSS_NEWTON_ITER iterations (a large residual and strong curvature
    make it crawl), IPOPT starts over with the exact Hessian (structured and compiled like the
    rest, about twice a Gauss-Newton iteration's cost): from the initial guess, since the
    crawl can end far from where the exact Hessian converges from. The result counts the
    iterations and time of both."""
    if spec.hessian != "auto" or hessian_kind(nlp, spec) != "gauss-newton":
        return _solve(nlp, spec, verbose, progress)
    limit = min(int(spec.ipopt.get("max_iter", 1000)), AUTO_GAUSS_NEWTON_ITER)
    first = _solve(nlp, spec.model_copy(update={"ipopt": {**spec.ipopt, "max_iter": limit}}), verbose, progress)
    if first.converged or first.return_status != "Maximum_Iterations_Exceeded" or limit < AUTO_GAUSS_NEWTON_ITER:
        return first
    second = _solve(nlp, spec.model_copy(update={"hessian": "exact"}), verbose, progress)
    return dataclasses.replace(
        second,
        iterations=first.iterations + second.iterations,
        wall_s=first.wall_s + second.wall_s,
        build_s=first.build_s + second.build_s,
    )


def _solve(nlp: NLPBuilder, spec: Solver, verbose: bool, progress: TextIO | None) -> SolveResult:
    """One IPOPT run from the NLP's initial guess."""
    built = build_solver(nlp, spec, verbose, progress)
    b = nlp.bounds()
    t0 = time.perf_counter()
    sol = built.function(**b)
    wall = time.perf_counter() - t0
    stats = built.function.stats()
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
        profile={
            k[len("t_wall_") :]: (int(stats.get("n_call_" + k[len("t_wall_") :], 0)), float(v))
            for k, v in stats.items()
            if k.startswith("t_wall_nlp_")
        },
    )
