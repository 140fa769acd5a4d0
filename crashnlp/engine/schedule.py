"""Run tasks that depend on one another on an executor's lanes, each as soon as what it needs is done.

A study's cases form a forest: a case warm-starts from its parent's solution, so
it may start only once its parent has finished, but need not wait for anything
else (no waves). Of the tasks ready at a time, the one with the most work on the
longest chain below it goes first (critical path first), so that a slow cold
seed and the cases waiting for it start early. A task goes to its parent's lane
when that lane is free: a warm start has its parent's shape, so the worker that
solved the parent may hold the built solver. Order and lanes change only when
a case runs, never what it computes: the plan fixes every parent.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from crashnlp.engine.executors import Executor

# a cold solve's work in warm ones: a cold start takes several times the iterations of a warm start
# from a neighbouring case (measured: docs/design-notes.md, "A cold solve's weight in a study")
COLD_WORK = 5.0


def children(parent: Mapping[int, int | None]) -> dict[int, list[int]]:
    """The tasks that wait for each task, in number order."""
    kids: dict[int, list[int]] = {n: [] for n in parent}
    for n in sorted(parent):
        p = parent[n]
        if p is not None and p in kids:
            kids[p].append(n)
    return kids


def work_below(parent: Mapping[int, int | None]) -> dict[int, float]:
    """The work on the longest chain from each task down (a task with no parent is a cold solve)."""
    kids = children(parent)
    order = [n for n in sorted(parent) if parent[n] not in kids]
    for n in order:  # grows while it is walked: every task after its parent
        order.extend(kids[n])
    work: dict[int, float] = {}
    for n in reversed(order):
        own = COLD_WORK if parent[n] is None else 1.0
        work[n] = own + max((work[k] for k in kids[n]), default=0.0)
    return work


def run_tree(
    executor: Executor,
    fn: Callable[[Any], Any],
    parent: Mapping[int, int | None],
    job: Callable[[int], Any],
    priority: Mapping[int, float] | None = None,
) -> Iterator[tuple[int, Any]]:
    """fn(job(n)) for every task n of `parent`, yielding (n, result) as each finishes.

    A task starts once its parent has finished and been yielded (a parent that is not a task
    counts as finished), so `job(n)` may read what the caller stored for the parent. Ready
    tasks start by `priority` (default: work_below), highest first, ties to the lower number;
    at most one task per lane runs at a time. A task that raised yields its exception.
    """
    rank = priority if priority is not None else work_below(parent)
    kids = children(parent)
    ready = [(-rank[n], n) for n in parent if parent[n] not in kids]
    heapq.heapify(ready)
    running: dict[int, int] = {}  # lane -> task
    lane_of: dict[int | None, int] = {}  # finished task -> its lane
    while ready or running:
        while ready and len(running) < executor.lanes:
            n = heapq.heappop(ready)[1]
            lane = _lane(lane_of.get(parent[n], -1), running, executor.lanes)
            executor.submit(lane, fn, job(n))
            running[lane] = n
        lane, outcome = executor.wait()
        n = running.pop(lane)
        lane_of[n] = lane
        yield n, outcome
        for k in kids[n]:
            heapq.heappush(ready, (-rank[k], k))


def _lane(preferred: int, running: Mapping[int, int], lanes: int) -> int:
    """The preferred lane if it is free, else the first free one."""
    if 0 <= preferred < lanes and preferred not in running:
        return preferred
    return next(k for k in range(lanes) if k not in running)


def map_all(executor: Executor, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
    """fn(item) for independent items, in order of position, yielding (position, result) as each finishes."""
    return run_tree(executor, fn, dict.fromkeys(range(len(items))), items.__getitem__, dict.fromkeys(range(len(items)), 0.0))
