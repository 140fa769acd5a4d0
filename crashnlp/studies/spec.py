"""The study file: a base problem and the entries to vary, checked before anything runs.

A sweep path is a dotted path into the problem file ("constraints.bounds.pitch",
"vehicle.mass", "tests.0.speed", "solver.ipopt.max_iter"); it must name an entry
the problem schema has, so a typo fails at once with one line instead of making
every case fail.
"""

import copy
import types
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Self, Union, get_args, get_origin

from crashnlp.base.errors import InputError
from crashnlp.base.records import Field, Record, ValidationError, model_validator
from crashnlp.base.units import to_si
from crashnlp.problem.errors import ProblemError, all_errors
from crashnlp.problem.load import read_yaml
from crashnlp.problem.schema import OUTPUT_UNITS, FolderName, Problem, problem_from_dict

Key = str | int


class StudySpec(Record):
    """What a study file may say."""

    name: FolderName
    problem: Path = Field(description="base problem file, relative to the study file")
    sweep: Mapping[str, Annotated[tuple[Any, ...], Field(min_length=1)]] = Field(
        min_length=1, description="dotted path into the problem -> the values it takes"
    )
    mode: Literal["grid", "zip"] = Field("grid", description="grid: all combinations; zip: the i-th values together")
    seeds: tuple[int, ...] | None = Field(
        None, description="case numbers (0-based) solved cold; default the corners of the grid (zip: both ends)"
    )
    max_depth: int | None = Field(
        None,
        ge=0,
        description="instead of seeds: cold seeds on a lattice, so that no case is more than this many warm starts "
        "from one (more cold solves, shorter chains of solves that must run one after another)",
    )

    @model_validator(mode="after")
    def _seeds_or_depth(self) -> Self:
        if self.seeds is not None and self.max_depth is not None:
            raise ValueError("give seeds or max_depth, not both")
        return self


@dataclass(frozen=True)
class SweepEntry:
    """One swept entry: its path as written, its keys into the raw problem, its values and SI unit."""

    path: str
    keys: tuple[Key, ...]
    values: tuple[Any, ...]
    unit: str | None

    def si(self, value: Any) -> float:
        """A number to plot a value against: SI, the non-null end of a half-open bound; NaN if none."""
        if isinstance(value, (list, tuple)):
            ends = [v for v in value if v is not None]
            value = ends[0] if len(ends) == 1 else None
        if value is None or isinstance(value, bool):
            return float("nan")
        try:
            return to_si(value, self.unit or "") if isinstance(value, str) else float(value)
        except (ValueError, TypeError):
            return float("nan")


@dataclass(frozen=True)
class Study:
    """A validated study: the raw base problem (a dict) and the sweep entries."""

    name: str
    source: Path
    base: dict[str, Any]
    base_dir: Path
    problem_source: str
    entries: tuple[SweepEntry, ...]
    mode: str
    seeds: tuple[int, ...] | None
    max_depth: int | None = None


def load_study(path: str | Path) -> Study:
    """Read and check a study file; every problem with it is an InputError naming the file and key."""
    path = Path(path)
    raw = read_yaml(path, "a study file (YAML)")
    if not isinstance(raw, dict):
        raise InputError(f"{path}: expected a mapping at the top level")
    try:
        spec = StudySpec.model_validate(raw)
    except ValidationError as exc:
        raise InputError(f"{path}: {all_errors(exc)}") from None
    problem_path = spec.problem if spec.problem.is_absolute() else path.resolve().parent / spec.problem
    if not problem_path.is_file():
        raise InputError(f"{path}: problem: file not found: {problem_path}")
    try:
        base = read_yaml(problem_path)
        problem = problem_from_dict(base, problem_path.parent, source=str(problem_path))
    except ProblemError as exc:
        raise InputError(f"{path}: problem: {exc}") from None
    entries = tuple(_entry(path, p, v, base, problem) for p, v in spec.sweep.items())
    if spec.mode == "zip" and len({len(e.values) for e in entries}) > 1:
        lengths = ", ".join(f"{e.path}: {len(e.values)}" for e in entries)
        raise InputError(f"{path}: sweep: zip mode needs lists of the same length ({lengths})")
    return Study(
        spec.name,
        path,
        base,
        problem_path.parent,
        str(problem_path),
        entries,
        spec.mode,
        tuple(spec.seeds) if spec.seeds is not None else None,
        spec.max_depth,
    )


