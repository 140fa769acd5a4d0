"""The cases of a study and the warm-start plan, fixed from the case list alone.

Warm starts must not depend on which case happens to finish first, or two
executors would give different tables. So the plan is made up front: seed cases
(by default the corners of the grid) are solved cold in wave 0; wave k then holds
every case next to (Chebyshev distance 1 in grid-index space) a case of an earlier
wave, and each warm-starts from its nearest such case (Euclidean in index space,
ties to the lower case number). The cases of a wave run in parallel.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from crashnlp.errors import InputError
from crashnlp.studies.spec import Study, set_path


@dataclass(frozen=True)
class PlannedCase:
    """One case: where it sits in the grid, its swept values, its parent and wave."""

    number: int
    index: tuple[int, ...]
    values: tuple[Any, ...]  # one per sweep entry, as the user wrote it
    parent: int | None
    wave: int

    @property
    def id(self) -> str:
        return case_id(self.number)


MAX_CASES = 10_000  # a grid larger than this is a mistake, not a study


def case_id(number: int) -> str:
    """File and table name of a case."""
    return f"case-{number:03d}"


def case_indices(study: Study) -> list[tuple[int, ...]]:
    """Grid index of every case, in case order (zip: one index); refuse more than MAX_CASES."""
    if study.mode == "zip":
        return [(i,) for i in range(len(study.entries[0].values))]
    count = int(np.prod([len(e.values) for e in study.entries], dtype=float))
    if count > MAX_CASES:
        raise InputError(f"{study.source}: sweep: {count:g} cases in the grid, more than {MAX_CASES:,}")
    return list(itertools.product(*(range(len(e.values)) for e in study.entries)))


def corners(indices: list[tuple[int, ...]]) -> list[int]:
    """Case numbers at the corners of the index box (both ends of a line)."""
    top = np.max(indices, axis=0)
    wanted = {tuple(c) for c in itertools.product(*[(0, t) for t in top])}
    return [n for n, ix in enumerate(indices) if ix in wanted]


def warm_start_plan(indices: list[tuple[int, ...]], seeds: list[int]) -> tuple[list[int | None], list[int]]:
    """Parent and wave of every case (see the module docstring)."""
    pts = np.asarray(indices, dtype=float)
    parent: list[int | None] = [None] * len(indices)
    wave = [-1] * len(indices)
    for s in seeds:
        wave[s] = 0
    k = 0
    while min(wave) < 0:
        k += 1
        planned = np.flatnonzero(np.asarray(wave) >= 0)
        for n in np.flatnonzero(np.asarray(wave) < 0):
            near = planned[np.max(np.abs(pts[planned] - pts[n]), axis=1) <= 1]
            if near.size:
                d = np.linalg.norm(pts[near] - pts[n], axis=1)
                parent[n] = int(near[np.argmin(d)])  # argmin takes the first (lowest number) of ties
                wave[n] = k
    return parent, wave


def plan_cases(study: Study) -> list[PlannedCase]:
    """Every case of a study with its warm-start parent and wave."""
    indices = case_indices(study)
    seeds = list(study.seeds) if study.seeds is not None else corners(indices)
    bad = [s for s in seeds if not 0 <= s < len(indices)]
    if bad or not seeds:
        raise InputError(f"{study.source}: seeds: need case numbers from 0 to {len(indices) - 1}")
    parent, wave = warm_start_plan(indices, sorted(set(seeds)))
    cases = []
    for n, ix in enumerate(indices):
        values = tuple(e.values[ix[0] if study.mode == "zip" else ix[i]] for i, e in enumerate(study.entries))
        cases.append(PlannedCase(n, ix, values, parent[n], wave[n]))
    return cases


def waves(cases: list[PlannedCase]) -> list[list[PlannedCase]]:
    """Cases grouped by wave, in wave order."""
    return [[c for c in cases if c.wave == k] for k in range(max(c.wave for c in cases) + 1)]


def case_problem(study: Study, case: PlannedCase) -> dict[str, Any]:
    """The raw problem of a case: the base with the swept entries replaced."""
    raw = copy.deepcopy(study.base)
    for entry, value in zip(study.entries, case.values):
        set_path(raw, entry.keys, value)
    return raw


def case_key(raw: dict[str, Any], parent: int | None) -> str:
    """Fingerprint of what a case computes: a stored case is reused only if it matches."""
    text = json.dumps({"problem": raw, "parent": parent}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]
