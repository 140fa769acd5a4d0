"""IPOPT's iteration callback and the detectors it runs on a Gauss-Newton fit's iterates: its
slow tail, a cycle, a wander, a cycle that does not settle. Each rule is stated with its
thresholds below and its reason; the measurements behind the numbers are in
docs/design-notes.md ("Gauss-Newton's slow tail" and the sections after it). The thresholds
were set on the fits named there (the robustness corpus's seed, the 64-case grid, cross-speed
vehicles) and are checked, unchanged, on a corpus seed no fit had seen: bench/detectors.py
counts each rule's firings, false alarms and misses on the set seed and on that one
(docs/design-notes.md, "The watch's rules on an unseen seed")."""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, TextIO

import casadi as ca
import numpy as np

from crashnlp.optimize.options import SETTLE_OPTIONS
from crashnlp.optimize.solved import Stop

# Gauss-Newton's slow tail. Rule: TAIL_RUN ratios of successive primal steps in a row between
# TAIL_RATIO and 1 and within TAIL_SPREAD of each other, the last step below TAIL_STEP in the
# scaled variables, the constraints met to TAIL_VIOLATION. Reason: near a fit that leaves large
# residuals, or along a weakly determined direction, Gauss-Newton converges only linearly; a
# contraction of 0.5 or slower gains a digit in 3.3 iterations or more, where Newton, once this
# close, gains them quadratically. The ratio must be steady: steps that shrink unevenly are
# Gauss-Newton leaving a point, not closing in on it. Measured: docs/design-notes.md,
# "Gauss-Newton's slow tail".
TAIL_RATIO, TAIL_SPREAD, TAIL_RUN, TAIL_STEP, TAIL_VIOLATION = 0.5, 0.02, 3, 3e-2, 1e-4

# A cycle: the iterates go round a point instead of closing in on it. Rule: from CYCLE_START
# iterations on, CYCLE_RUN iterates in a row each within CYCLE_RETURN of its stride from one of the
# CYCLE_PERIOD iterates before the last (it came back), the steps over the last half of them no
# shorter than CYCLE_SHRINK of the half before, the constraints met to CYCLE_VIOLATION. An
# iterate's stride is the longer of its step and the step before: a cycle may hold a step that the
# line search cut to almost nothing. Reason: where the crush crosses a kink of the force laws
# inside an integration step, the step's derivatives jump as the parameters move the crossing
# across a stage of the step; the dual infeasibility then stays put and IPOPT steps round and round
# the optimum, where a converging run shortens its steps. A cycle can be long, so the window looks
# CYCLE_PERIOD back. Measured: docs/design-notes.md, "Fits that finish: measured", "The 4-degree
# row" and "A cycle through a step cut short".
CYCLE_START, CYCLE_RUN, CYCLE_PERIOD, CYCLE_RETURN, CYCLE_SHRINK, CYCLE_VIOLATION = 20, 8, 30, 0.3, 0.7, 1e-3

# A wander: the iterates left the start's basin. Rule, for a warm start only: after WANDER_START
# iterations, an objective above WANDER_RISE times the start's with the constraints violated by
# more than WANDER_VIOLATION; Gauss-Newton then starts over from the start with a small barrier
# that only falls (crashnlp.optimize.options.WANDER_OPTIONS). Reason: from a start near a fit (a
# study case warm-started from its neighbour's solution) that sits on its constraints, IPOPT's
# first barrier pushes it off them, a long Gauss-Newton step opens the shooting defects, and the
# iterates wander at objectives far above the start's before they find their way back. That
# barrier is not every warm start's, since it costs iterations where nothing wanders; and cold
# starts are not watched, since far from the optimum a fit's objective may rise and come back.
# Measured: docs/design-notes.md, "The 4-degree row" and "Fits that finish: measured".
WANDER_START, WANDER_RISE, WANDER_VIOLATION = 25, 2.0, 1e-3

