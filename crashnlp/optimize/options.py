"""IPOPT's option policy: the options every run gets, a least-squares fit's, and those of each
restart of crashnlp.optimize.solve (a wander's, a warm start's, a cycle's settling). Each rule
is stated with its reason; the measurements behind the numbers are in docs/design-notes.md
("IPOPT options of a fit")."""

from __future__ import annotations

from typing import Any

from crashnlp.base.errors import InputError
from crashnlp.numerics.nlp import NLPBuilder
from crashnlp.problem.schema import Solver

# A wander (crashnlp.optimize.watch, WANDER_START): Gauss-Newton starts over from the start with a
# barrier that starts small and only falls, so that it does not push the start off its constraints.
WANDER_OPTIONS = {"mu_strategy": "monotone", "mu_init": 1e-4}
# A steady objective. Rule: IPOPT stops at its own acceptable level once STEADY_OPTIONS hold for 8
# iterations in a row: the objective changing by less than 1e-7 (relative where it is above 1)
# with the constraints met to 1e-6. Reason: where a kink of the force laws is crossed inside an
# integration step, a fit can reach its objective and then sit there, the dual infeasibility held
# up by the derivatives' jump, the barrier at its floor, each line search cut at an unchanged
# iterate; going on moves no parameter by a meaningful share of its standard error.
# Gauss-Newton's slow tail (crashnlp.optimize.watch) is as steady: where `solve` watches for it
# it hands it to Newton first, and a Gauss-Newton run that does not watch may stop in it.
# Measured: docs/design-notes.md, "Fits that finish: measured"; checked on a corpus seed it was not
# set on (bench/detectors.py): "The watch's rules on an unseen seed".
STEADY_OPTIONS = {
    "acceptable_tol": 1e20,
    "acceptable_obj_change_tol": 1e-7,
    "acceptable_constr_viol_tol": 1e-6,
    "acceptable_iter": 8,
}
# Settling a cycle that no finer integration can take away (the finest RK4 steps, or collocation).
# Rule: Gauss-Newton starts again from the cycle's iterate, warm, and IPOPT stops at its own
# acceptable level once SETTLE_OPTIONS hold for 15 iterations in a row: the objective steady to
# the fit's tolerance (relative) with the constraints met. The dual infeasibility is not asked to
# fall, since the derivatives' jump at the kink keeps it up. Reason: going on round the cycle
# would move the parameters by a few millionths of their standard errors (docs/design-notes.md,
# "Fits that finish: measured"). The settle's run is watched: a cycle there whose objective or
# constraints these options refuse never settles, and the exact Hessian finishes from it
# (crashnlp.optimize.watch, "A cycle that does not settle").
SETTLE_OPTIONS = {**STEADY_OPTIONS, "acceptable_obj_change_tol": 1e-5, "acceptable_iter": 15}
# Newton from where Gauss-Newton's tail began: IPOPT takes the iterate and its multipliers as
# they are, with a barrier already at its floor.
WARM_OPTIONS = {
    "warm_start_init_point": "yes",
    "mu_init": 1e-9,
    "warm_start_bound_push": 1e-9,
    "warm_start_mult_bound_push": 1e-9,
    "warm_start_slack_bound_push": 1e-9,
}
# IPOPT's options for a least-squares fit (designs keep IPOPT's own); the measurements behind
# them, and the options screened beside them, are in docs/design-notes.md ("IPOPT options of a fit"):
# - tol 1e-5: near a fit that leaves residuals Gauss-Newton converges only linearly, and the
#   iterations from 1e-5 to IPOPT's 1e-8 move no parameter by a share of its standard error that
#   matters.
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
