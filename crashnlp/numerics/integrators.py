"""Fixed-step Runge-Kutta as CasADi Functions, shared by the transcriptions and the batch simulator."""

from __future__ import annotations

import casadi as ca


def rk4(rhs: ca.Function, h: float, substeps: int = 1) -> ca.Function:
    """`substeps` classical RK4 steps over h of x' = rhs(x, p) as an SX Function (x, p) -> x(h).

    `rhs` is any Function of a state column and one parameter input (its sizes are kept)."""
    x, p = ca.SX.sym("x", rhs.size1_in(0)), ca.SX.sym("p", rhs.sparsity_in(1))
    dt, xk = h / substeps, x
    for _ in range(substeps):
        k1 = rhs(xk, p)
        k2 = rhs(xk + dt / 2 * k1, p)
        k3 = rhs(xk + dt / 2 * k2, p)
        k4 = rhs(xk + dt * k3, p)
        xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function(f"rk4_{substeps}", [x, p], [xk])