# A cycle that does not settle. Rule, for the settling of a cycle only (SETTLE_OPTIONS): the cycle
# rule above, its thresholds unchanged but for the constraints, fires in the settle's own run, and
# the cycle holds an iterate that IPOPT's acceptable test of the settle refuses: the objective
# changing by more than its acceptable_obj_change_tol (relative where above 1) from one of the last
# CYCLE_RUN iterates to the next, or the constraints violated by more than its
# acceptable_constr_viol_tol (however far: a settle's cycle is not held to CYCLE_VIOLATION, as a
# cycle that violates the constraints cannot settle either); the exact Hessian then finishes from
# the settle's iterate (crashnlp.optimize.solve). Reason: a cycle comes back to its iterates, so an
# iterate the acceptable test refuses breaks every run of iterates the settle counts toward its
# stop, lap after lap, and the settle runs to its limit; the settle is for cycles whose objective
# has stopped moving, where the exact Hessian sees the same kink. Where the objective still swings
# from one iterate to the next, the Gauss-Newton step, not the kink, keeps the iterates going
# round, and the exact Hessian started there converges. No threshold of its own: the cycle's are
# the cycle rule's, the acceptable test's the settle's. Measured: docs/design-notes.md, "A cycle
# that does not settle".
# what the Watch looks for: the slow tail, a cycle, a wander, and a settle's cycle (which stops it
# as "unsettled", a Stop and no look)
Look = Literal["tail", "cycle", "wander", "settle"]


class Watch(ca.Callback):
    """IPOPT's iteration callback: a short line every `every` iterations when asked, and for a
    Gauss-Newton fit a stop in its slow tail, a cycle or a wander (the rules above)."""

    def __init__(self, nx: int, ng: int, every: int = 10):
        ca.Callback.__init__(self)
        self.nx, self.ng, self.every = nx, ng, every
        self.start(np.zeros(ng), np.zeros(ng), None)
        self.construct("watch", {})

    def start(self, lbg: np.ndarray, ubg: np.ndarray, out: TextIO | None, looks: frozenset[Look] = frozenset()) -> None:
        """Before a run: the constraint bounds, where progress goes, and which of Gauss-Newton's
        slow tail, a cycle, a wander and a settle's cycle that does not settle stop it."""
        self.lbg, self.ubg, self.out, self.looks = lbg, ubg, out, looks
        self.count = 0
        self.x: np.ndarray | None = None  # the last iterate
        self.steps: list[float] = []  # the primal steps' lengths, scaled variables
        self.iterates: list[np.ndarray] = []  # the last CYCLE_PERIOD + 1
        self.returns = 0  # iterates in a row that came back (CYCLE_START above)
        self.objectives: list[float] = []  # a settle's last CYCLE_RUN + 1 objectives (`unsettled`)
        self.remaining: float | None = None  # set to hand over to Newton: the distance still to go
        self.start_objective: float | None = None
        self.stopped: Stop | None = None  # set to stop a cycle, a wander or an unsettled cycle (rules above)
        self.broken: BrokenPipeError | None = None  # set when `out`'s reader left: the run stops there

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name == "x":
            return ca.Sparsity.dense(self.nx)
        if name == "g":
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)  # the multipliers are not read: nlpsol skips empty inputs

    def eval(self, arg):
        count, self.count = self.count, self.count + 1
        printing = self.out is not None and count % self.every == 0
        if not (printing or self.looks):  # designs, profiles, most iterations: nothing to look at
            return [0]
        names = ca.nlpsol_out()

        def violation() -> float:
            g = np.asarray(arg[names.index("g")]).ravel()
            return float(np.max(np.maximum(self.lbg - g, g - self.ubg), initial=0.0))

        if printing:
            f = float(arg[names.index("f")])
            try:
                print(f"  iter {count:4d}  objective {f:11.5g}  constraint violation {violation():9.2e}", file=self.out)
            except BrokenPipeError as exc:  # CasADi would turn it into IPOPT's stop and the run would go on
                self.broken = exc
                return [1]
        if self.looks:
            self._follow(arg[names.index("x")].full().ravel(), float(arg[names.index("f")]), violation)
        return [int(self.remaining is not None or self.stopped is not None)]

    def _follow(self, x: np.ndarray, f: float, violation: Callable[[], float]) -> None:
        """Gauss-Newton's steps: in its slow tail, `remaining` is the distance still to go; in a
        cycle, a wander or a settle's cycle that does not settle, `stopped` says which (the
        constraint violation is computed only there)."""
        if self.start_objective is None:
            self.start_objective = f
        if self.x is not None:
            self.steps.append(float(np.abs(x - self.x).max(initial=0.0)))
        self.x = x
        if "cycle" in self.looks or "settle" in self.looks:
            judged = self.count >= CYCLE_START - CYCLE_RUN  # a cycle is seen from CYCLE_START on
            self.iterates, self.returns = followed(self.iterates, self.returns, x, judged)
        if "settle" in self.looks:
            self.objectives = [*self.objectives[-CYCLE_RUN:], f]
        if "tail" in self.looks and slow_tail(self.steps) and violation() <= TAIL_VIOLATION:
            ratio = self.steps[-1] / self.steps[-2]
            self.remaining = self.steps[-1] * ratio / (1 - ratio)
        elif (
            "cycle" in self.looks
            and self.count >= CYCLE_START
            and cycle(self.returns, self.steps)
            and violation() <= CYCLE_VIOLATION
        ):
            self.stopped = "cycle"
        elif (
            "settle" in self.looks
            and self.count >= CYCLE_START
            and cycle(self.returns, self.steps)
            and unsettled(self.objectives, violation())
        ):
            self.stopped = "unsettled"
        elif (
            "wander" in self.looks
            and self.count >= WANDER_START
            and f > WANDER_RISE * self.start_objective
            and violation() > WANDER_VIOLATION
        ):
            self.stopped = "wander"