def _entry(source: Path, path: str, values: tuple[Any, ...], base: dict, problem: Problem) -> SweepEntry:
    keys = resolve_path(path, base)
    if keys is None:
        raise InputError(f"{source}: sweep.{path}: not an entry of the problem schema")
    return SweepEntry(path, keys, tuple(values), _unit(keys, problem))


def _unit(keys: tuple[Key, ...], problem: Problem) -> str | None:
    if len(keys) == 3 and keys[:2] == ("constraints", "bounds"):
        return OUTPUT_UNITS[str(keys[2])]
    return problem.quantity_unit(".".join(map(str, keys)))


def resolve_path(path: str, raw: dict) -> tuple[Key, ...] | None:
    """Keys into the raw problem for a dotted path, or None if the schema has no such entry.

    A mapping with free keys (estimate, solver.ipopt) may take several segments
    as one key (estimate keys contain dots): a key the base problem already has
    wins, else the shortest run after which the rest of the path still resolves.
    """
    keys = _resolve(Problem, path.split("."), raw)
    return None if keys is None else tuple(keys)


def _resolve(tp: Any, parts: list[str], node: Any) -> list[Key] | None:
    if not parts:
        return []
    tp = _unwrap(tp)
    origin = get_origin(tp)
    runs = [1]
    if origin in (dict, Mapping) and get_args(tp)[0] is str:
        present = [n for n in range(len(parts), 0, -1) if isinstance(node, dict) and ".".join(parts[:n]) in node]
        runs = present + [n for n in range(1, len(parts) + 1) if n not in present]
    for n in runs:
        name = ".".join(parts[:n])
        child = _child(tp, name)
        if child is None:
            continue
        key: Key = int(name) if origin in (list, tuple) else name
        rest = _resolve(child, parts[n:], _get(node, key))
        if rest is not None:
            return [key, *rest]
    return None


def _get(node: Any, key: Key) -> Any:
    if isinstance(node, dict):
        return node.get(key)
    if isinstance(node, list) and isinstance(key, int) and key < len(node):
        return node[key]
    return None


def _unwrap(tp: Any) -> Any:
    """Strip Annotated and Optional; a union of models stays a union."""
    while get_origin(tp) is Annotated:
        tp = get_args(tp)[0]
    if get_origin(tp) in (Union, types.UnionType):
        args = [a for a in get_args(tp) if a is not type(None)]
        return _unwrap(args[0]) if len(args) == 1 else tp
    return tp


def _child(tp: Any, key: str) -> Any:
    """Type of entry `key` inside type `tp`, or None if it has none."""
    origin = get_origin(tp)
    if origin in (Union, types.UnionType):
        found = [c for c in (_child(_unwrap(a), key) for a in get_args(tp)) if c is not None]
        return found[0] if found else None
    if isinstance(tp, type) and issubclass(tp, Record):
        info = tp.model_fields.get(key)
        return None if info is None or info.exclude else info.annotation
    if origin in (dict, Mapping):
        k, v = get_args(tp)
        allowed = get_args(_unwrap(k)) if get_origin(_unwrap(k)) is Literal else None
        return v if allowed is None or key in allowed else None
    if origin in (list, tuple) and key.isdigit():
        args = get_args(tp)
        if origin is tuple and args and args[-1] is not Ellipsis:
            return args[int(key)] if int(key) < len(args) else None
        return args[0] if args else Any
    return None


def set_path(raw: dict, keys: tuple[Key, ...], value: Any) -> None:
    """Replace the entry at `keys` in a raw problem, creating mappings on the way. Each list or
    mapping on the way is replaced by a copy of its own first: a file's alias may give one value
    to several places (a two-test problem's shared channels), and the change is this place's."""
    node: Any = raw
    for key in keys[:-1]:
        if isinstance(node, dict):
            child = node.get(key)
            node[key] = copy.copy(child) if isinstance(child, (dict, list)) else {}
            node = node[key]
        elif isinstance(node, list) and isinstance(key, int) and key < len(node):
            if isinstance(node[key], (dict, list)):
                node[key] = copy.copy(node[key])
            node = node[key]
        else:
            raise InputError(f"{'.'.join(map(str, keys))}: the problem has no entry {key!r} to change")
    if isinstance(node, list) and isinstance(keys[-1], int) and keys[-1] >= len(node):
        raise InputError(f"{'.'.join(map(str, keys))}: index past the end of the list")
    node[keys[-1]] = copy.deepcopy(value)
