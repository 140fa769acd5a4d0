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


def with_parameters(problem: Problem, params: Mapping[str, Any], source: str) -> Problem:
    """`problem` with `params` (dotted path -> value, as a result.json's "parameters" holds them)
    in place of its values. An InputError naming `source` and the key refuses a path that is no
    numeric entry of the problem, a list of another length than the problem's entry (the result
    comes from another problem), and whatever the schema refuses of the values (not finite,
    beyond any physical value, not a number)."""
    for path, value in params.items():
        try:
            problem.unit_at(path)
        except ValueError:
            raise InputError(f"{source}: parameters.{path}: not a parameter of {problem.name}") from None
        current = problem.value_at(path)
        size, given = (
            (len(current) if isinstance(current, tuple) else 1),
            (len(value) if isinstance(value, (list, tuple, np.ndarray)) else 1),
        )
        if given != size:
            raise InputError(
                f"{source}: parameters.{path}: {given} values, but {problem.name} has {size} "
                f"(length mismatch: the result comes from another problem)"
            )
    try:
        return problem.with_values(dict(params))
    except KeyError as exc:
        raise InputError(f"{source}: parameters.{exc.args[0]}: not a parameter of {problem.name}") from None
    except InputError as exc:
        raise InputError(f"{source}: {str(exc).removeprefix('with_values: ')}") from None