def slow_tail(steps: list[float]) -> bool:
    """Whether the last primal steps shrink linearly, slowly and steadily (TAIL_RATIO above)."""
    if len(steps) <= TAIL_RUN or steps[-1] > TAIL_STEP or min(steps[-TAIL_RUN - 1 :]) <= 0:
        return False
    last = steps[-TAIL_RUN - 1 :]
    ratios = [b / a for a, b in zip(last, last[1:])]  # a few numbers: plain Python, no numpy calls
    return all(TAIL_RATIO <= r < 1 for r in ratios) and max(ratios) - min(ratios) <= TAIL_SPREAD


def followed(iterates: list[np.ndarray], returns: int, x: np.ndarray, judged: bool = True) -> tuple[list[np.ndarray], int]:
    """The last CYCLE_PERIOD + 1 iterates with `x`, and how many in a row came back (`came_back`);
    not `judged`, none (before a cycle could be seen, the window is only filled)."""
    iterates = [*iterates[-CYCLE_PERIOD:], x]
    return iterates, returns + 1 if judged and came_back(iterates) else 0


def came_back(iterates: list[np.ndarray]) -> bool:
    """Whether the last iterate lies within CYCLE_RETURN of its stride from an earlier one than
    the one before it (CYCLE_START above). Its stride is the longer of its own step and the step
    before: a cycle may hold a step that IPOPT's line search cut to almost nothing, and the iterate
    that step reaches comes back within a fraction of the cycle's steps, not of its own."""
    if len(iterates) < 3:
        return False
    x = iterates[-1]
    stride = max(float(np.abs(b - a).max(initial=0.0)) for a, b in zip(iterates[-3:-1], iterates[-2:]))
    if stride <= 0:
        return False
    distances = np.abs(np.stack(iterates[:-2]) - x).max(axis=1, initial=0.0)  # one call for the window
    return bool(distances.min() <= CYCLE_RETURN * stride)


def unsettled(objectives: list[float], violation: float) -> bool:
    """Whether a settle's cycle holds an iterate its acceptable test refuses ("A cycle that does
    not settle" above): the constraints violated by more than SETTLE_OPTIONS' tolerance, or the
    objective changing by more than its tolerance between two of the last `objectives` (relative
    where above 1)."""
    changes = [abs(b - a) / max(1.0, abs(b)) for a, b in zip(objectives, objectives[1:])]
    steady, met = SETTLE_OPTIONS["acceptable_obj_change_tol"], SETTLE_OPTIONS["acceptable_constr_viol_tol"]
    return violation > met or max(changes, default=0.0) > steady


def cycle(returns: int, steps: list[float]) -> bool:
    """Whether the iterates go round a point: CYCLE_RUN of them in a row came back, with steps
    that do not shrink (CYCLE_START above)."""
    if returns < CYCLE_RUN or len(steps) < CYCLE_RUN:
        return False
    last, half = steps[-CYCLE_RUN:], CYCLE_RUN // 2
    return sum(last[half:]) >= CYCLE_SHRINK * sum(last[:half])
