"""A problem with a fit's parameters in place of its values: the one check of
`crashnlp simulate --params` and `crashnlp.simulate(params=...)`, so that both refuse the same
parameters with the same line.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.problem.schema import Problem

VALUES, BREAKPOINTS = "model.spring.values", "model.spring.crush_breakpoints"


def with_parameters(problem: Problem, params: Mapping[str, Any], source: str) -> Problem:
    """`problem` with `params` (dotted path -> value, as a result.json's "parameters" holds them)
    in place of its values. An InputError naming `source` and the key refuses a path that is no
    numeric entry of the problem, a list of another length than the problem's entry (the result
    comes from another problem), spring values without the crush breakpoints they stand at (a
    problem that leaves its breakpoints to the data: `_refuse_values_alone`), and whatever the
    schema refuses of the values (not finite, beyond any physical value, not a number)."""
    for path, value in params.items():
        try:
            problem.unit_at(path)
        except ValueError:
            raise InputError(f"{source}: parameters.{path}: not a parameter of {problem.name}") from None
        size, given = _size(problem.value_at(path)), (len(value) if isinstance(value, (list, tuple, np.ndarray)) else 1)
        if size is not None and given != size:
            raise InputError(
                f"{source}: parameters.{path}: {given} values, but {problem.name} has {size} "
                f"(length mismatch: the result comes from another problem)"
            )
    _refuse_values_alone(problem, params, source)
    try:
        return problem.with_values(dict(params))
    except InputError as exc:
        raise InputError(f"{source}: {str(exc).removeprefix('with_values: ')}") from None


def _size(current: Any) -> int | None:
    """How many values a problem's entry holds: a list's length, 1 for a number; None for an entry
    it leaves to the data (none, or a count of breakpoints), whose size nothing fixes yet."""
    if isinstance(current, (list, tuple)):  # a loaded problem's lists are tuples (frozen)
        return len(current)
    return 1 if isinstance(current, (int, float)) else None


def _refuse_values_alone(problem: Problem, params: Mapping[str, Any], source: str) -> None:
    """Refuse spring values for a problem that leaves its crush breakpoints to the data (none, or
    a count) where `params` does not give the breakpoints either: nothing says where the values
    stand. A fit's identified vehicle carries them, and `crashnlp.simulate(params=result)` (or its
    result.json) puts them in (crashnlp.results.identified.apply)."""
    if VALUES in params and BREAKPOINTS not in params and not isinstance(problem.value_at(BREAKPOINTS), (list, tuple)):
        raise InputError(
            f"{source}: parameters.{VALUES}: {problem.name} leaves its crush breakpoints to the data, and these values "
            f"come without them; give the fit's Result or its result.json with the identified vehicle, which carries "
            f"them, or {BREAKPOINTS} with the values"
        )
