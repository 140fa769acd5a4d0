"""The process-wide cache of IPOPT solvers: one nlpsol per NLP shape and options in a process,
since study workers and profiles solve many NLPs of one shape and building one costs more than
many of their solves."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import Any, TextIO

import casadi as ca
import numpy as np

from crashnlp.numerics.nlp import NLPBuilder
from crashnlp.optimize.options import WARM_OPTIONS, hessian_kind, ipopt_options
from crashnlp.optimize.oracle import SOLVER_OPTIONS, oracle
from crashnlp.optimize.watch import Look, Watch
from crashnlp.problem.schema import Solver


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
        at what it `looks` for (Watch). `out`'s reader gone, the run stops at that line with the
        BrokenPipeError raised here, where the command ends as at any other write to it."""
        self.watch.start(args["lbg"], args["ubg"], out, looks)
        sol = self.function(**args)
        if self.watch.broken is not None:
            raise self.watch.broken
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
