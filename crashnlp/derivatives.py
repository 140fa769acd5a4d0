"""Structure-exploiting derivatives of an assembled NLP.

The costly part of every crashnlp NLP is a few mapped interval functions (one
RK4 step, one collocation interval, the outputs at one node), each a small SX
Function of one column of inputs. CasADi's own Jacobian of the whole MX graph
colours it and sweeps every colour through every interval; here each interval
function's Jacobian is derived once, symbolically, mapped over the columns and
laid out block-diagonally (no copying: the mapped result has the same
nonzeros), then chained through the cheap outer expressions (selections,
scalings, differences) that CasADi differentiates directly:

    dg/dz = dg/dz|_V + sum_b dg/dV_b * blockdiag(J_b) * dW_b/dz

with V_b a block's outputs and W_b its inputs. The Gauss-Newton Hessian of a
least-squares objective sum |r|^2 + q is 2 J_r^T J_r + hess(q), the Hessian
nonlinear least-squares solvers use: it drops the constraints' curvature,
which the dynamics multipliers make small near a good fit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca

from crashnlp.runtime import mapped


@dataclass
class MappedBlock:
    """One interval function mapped over n columns, as it appears in the NLP."""

    fn: ca.Function  # SX, one column
    n: int
    inputs: list[ca.MX]  # each (rows x cols * n), functions of the decision vector and parameters
    outputs: list[ca.MX]  # the mapped call's outputs
    threads: int | None = None  # as the NLP's own maps

    def jacobians(self, z: ca.MX) -> list[ca.MX]:
        """d vec(output) / dz of every output: per-column Jacobians, block-diagonal, times dW/dz.

        Only the column inputs that depend on z are differentiated: the NLP's parameters
        (the fixed model values beside theta) would only add zero columns to every step."""
        ins = self.fn.sx_in()
        w = ca.vertcat(*[ca.vec(i) for i in ins])
        stacked = ca.vertcat(*[ca.reshape(x, s.numel(), self.n) for x, s in zip(self.inputs, ins)])
        dw: Any = ca.jacobian(ca.vec(stacked), z)
        m = w.numel()
        live = sorted({r % m for r in dw.sparsity().row()})
        dw = dw[[c * m + r for c in range(self.n) for r in live], :]
        dw = ca.evalf(dw) if not ca.symvar(dw) else dw
        column = ca.Function(f"{self.fn.name()}_jac", ins, [ca.jacobian(ca.vec(o), w[live]) for o in self.fn.call(ins)])
        per_column = mapped(column, self.n, self.threads).call(self.inputs)
        eye = ca.DM.eye(self.n)
        return [
            ca.mtimes(ca.sparsity_cast(J, ca.kron(eye, ca.DM.ones(column.sparsity_out(k))).sparsity()), dw)
            for k, J in enumerate(per_column)
        ]


class Derivatives:
    """Jacobians of NLP expressions through the mapped blocks they contain."""

    def __init__(self, z: ca.MX, p: ca.MX, blocks: list[MappedBlock]):
        self.z, self.p = z, p
        self.values = [v for b in blocks for v in b.outputs]
        self.symbols = [ca.MX.sym(f"V{i}", v.sparsity()) for i, v in enumerate(self.values)]
        self._blocks = blocks
        self._jacobians: list[ca.MX] | None = None

    def _block_jacobians(self) -> list[ca.MX]:
        if self._jacobians is None:
            self._jacobians = [J for b in self._blocks for J in b.jacobians(self.z)]
        return self._jacobians

    def jacobian(self, expr: ca.MX) -> ca.MX:
        """d expr / dz, the blocks' Jacobians chained in."""
        outer = ca.graph_substitute(expr, self.values, self.symbols)
        J = ca.jacobian(outer, self.z)
        for sym, dv in zip(self.symbols, self._block_jacobians()):
            if ca.depends_on(outer, sym):
                J = J + ca.mtimes(ca.jacobian(outer, sym), dv)
        return ca.graph_substitute(J, self.symbols, self.values)

    def jac_g(self, g: ca.MX) -> ca.Function:
        """The constraint Jacobian in nlpsol's `jac_g` form."""
        return ca.Function("jac_g", [self.z, self.p], [g, self.jacobian(g)], ["x", "p"], ["g", "jac_g_x"])

    def gauss_newton(self, residuals: ca.MX, rest: ca.MX, ng: int) -> ca.Function:
        """nlpsol's `hess_lag` for f = |residuals|^2 + rest: lam_f (2 J^T J + hess(rest))."""
        J = self.jacobian(residuals)
        H = 2 * ca.mtimes(J.T, J) + ca.hessian(rest, self.z)[0]
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", ng)
        return ca.Function(
            "hess_lag",
            [self.z, self.p, lam_f, lam_g],
            [ca.triu(lam_f * H)],
            ["x", "p", "lam_f", "lam_g"],
            ["triu_hess_gamma_x_x"],
        )
