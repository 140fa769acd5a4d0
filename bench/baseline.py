"""The scipy baseline: single shooting with solve_ivp inside least_squares.

Same model (crashnlp's CasADi augmented RHS, evaluated numerically: 4 states,
the largest crush so far and two absorbed energies, as the forward simulator
uses; the outputs by crashnlp's own compiled evaluation), same data, window,
free parameters, initial values, bounds and residual definition as the NLP. What differs is the method: a trust-region reflective
least-squares solve with a finite-difference Jacobian, one forward simulation
per residual evaluation. The NLP's monotone-crush constraint has no counterpart
here (it is inactive at the NLP's solution).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares

from bench.common import Target, node_times, residual_vector
from crashnlp.case.case import Case
from crashnlp.models.simulation import response_from_states
from crashnlp.optimize.free import FreeParameters

METHOD, RTOL, ATOL, MAX_STEP = "LSODA", 1e-6, 1e-8, 1e-3
DIFF_STEP = 1e-3  # relative finite-difference step ~ sqrt(rtol): scipy's default (1.5e-8) drowns in integrator error


@dataclass
class BaselineResult:
    parameters: dict  # path -> value, as crashnlp's Solution.parameters
    p: np.ndarray
    wall_s: float
    iterations: int  # least_squares' own count (Jacobian evaluations)
    simulations: int  # every forward simulation, finite differences included
    status: int
    message: str
    cost: float  # its own objective (sum of squared residuals) at the end

    @property
    def converged(self) -> bool:
        """least_squares status > 0 is a convergence test met; 0 is max_nfev reached."""
        return self.status > 0


def shoot(
    case: Case,
    p: np.ndarray,
    test_index: int,
    times: np.ndarray,
    method: str = METHOD,
    rtol: float = RTOL,
    atol: float = ATOL,
    max_step: float = MAX_STEP,
) -> dict[str, np.ndarray]:
    """Outputs of one test at `times` by solve_ivp on the augmented RHS (7 states)."""
    test = case.tests[test_index]
    model = case.model
    pt = case.test_parameters(test, p)
    rhs = model.augmented_rhs
    x0 = np.concatenate([np.asarray(model.initial_state(pt, test.speed)).ravel(), np.zeros(3)])
    sol = solve_ivp(
        lambda t, x: np.asarray(rhs(x, pt)).ravel(),
        (float(times[0]), float(times[-1])),
        x0,
        method=method,
        t_eval=times,
        rtol=rtol,
        atol=atol,
        max_step=max_step,
    )
    if not sol.success:
        raise RuntimeError(f"solve_ivp: {sol.message}")
    return response_from_states(model, pt, sol.t, sol.y).outputs  # crashnlp's own (compiled) outputs


class SingleShooting:
    """Residual function theta -> r(theta) counting its forward simulations."""

    def __init__(self, case: Case, targets: list[Target]):
        self.case, self.targets = case, targets
        self.free = FreeParameters(case.layout, case.base, case.problem.estimate)
        self.times = [node_times(case, t) for t in case.tests]
        self.simulations = 0

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        p = self.free.full(theta)
        outputs = [shoot(self.case, p, i, times) for i, times in enumerate(self.times)]
        self.simulations += len(outputs)
        return residual_vector(self.targets, outputs)


def fit(case: Case, targets: list[Target], max_nfev: int) -> BaselineResult:
    """least_squares (trf, bounds, x_scale='jac', 2-point Jacobian with a step above the
    integrator's error) from the problem's initial values."""
    fun = SingleShooting(case, targets)
    free = fun.free
    t0 = time.perf_counter()
    res = least_squares(
        fun,
        free.initial,
        jac="2-point",
        diff_step=DIFF_STEP,
        bounds=(free.lower, free.upper),
        x_scale="jac",
        method="trf",
        max_nfev=max_nfev,
    )
    wall = time.perf_counter() - t0
    return BaselineResult(
        free.named(res.x),
        free.full(res.x),
        wall,
        int(res.njev or 0),
        fun.simulations,
        int(res.status),
        str(res.message),
        float(2 * res.cost),
    )
