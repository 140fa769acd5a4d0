"""The cases of a study and the warm-start plan, fixed from the case list alone.

Seed cases (by default the corners of the grid) are solved cold. Every other
case warm-starts from a parent: a case next to it (Chebyshev distance 1 in
grid-index space) one step closer to the nearest seed, the nearest such
(Euclidean in index space), ties to the lower case number. A case's depth, its
number of warm starts from a seed, is its Chebyshev distance to the nearest seed.
A case runs as soon as its parent is solved (crashnlp.engine.schedule), so one
slow case holds up only the cases planned from it.

Identical tables or full parallelism: a plan that adapted to the run (a seed
per worker, or a warm start from whichever neighbour is solved first) would keep
every worker busy from the start, but its table would change with the worker
count and the timing. This plan never adapts: every executor and worker count
gives the same table. The parallelism it offers is set by the study file
instead: the seeds are what can run at first, and the depth is the longest
chain of solves that must run one after another. On a grid of two or more
swept entries the corners leave short chains (a 4 x 4 grid: depth 1; 100 x 100:
depth 49); a long single sweep does not (1,000 values: depth 499). `max_depth`
spreads seeds on a lattice so that no case is more than that many warm starts
from one: more cold solves (each costs several warm ones), shorter chains.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from crashnlp.base import VERSION
from crashnlp.base.cache import files_digest, installed_version
from crashnlp.base.errors import InputError
from crashnlp.numerics import compile_job
from crashnlp.studies.spec import Study, set_path


@dataclass(frozen=True)
class PlannedCase:
    """One case: where it sits in the grid, its swept values, its parent and depth."""

    number: int
    index: tuple[int, ...]
    values: tuple[Any, ...]  # one per sweep entry, as the user wrote it
    parent: int | None
    depth: int

    @property
    def id(self) -> str:
        return case_id(self.number)


MAX_CASES = 10_000  # a grid larger than this is a mistake, not a study


def case_id(number: int) -> str:
    """File and table name of a case."""
    return f"case-{number:03d}"


def grid_shape(study: Study) -> tuple[int, ...]:
    """Values per swept entry (zip: one axis); refuse more than MAX_CASES cases."""
    if study.mode == "zip":
        return (len(study.entries[0].values),)
    shape = tuple(len(e.values) for e in study.entries)
    if math.prod(shape) > MAX_CASES:
        raise InputError(f"{study.source}: sweep: {math.prod(shape):,} cases in the grid, more than {MAX_CASES:,}")
    return shape


def case_indices(study: Study) -> list[tuple[int, ...]]:
    """Grid index of every case, in case order (the case number is the C-order position in the grid)."""
    return list(itertools.product(*(range(n) for n in grid_shape(study))))


def corners(shape: tuple[int, ...]) -> list[int]:
    """Case numbers at the corners of the grid (both ends of a line)."""
    ends = itertools.product(*[sorted({0, n - 1}) for n in shape])
    return sorted(int(np.ravel_multi_index(ix, shape)) for ix in ends)


def lattice(shape: tuple[int, ...], depth: int) -> list[int]:
    """Case numbers on a lattice that leaves no case more than `depth` from one: in each axis,
    the middles of blocks of 2 depth + 1 values (the last block's clipped to the end)."""
    axes = [sorted({min(depth + k * (2 * depth + 1), n - 1) for k in range(math.ceil(n / (2 * depth + 1)))}) for n in shape]
    return sorted(int(np.ravel_multi_index(ix, shape)) for ix in itertools.product(*axes))


def depths(shape: tuple[int, ...], seeds: list[int]) -> np.ndarray:
    """Chebyshev distance in index space from every case to its nearest seed. The min over seeds of
    the largest index difference separates by axes: f <- min_y max(|x - y|, f(y)) along each axis
    in turn, starting from 0 at the seeds (cases x axis lengths, not cases x seeds)."""
    far = max(shape)  # more than any distance in the grid
    depth = np.full(math.prod(shape), far)
    depth[seeds] = 0
    depth = depth.reshape(shape)
    for axis in range(len(shape)):
        depth = _along(depth, axis)
    return depth.ravel()


def _along(f: np.ndarray, axis: int) -> np.ndarray:
    """g(x) = min_y max(|x - y|, f(y)) along `axis`; a shift s can lower only values above s."""
    g = f.copy()
    fa, ga = np.moveaxis(f, axis, 0), np.moveaxis(g, axis, 0)
    for s in range(1, fa.shape[0]):
        if s >= ga.max():
            break
        ga[s:] = np.minimum(ga[s:], np.maximum(s, fa[:-s]))
        ga[:-s] = np.minimum(ga[:-s], np.maximum(s, fa[s:]))
    return g


def _offsets(shape: tuple[int, ...]) -> Iterator[np.ndarray]:
    """Steps to a neighbour (each index by -1, 0 or +1): fewest changed indices first, then in the
    order of the neighbour's case number."""
    strides = np.array([math.prod(shape[i + 1 :]) for i in range(len(shape))])
    axes = [i for i, n in enumerate(shape) if n > 1]
    for count in range(1, len(axes) + 1):
        steps = []
        for chosen in itertools.combinations(axes, count):
            for signs in itertools.product((-1, 1), repeat=count):
                step = np.zeros(len(shape), dtype=int)
                step[list(chosen)] = signs
                steps.append(step)
        yield from sorted(steps, key=lambda s: int(s @ strides))


def parents(shape: tuple[int, ...], depth: np.ndarray) -> list[int | None]:
    """The parent of every case (see the module docstring); None for the seeds (depth 0)."""
    points = np.indices(shape).reshape(len(shape), -1).T
    parent = np.full(len(points), -1)
    for step in _offsets(shape):
        todo = np.flatnonzero((parent < 0) & (depth > 0))
        if not todo.size:
            break
        near = points[todo] + step
        inside = np.all((near >= 0) & (near < shape), axis=1)
        todo, near = todo[inside], np.ravel_multi_index(tuple(near[inside].T), shape)
        closer = depth[near] == depth[todo] - 1
        parent[todo[closer]] = near[closer]
    return [int(p) if p >= 0 else None for p in parent]


def warm_start_plan(shape: tuple[int, ...], seeds: list[int]) -> tuple[list[int | None], list[int]]:
    """Parent and depth of every case of a grid of `shape` (see the module docstring)."""
    depth = depths(shape, seeds)
    return parents(shape, depth), depth.tolist()


def plan_cases(study: Study) -> list[PlannedCase]:
    """Every case of a study with its warm-start parent and depth."""
    shape = grid_shape(study)
    count = math.prod(shape)
    seeds = list(study.seeds) if study.seeds is not None else corners(shape)
    if study.max_depth is not None:
        seeds = lattice(shape, study.max_depth)
    bad = [s for s in seeds if not 0 <= s < count]
    if bad or not seeds:
        raise InputError(f"{study.source}: seeds: need case numbers from 0 to {count - 1}")
    parent, depth = warm_start_plan(shape, sorted(set(seeds)))
    cases = []
    for n, ix in enumerate(case_indices(study)):
        values = tuple(e.values[ix[0] if study.mode == "zip" else ix[i]] for i, e in enumerate(study.entries))
        cases.append(PlannedCase(n, ix, values, parent[n], depth[n]))
    return cases


def case_problem(study: Study, case: PlannedCase) -> dict[str, Any]:
    """The raw problem of a case: the base with the swept entries replaced."""
    raw = copy.deepcopy(study.base)
    for entry, value in zip(study.entries, case.values):
        set_path(raw, entry.keys, value)
    return raw


def case_key(raw: dict[str, Any], parent: str | None, data: list[tuple[str, str]], code: str) -> str:
    """Fingerprint of what a case computes: its problem, its parent's fingerprint (None for a
    seed: a case warm-started from another solution is another case), every data file it reads
    (`data`: name and sha256) and the code that solves it (`code_identity`). A stored case is
    reused only if it matches: a case of edited data, of another parent or of other code is
    solved again."""
    text = json.dumps({"problem": raw, "parent": parent, "data": data, "code": code}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def file_digests(paths: Iterable[Path]) -> dict[Path, str]:
    """The sha256 of each distinct file's contents, each read once."""
    return {path: compile_job.sha256_of(path) for path in dict.fromkeys(paths)}


@cache
def code_identity() -> str:
    """What identifies the code that solves a case: crashnlp's version, the sha256 of its package's
    files (`package_digest`; the version stays the same while the code changes between releases)
    and CasADi's version (IPOPT comes with it). Once per process: about 20 ms."""
    root = Path(__file__).parents[1]
    return f"crashnlp {VERSION} {package_digest(root)}, casadi {installed_version('casadi', 'casadi')}"


def package_digest(root: Path) -> str:
    """The sha256 of every file under `root` (its path and its contents), compiled bytecode left out."""
    return files_digest(sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts), root)
