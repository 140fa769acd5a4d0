"""Structure-exploiting derivatives of an assembled NLP.

The costly part of every crashnlp NLP is a few mapped interval functions (one
RK4 step, one collocation interval, the outputs at one node), each a small SX
Function of one column of inputs. CasADi's own derivatives of the whole MX
graph colour it and sweep every colour through every interval; here each
interval function's derivatives are derived once, symbolically, mapped over
the columns and laid out block-diagonally (no copying: the mapped result has
the same nonzeros), then chained through the cheap outer expressions
(selections, scalings, differences, squares) that CasADi differentiates
directly. With V_b a block's outputs, W_b its inputs (affine in z):

    dg/dz = dg/dz|_V + sum_b dg/dV_b * blockdiag(J_b) * dW_b/dz

and, for the Lagrangian L = lam_f f + lam_g^T g = L_out(z, V),

    hess L = A^T hess L_out A + sum_b dW_b/dz^T blockdiag(hess (mu_b^T F_b)) dW_b/dz

with A = [I; dV/dz] and mu_b = dL_out/dV_b, each column's second derivatives
weighted by its own adjoint. The Gauss-Newton Hessian of a least-squares
objective sum |r|^2 + q is 2 J_r^T J_r + hess(q), the Hessian nonlinear
least-squares solvers use: it drops the blocks' curvature, which the dynamics
multipliers make small near a good fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import accumulate
from typing import Any

import casadi as ca

from crashnlp.numerics.runtime import mapped


def _block_diagonal(per_column: ca.MX, pattern: ca.Sparsity, n: int) -> ca.MX:
    """n per-column matrices of one pattern, side by side as a mapped call returns them, as one
    block-diagonal matrix (the same nonzeros: no copy)."""
    return ca.sparsity_cast(per_column, ca.kron(ca.DM.eye(n), ca.DM.ones(pattern)).sparsity())


def _used_elements(d_outer: ca.MX | None, m: int) -> list[int]:
    """The elements of one column's output (m of them, the same in every column) that a
    Jacobian with respect to the whole mapped output uses in any column."""
    return [] if d_outer is None else sorted({c % m for c in d_outer.sparsity().get_col()})


@dataclass
class MappedBlock:
    """One interval function mapped over n columns, as it appears in the NLP."""

    fn: ca.Function  # SX, one column
    n: int
    inputs: list[ca.MX]  # each (rows x cols * n), functions of the decision vector and parameters
    outputs: list[ca.MX]  # the mapped call's outputs
    threads: int | None = None  # as the NLP's own maps
    _dw: tuple[list[int], Any] | None = field(default=None, init=False, repr=False)
    _jacobians: dict[tuple, list[ca.MX]] = field(default_factory=dict, init=False, repr=False)

    def input_jacobian(self, z: ca.MX) -> tuple[list[int], Any]:
        """The rows of one column's inputs that depend on z ("live": the NLP's parameters, the
        fixed model values beside theta, would only add zero rows) and d(live rows of every
        column)/dz, constant in z: the transcriptions feed blocks with affine selections of z."""
        if self._dw is None:
            m = sum(s.numel() for s in self.fn.sx_in())
            stacked = ca.vertcat(*[ca.reshape(x, s.numel(), self.n) for x, s in zip(self.inputs, self.fn.sx_in())])
            dw: Any = ca.jacobian(ca.vec(stacked), z)
            if ca.depends_on(dw, z):
                raise ValueError(f"{self.fn.name()}: the inputs of a mapped block must be affine in the decision vector")
            live = sorted({r % m for r in dw.sparsity().row()})
            dw = dw[[c * m + r for c in range(self.n) for r in live], :]
            self._dw = (live, ca.evalf(dw) if not ca.symvar(dw) else dw)
        return self._dw

    def _column(self, name: str, z: ca.MX, derivative) -> ca.Function:
        """An SX Function of one column's inputs (and the extra symbols `derivative` adds) to the
        derivatives `derivative` takes with respect to the column's live inputs."""
        ins = self.fn.sx_in()
        live, _ = self.input_jacobian(z)
        w = ca.vertcat(*[ca.vec(i) for i in ins])[live]
        extra, outs = derivative(ins, w)
        return ca.Function(f"{self.fn.name()}_{name}", [*ins, *extra], outs)

    def _outputs(self, ins: list[ca.SX]) -> list[ca.SX]:
        """The interval function's outputs on one column's symbols."""
        return self.fn.call(ins)

    def jacobians(self, z: ca.MX, wanted: list[list[int]] | None = None) -> list[ca.MX]:
        """d vec(output)[wanted] / dz of every output, rows column by column: per-column
        Jacobians, block-diagonal, times dW/dz. `wanted[k]`: the elements of one column's
        vec(output k) asked for, the same in every column (all when None): a constraint on the
        crush needs one of the 14 outputs' rows, a fit its four channels. One mapped call per
        selection, shared by every derivative that asks for it (jac_g, the Hessians, the
        covariance's sensitivities), so the generated code holds each column function once."""
        wanted = wanted or [list(range(self.fn.numel_out(k))) for k in range(self.fn.n_out())]
        key = tuple(tuple(rows) for rows in wanted)
        if key not in self._jacobians:
            self._jacobians[key] = self._selected_jacobians(z, wanted)
        return self._jacobians[key]

    def _selected_jacobians(self, z: ca.MX, wanted: list[list[int]]) -> list[ca.MX]:
        _, dw = self.input_jacobian(z)
        asked = [k for k, rows in enumerate(wanted) if rows]
        if not asked:
            return [ca.MX(0, z.numel()) for _ in wanted]

        def jacobian(ins, w):
            outs = self._outputs(ins)
            return [], [ca.jacobian(ca.vec(outs[k])[wanted[k]], w) for k in asked]

        column = self._column("jac", z, jacobian)
        per_column = iter(mapped(column, self.n, self.threads).call(self.inputs))
        jacobians = [ca.MX(0, z.numel()) for _ in wanted]
        for i, k in enumerate(asked):
            jacobians[k] = ca.mtimes(_block_diagonal(next(per_column), column.sparsity_out(i), self.n), dw)
        return jacobians

    def curvature(self, z: ca.MX, adjoints: list[ca.MX]) -> ca.MX:
        """dW/dz^T blockdiag(hess_w sum_k <mu_k, F_k(w)>) dW/dz: the second derivatives of every
        column weighted by its outputs' adjoints mu_k (shaped as the outputs)."""
        _, dw = self.input_jacobian(z)

        def hessian(ins, w):
            mus = [ca.SX.sym(f"mu{k}", self.fn.sparsity_out(k)) for k in range(self.fn.n_out())]
            weighted = sum(ca.dot(mu, o) for mu, o in zip(mus, self._outputs(ins)))
            return mus, [ca.hessian(weighted, w)[0]]

        column = self._column("hess", z, hessian)
        (H,) = mapped(column, self.n, self.threads).call([*self.inputs, *adjoints])
        return ca.mtimes(dw.T, ca.mtimes(_block_diagonal(H, column.sparsity_out(0), self.n), dw))


