"""Read a YAML problem file into a validated `Problem`; bad input becomes one line."""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from crashnlp.errors import InputError
from crashnlp.problem.schema import Problem


class ProblemError(InputError):
    """Bad input: the message is the one line the user sees (exit status 2)."""


def _loc(loc: tuple) -> str:
    return ".".join(str(p) for p in loc if p not in ("function-after", "function-before"))


def first_error(exc: ValidationError) -> str:
    err = exc.errors()[0]
    msg = err["msg"].removeprefix("Value error, ")
    loc = _loc(err["loc"])
    if err["type"] == "extra_forbidden":
        msg = "unknown key"
    elif err["type"] == "missing":
        msg = "missing key"
    return f"{loc}: {msg}" if loc else msg


def problem_from_dict(raw: dict[str, Any], base_dir: Path, source: str = "problem") -> Problem:
    """Validate a problem given as a plain dict (paths relative to `base_dir`)."""
    if not isinstance(raw, dict):
        raise ProblemError(f"{source}: expected a mapping at the top level")
    try:
        problem = Problem.model_validate(copy.deepcopy(raw), context={"base_dir": base_dir})
    except ValidationError as exc:
        raise ProblemError(f"{source}: {first_error(exc)}") from None
    problem.base_dir = base_dir
    return problem


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Parse a YAML file, turning every read or syntax failure into a ProblemError."""
    path = Path(path)
    if not path.is_file():
        raise ProblemError(f"{path}: file not found")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark else ""
        raise ProblemError(f"{path}:{where} not valid YAML") from None
    return raw


def load_problem(path: str | Path) -> Problem:
    """Load and validate a problem file."""
    path = Path(path)
    return problem_from_dict(read_yaml(path), path.resolve().parent, source=str(path))
