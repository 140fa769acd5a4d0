"""The parameter vector: every numeric entry of `vehicle` and `model`, by dotted path.

The symbolic model takes all of them as one input vector, so any entry can be
estimated, swept or fixed without rebuilding the model's functions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from crashnlp.base.records import Record
from crashnlp.problem.schema import Problem, Strict

ROOTS = ("vehicle", "model")


def _walk(node: Record, prefix: str):
    for name in type(node).model_fields:
        value = getattr(node, name)
        path = f"{prefix}.{name}"
        if isinstance(value, Record):
            yield from _walk(value, path)
        elif isinstance(node, Strict) and node.unit_of(name) is not None and value is not None:
            if isinstance(value, tuple) or isinstance(value, (int, float)) and not isinstance(value, bool):
                yield path, value


@dataclass(frozen=True)
class ParameterLayout:
    """Ordered (path, size) entries of the full parameter vector."""

    entries: tuple[tuple[str, int], ...]

    @classmethod
    def of(cls, problem: Problem) -> ParameterLayout:
        return cls(tuple((p, np.size(v)) for root in ROOTS for p, v in _walk(getattr(problem, root), root)))

    @property
    def size(self) -> int:
        return sum(n for _, n in self.entries)

    def slices(self) -> dict[str, slice]:
        out, i = {}, 0
        for path, n in self.entries:
            out[path] = slice(i, i + n)
            i += n
        return out

    def split(self, vec: Any) -> dict[str, Any]:
        """Named pieces of a parameter vector (numeric or symbolic)."""
        return {path: vec[s] for path, s in self.slices().items()}

    def values(self, problem: Problem) -> np.ndarray:
        """The problem's own values, in layout order."""
        found = dict(p for root in ROOTS for p in _walk(getattr(problem, root), root))
        return np.concatenate([np.atleast_1d(np.asarray(found[p], dtype=float)) for p, _ in self.entries])

    def index(self, path: str) -> slice:
        try:
            return self.slices()[path]
        except KeyError:
            raise KeyError(path) from None

    def with_values(self, base: np.ndarray, named: dict[str, Any]) -> np.ndarray:
        """Copy of `base` with named entries replaced (e.g. identified parameters)."""
        out = np.array(base, dtype=float)
        for path, value in named.items():
            out[self.index(path)] = np.asarray(value, dtype=float)
        return out
