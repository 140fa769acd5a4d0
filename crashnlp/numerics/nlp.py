"""A small NLP assembler over CasADi MX: scaled decision variables, named constraints.

Decision variables are stored scaled to order one (x = scale * z), so IPOPT
sees well-conditioned variables whatever the units. Interval functions enter
through `mapped`, least-squares terms through `least_squares`, so that the
derivatives can exploit both (crashnlp.numerics.derivatives).

Every number that may change between two solves of the same shape (data,
fixed model values, scales) enters as an NLP parameter, not as a constant of
the graph: the NLP's functions then depend only on the problem's structure,
and one compiled solver serves every run and every study case of that shape
(crashnlp.optimize.oracle).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from crashnlp.numerics.derivatives import Derivatives, MappedBlock
from crashnlp.numerics.runtime import mapped

ACCEPTABLE = "Solved_To_Acceptable_Level"  # IPOPT stopped at its acceptable level (solve.STEADY_OPTIONS, SETTLE_OPTIONS)
SUCCESS = ("Solve_Succeeded", ACCEPTABLE)


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
    parameters: list[ca.MX] = field(default_factory=list)
    parameter_values: list[np.ndarray] = field(default_factory=list)
    squares: list[ca.MX] = field(default_factory=list)  # least-squares residuals
    rest: ca.MX = field(default_factory=lambda: ca.MX(0))  # the other objective terms
    threads: int | None = None  # for the mapped interval functions (None: runtime.map_threads(); 1 when compiled)
    symbolic: bool = True  # the numbers given to `parameter` as parameters (else constants)
    # IPOPT options a solve of this NLP with the Gauss-Newton Hessian needs (its transcription's)
    gauss_newton_options: dict[str, Any] = field(default_factory=dict)
    # Functions of (x, p) the caller evaluates after the solve, compiled with the solver's
    # (crashnlp.optimize.oracle); `functions` holds them all, as the last solve had them
    extras: dict[str, Callable[[], ca.Function]] = field(default_factory=dict)
    functions: dict[str, ca.Function] = field(default_factory=dict)
    _derivatives: tuple[int, Derivatives] | None = field(default=None, init=False, repr=False)
    _key: tuple[tuple, str] | None = field(default=None, init=False, repr=False)
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
        return ca.reshape(raw * self.parameter(f"{name}.scale", scale), shape[0], shape[1])

    def parameter(self, name: str, value) -> ca.MX:
        """A named number of the problem (a scalar, vector or matrix), symbolic in the NLP:
        its value is passed at every solve, so it may change without changing the NLP.
        A constant of the graph instead when the NLP is not `symbolic`."""
        a = np.asarray(value, dtype=float)
        rows, cols = (a.shape + (1, 1))[:2] if a.ndim <= 2 else (a.size, 1)
        if not self.symbolic:
            return ca.MX(ca.DM(a.reshape(rows, cols)))
        symbol = ca.MX.sym(name, rows, cols)
        self.parameters.append(symbol)
        self.parameter_values.append(a.reshape(rows, cols).ravel(order="F"))
        return symbol

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
        outputs = mapped(fn, n, self.threads).call(full)
        self.mapped_blocks.append(MappedBlock(fn, n, full, outputs, self.threads))
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

    @property
    def p(self) -> ca.MX:
        """All parameters as one column (the NLP's `p`)."""
        return ca.vertcat(*[ca.vec(s) for s in self.parameters]) if self.parameters else ca.MX(0, 1)

    def problem(self) -> dict:
        g = ca.vertcat(*self.g) if self.g else ca.MX(0, 1)
        return {"x": self.decision, "p": self.p, "f": self.objective, "g": g}

    def function(self, name: str, outputs: list[ca.MX], names: list[str] | None = None) -> ca.Function:
        """A Function (x, p) -> outputs of expressions of this NLP."""
        names = names or [f"o{i}" for i in range(len(outputs))]
        return ca.Function(name, [self.decision, self.p], outputs, ["x", "p"], names)

    def key(self) -> str:
        """A hash of the NLP's structure: its f and g as functions of (x, p), serialized (and
        CasADi's version). Equal keys, equal functions: the numbers are all in p. Asked for
        once the NLP is complete (it is recomputed when blocks are added, not terms)."""
        size = (len(self.z), len(self.g), len(self.squares), len(self.parameters))
        if self._key is None or self._key[0] != size:
            problem = self.problem()
            text = self.function("nlp", [problem["f"], problem["g"]]).serialize() + ca.CasadiMeta.version()
            self._key = (size, hashlib.sha256(text.encode()).hexdigest()[:20])
        return self._key[1]

    def evaluate(self, outputs: list[ca.MX], z: np.ndarray) -> list[ca.DM]:
        """Expressions of this NLP at a solution vector (with its parameter values)."""
        return self.function("evaluate", outputs).call([z, self.bounds()["p"]])

    def derivatives(self) -> Derivatives:
        """Structured derivatives of this NLP, built once for its current blocks."""
        if self._derivatives is None or self._derivatives[0] != len(self.mapped_blocks):
            self._derivatives = (len(self.mapped_blocks), Derivatives(self.decision, self.p, self.mapped_blocks))
        return self._derivatives[1]

    def bounds(self) -> dict[str, np.ndarray]:
        """Numeric arguments of a solve: bounds, initial guess and parameter values."""
        cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0)
        return {
            "lbx": cat(self.lbz),
            "ubx": cat(self.ubz),
            "x0": cat(self.z0),
            "lbg": cat(self.lbg),
            "ubg": cat(self.ubg),
            "p": cat(self.parameter_values),
        }

    def value(self, name: str, z: np.ndarray) -> np.ndarray:
        """Unscaled value of a variable block from a solution vector."""
        b = self.blocks[name]
        n = b.shape[0] * b.shape[1]
        return (np.asarray(z).ravel()[b.offset : b.offset + n] * b.scale).reshape(b.shape, order="F")