class Derivatives:
    """Jacobians and Hessians of NLP expressions through the mapped blocks they contain."""

    def __init__(self, z: ca.MX, p: ca.MX, blocks: list[MappedBlock]):
        self.z, self.p = z, p
        self.values = [v for b in blocks for v in b.outputs]
        self.flat = [ca.MX.sym(f"V{i}", ca.vec(v).sparsity()) for i, v in enumerate(self.values)]
        self.symbols = [ca.reshape(s, v.size1(), v.size2()) for s, v in zip(self.flat, self.values)]
        self._blocks = blocks

    def _block_jacobians(self) -> list[ca.MX]:
        """Every row of every block output (each block keeps its own)."""
        return [J for b in self._blocks for J in b.jacobians(self.z)]

    def _outer(self, expr: ca.MX) -> ca.MX:
        """expr with the blocks' outputs replaced by symbols."""
        return ca.graph_substitute(expr, self.values, self.symbols)

    def _inner(self, expr: ca.MX) -> ca.MX:
        """The blocks' outputs put back into an expression of their symbols."""
        return ca.graph_substitute(expr, self.flat, [ca.vec(v) for v in self.values])

    def jacobian(self, expr: ca.MX, every_row: bool = False) -> ca.MX:
        """d expr / dz, the blocks' Jacobians chained in: of each block output, only the rows
        (elements of a column's output) that expr uses are differentiated and multiplied, or
        with `every_row` all rows of the outputs it uses (the same values, more structural zeros)."""
        outer = self._outer(expr)
        J = ca.jacobian(outer, self.z)
        flat = iter(self.flat)
        for block in self._blocks:
            syms = [next(flat) for _ in block.outputs]
            d_outer = [ca.jacobian(outer, s) if ca.depends_on(outer, s) else None for s in syms]
            sizes = [block.fn.numel_out(k) for k in range(len(syms))]
            wanted = [list(range(m)) if every_row and d is not None else _used_elements(d, m) for d, m in zip(d_outer, sizes)]
            for d, m, rows, dv in zip(d_outer, sizes, wanted, block.jacobians(self.z, wanted)):
                if d is not None and rows:
                    J = J + ca.mtimes(d[:, [j * m + e for j in range(block.n) for e in rows]], dv)
        return self._inner(J)

    def jac_g(self, g: ca.MX) -> ca.Function:
        """The constraint Jacobian in nlpsol's `jac_g` form."""
        return ca.Function("jac_g", [self.z, self.p], [g, self.jacobian(g)], ["x", "p"], ["g", "jac_g_x"])

    def hessian(self, f: ca.MX, g: ca.MX) -> ca.Function:
        """nlpsol's `hess_lag`, exact: the Hessian of lam_f f + lam_g^T g (see the module)."""
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.numel())
        outer = self._outer(lam_f * f + ca.dot(lam_g, g))
        y = ca.vertcat(self.z, *self.flat)
        H_out, grad = ca.hessian(outer, y)
        A = ca.vertcat(ca.MX(ca.DM.eye(self.z.numel())), *self._block_jacobians())
        H = ca.mtimes(A.T, ca.mtimes(H_out, A))
        sizes = [self.z.numel(), *(s.numel() for s in self.flat)]
        adjoints = iter(ca.vertsplit(grad, [0, *accumulate(sizes)])[1:])  # dL_out/dV, output by output
        for block in self._blocks:
            mus = [ca.reshape(next(adjoints), v.size1(), v.size2()) for v in block.outputs]
            H = H + block.curvature(self.z, mus)
        return self._hess_lag(self._inner(H), lam_f, lam_g)

    def gauss_newton(self, residuals: ca.MX, rest: ca.MX, ng: int) -> ca.Function:
        """nlpsol's `hess_lag` for f = |residuals|^2 + rest: lam_f (2 J^T J + hess(rest)). J has
        every row of the output blocks the residuals use: dropping the other outputs' rows gives
        the same values but a sparser Hessian, with which MUMPS pivots the near-singular KKT
        systems of joint fits otherwise and can fail where this one converges
        (docs/design-notes.md)."""
        J = self.jacobian(residuals, every_row=True)
        H = 2 * ca.mtimes(J.T, J) + ca.hessian(rest, self.z)[0]
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", ng)
        return self._hess_lag(lam_f * H, lam_f, lam_g)

    def _hess_lag(self, H: ca.MX, lam_f: ca.MX, lam_g: ca.MX) -> ca.Function:
        return ca.Function(
            "hess_lag",
            [self.z, self.p, lam_f, lam_g],
            [ca.triu(H)],
            ["x", "p", "lam_f", "lam_g"],
            ["triu_hess_gamma_x_x"],
        )
