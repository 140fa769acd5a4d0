"""A small NLP assembler over CasADi MX: scaled decision variables, named constraints.

Decision variables are stored scaled to order one (x = offset + scale * z), so
IPOPT sees well-conditioned variables whatever the units. Interval functions
enter through `mapped`, least-squares terms through `least_squares`, so that
the derivatives can exploit both (crashnlp.derivatives).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from crashnlp.derivatives import Derivatives, MappedBlock
from crashnlp.runtime import mapped

SUCCESS = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


def _fill(value, shape: tuple[int, int]) -> np.ndarray:
    """A value broadcast to `shape`, flattened column-major as CasADi stores it."""
    a = np.asarray(value, dtype=float)
    if a.ndim == 1 and shape[1] == 1 and a.size == shape[0]:
        a = a[:, None]
    return np.broadcast_to(a, shape).ravel(order="F")


@dataclass
class Block:
    name: str
    shape: tuple[int, int]
    offset: int
    scale: np.ndarray


DYNAMICS = "dynamics"  # the kind of the transcription's equality constraints
NOT_REPORTED = (DYNAMICS, "l1")  # kinds that are part of the formulation, not the user's constraints


@dataclass(frozen=True)
class ConstraintBlock:
    """A block of constraints, typed: its kind, its test (None when shared) and what it is."""

    kind: str
    test: str | None
    detail: str
    start: int
    size: int

    @property
    def name(self) -> str:
        return ".".join(part for part in (self.test, self.kind, self.detail) if part)

    @property
    def local(self) -> str:
        """The name without the test: what a problem file's constraint entry says."""
        return ".".join(part for part in (self.kind, self.detail) if part)


@dataclass
class NLPBuilder:
    """Collects variables, constraints and an objective, then builds nlpsol."""

    z: list[ca.MX] = field(default_factory=list)
    lbz: list[np.ndarray] = field(default_factory=list)
    ubz: list[np.ndarray] = field(default_factory=list)
    z0: list[np.ndarray] = field(default_factory=list)
    g: list[ca.MX] = field(default_factory=list)
    lbg: list[np.ndarray] = field(default_factory=list)
    ubg: list[np.ndarray] = field(default_factory=list)
    blocks: dict[str, Block] = field(default_factory=dict)
    constraints: list[ConstraintBlock] = field(default_factory=list)
    mapped_blocks: list[MappedBlock] = field(default_factory=list)
    squares: list[ca.MX] = field(default_factory=list)  # least-squares residuals
    rest: ca.MX = field(default_factory=lambda: ca.MX(0))  # the other objective terms
    _derivatives: tuple[int, Derivatives] | None = field(default=None, init=False, repr=False)
    _nz: int = 0
    _ng: int = 0

    def variable(self, name, shape, init, lb=-np.inf, ub=np.inf, scale=1.0) -> ca.MX:
        """A block of decision variables; returns its unscaled expression."""
        shape = (shape, 1) if isinstance(shape, int) else shape
        n = shape[0] * shape[1]
        full = lambda v: _fill(v, shape)
        scale = full(scale)
        raw = ca.MX.sym(name, n)
        self.z.append(raw)
        self.lbz.append(full(lb) / scale)
        self.ubz.append(full(ub) / scale)
        self.z0.append(full(init) / scale)
        self.blocks[name] = Block(name, shape, self._nz, scale)
        self._nz += n
        return ca.reshape(raw * ca.DM(scale), shape[0], shape[1])

    def constrain(self, kind: str, expr, lb=0.0, ub=0.0, test: str | None = None, detail: str = "") -> None:
        """lb <= expr <= ub elementwise (bounds broadcast), as a block of `kind` for `test`."""
        expr = ca.vec(expr)
        n = expr.numel()
        if n == 0:
            return
        self.g.append(expr)
        self.lbg.append(np.broadcast_to(np.asarray(lb, dtype=float), (n,)).copy())
        self.ubg.append(np.broadcast_to(np.asarray(ub, dtype=float), (n,)).copy())
        self.constraints.append(ConstraintBlock(kind, test, detail, self._ng, n))
        self._ng += n

    def mapped(self, fn: ca.Function, n: int, *inputs) -> list[ca.MX]:
        """fn (an SX Function of one column) over n columns; inputs of one column's size are repeated."""
        full = [x if x.size2() == n * fn.size2_in(i) else ca.repmat(x, 1, n) for i, x in enumerate(map(ca.MX, inputs))]
        outputs = mapped(fn, n).call(full)
        self.mapped_blocks.append(MappedBlock(fn, n, full, outputs))
        return outputs

    def minimize(self, term) -> None:
        self.rest = self.rest + term

    def least_squares(self, residuals: ca.MX) -> None:
        """Minimize the sum of squares of `residuals` (kept apart for the Gauss-Newton Hessian)."""
        self.squares.append(ca.vec(residuals))

    @property
    def residuals(self) -> ca.MX:
        return ca.vertcat(*self.squares) if self.squares else ca.MX(0, 1)

    @property
    def objective(self) -> ca.MX:
        return ca.sumsqr(self.residuals) + self.rest

    @property
    def decision(self) -> ca.MX:
        return ca.vertcat(*self.z)

    def problem(self) -> dict:
        return {"x": self.decision, "f": self.objective, "g": ca.vertcat(*self.g) if self.g else ca.MX(0, 1)}

    def derivatives(self) -> Derivatives:
        """Structured derivatives of this NLP, built once for its current blocks."""
        if self._derivatives is None or self._derivatives[0] != len(self.mapped_blocks):
            self._derivatives = (len(self.mapped_blocks), Derivatives(self.decision, self.mapped_blocks))
        return self._derivatives[1]

    def bounds(self) -> dict[str, np.ndarray]:
        cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0)
        return {"lbx": cat(self.lbz), "ubx": cat(self.ubz), "x0": cat(self.z0), "lbg": cat(self.lbg), "ubg": cat(self.ubg)}

    def value(self, name: str, z: np.ndarray) -> np.ndarray:
        """Unscaled value of a variable block from a solution vector."""
        b = self.blocks[name]
        n = b.shape[0] * b.shape[1]
        return (np.asarray(z).ravel()[b.offset : b.offset + n] * b.scale).reshape(b.shape, order="F")
