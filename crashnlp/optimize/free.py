"""Free parameters: the `estimate` entries of a problem as one scaled vector theta."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.models.parameters import ParameterLayout
from crashnlp.problem.schema import EstimateSpec


@dataclass(frozen=True)
class FreeEntry:
    path: str
    where: slice  # in the full parameter vector
    at: slice  # in theta
    initial: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    scale: np.ndarray


class FreeParameters:
    """Maps theta (the estimated entries) into the full parameter vector."""

    def __init__(self, layout: ParameterLayout, base: np.ndarray, estimate: Mapping[str, EstimateSpec]):
        self.layout, self.base = layout, np.asarray(base, dtype=float)
        self.entries: list[FreeEntry] = []
        i = 0
        for path, spec in estimate.items():
            try:
                where = layout.index(path)
            except KeyError:
                raise InputError(f"estimate.{path}: not a parameter of the model") from None
            n = where.stop - where.start
            initial = self._initial(path, spec, base[where], n)
            lo, hi = spec.bounds if spec.bounds is not None else (None, None)
            lower = np.full(n, -np.inf if lo is None else lo)
            upper = np.full(n, np.inf if hi is None else hi)
            if np.any(lower > upper):
                raise InputError(f"estimate.{path}.bounds: lower bound above upper bound")
            if np.any(initial < lower) or np.any(initial > upper):
                initial = np.clip(initial, lower, upper)
            self.entries.append(
                FreeEntry(path, where, slice(i, i + n), initial, lower, upper, self._scale(spec, initial, lower, upper))
            )
            i += n
        self.size = i

    @staticmethod
    def _initial(path: str, spec: EstimateSpec, current: np.ndarray, n: int) -> np.ndarray:
        if spec.initial is None:
            return np.array(current, dtype=float)
        value = np.atleast_1d(np.asarray(spec.initial, dtype=float))
        if value.size not in (1, n):
            raise InputError(f"estimate.{path}.initial: {value.size} values for an entry of size {n}")
        return np.broadcast_to(value, (n,)).copy()

    @staticmethod
    def _scale(spec: EstimateSpec, initial, lower, upper) -> np.ndarray:
        if spec.prior_scale is not None:
            return np.full(initial.shape, abs(float(spec.prior_scale)))  # SI once validated
        finite = [np.abs(b) for b in (lower, upper) if np.all(np.isfinite(b))]
        cands = np.max(np.vstack([np.abs(initial), *finite]), axis=0)
        return np.where(cands > 0, np.max(cands) * np.ones_like(cands), 1.0)

    def _cat(self, field: str) -> np.ndarray:
        return np.concatenate([getattr(e, field) for e in self.entries]) if self.entries else np.zeros(0)

    @property
    def initial(self) -> np.ndarray:
        return self._cat("initial")

    @property
    def lower(self) -> np.ndarray:
        return self._cat("lower")

    @property
    def upper(self) -> np.ndarray:
        return self._cat("upper")

    @property
    def scale(self) -> np.ndarray:
        return self._cat("scale")

    def labels(self) -> list[str]:
        return [
            e.path if e.at.stop - e.at.start == 1 else f"{e.path}[{k}]"
            for e in self.entries
            for k in range(e.at.stop - e.at.start)
        ]

    def full(self, theta, overrides: dict[str, float] | None = None, fixed=None):
        """Full parameter vector with theta in place (symbolic SX or MX, or numeric).

        Symbolic, the other entries are `fixed` (a symbolic full vector holding the fixed
        values, overrides included) or, without it, the base values as constants."""
        if isinstance(theta, (ca.SX, ca.MX)):
            base: Any = type(theta)(ca.DM(self.base)) if fixed is None else fixed
            symbolic = type(theta)(base)  # a copy: assigning into it leaves `fixed` as it is
            for e in self.entries:
                symbolic[e.where] = theta[e.at]
            for path, value in (overrides or {}).items():
                where = self.layout.index(path)
                symbolic[where] = value if fixed is None else base[where]
            return symbolic
        numeric = self.base.copy()
        for e in self.entries:
            numeric[e.where] = np.asarray(theta)[e.at]
        return self.layout.with_values(numeric, overrides or {})

    def named(self, theta: np.ndarray) -> dict[str, float | list[float]]:
        """Estimated values keyed as in `estimate` (SI)."""
        out = {}
        for e in self.entries:
            v = np.asarray(theta)[e.at]
            out[e.path] = float(v[0]) if e.where.stop - e.where.start == 1 else [float(x) for x in v]
        return out
