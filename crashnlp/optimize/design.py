"""Design: choose spring and damper values for a crash pulse, with no data.

The objective is a design goal (peak deceleration, maximum front-end crush, or the
Occupant Load Criterion) under the problem's constraints, on the same
transcription as identification. Where loading ends is not known before the
design is: the NLP is solved with the stop node of the previous solve until it
no longer moves (a fixed point, usually two or three solves, each warm-started).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TextIO

import casadi as ca
import numpy as np

from crashnlp.analysis.metrics import OLC_FREE, OLC_RESTRAINED
from crashnlp.case.case import Case
from crashnlp.optimize.identify import Solution, finish
from crashnlp.optimize.ocp import OptimalControl, Transcript
from crashnlp.optimize.solve import solve
from crashnlp.problem.schema import Design


def _epigraph(ocp: OptimalControl, name: str, rows: Callable[[Transcript], ca.MX], scale: float) -> None:
    """minimize s subject to rows(test) <= s at every node of every test."""
    s = ocp.nlp.variable(f"design.{name}", 1, scale, 0.0, np.inf, scale=scale)
    for tr in ocp.transcripts:
        ocp.nlp.constrain("design", rows(tr) - s, -np.inf, 0.0, test=tr.test.name, detail=name)
    ocp.nlp.minimize(s / scale)


def peak_decel(ocp: OptimalControl) -> None:
    """The largest deceleration over every node of every test."""
    scale = max(t.speed for t in ocp.case.tests) ** 2 / 1.0  # v0^2 / (2 * 0.5 m)
    _epigraph(ocp, "peak_decel", lambda tr: -tr.output("accel"), scale)


def max_front_end_crush(ocp: OptimalControl) -> None:
    """The largest front-end crush (the `crush` output) over every node of every test."""
    _epigraph(ocp, "crush", lambda tr: tr.output("crush"), 0.5)


def _interp(t: ca.MX, times: np.ndarray, values: ca.MX) -> ca.MX:
    """Piecewise-linear interpolation of node values at a symbolic time (hat functions)."""
    h = float(times[1] - times[0])
    hats = ca.fmax(0, 1 - ca.fabs(t - ca.DM(times).T) / h)
    return ca.dot(hats.T, values.T)


def olc(ocp: OptimalControl) -> None:
    """Occupant Load Criterion: the occupant flies free for 65 mm relative to the
    vehicle, then decelerates uniformly (OLC) over 235 mm to the vehicle's speed.
    t1, t2 and the deceleration are decision variables of the NLP."""
    total: ca.MX = ca.MX(0)
    for tr in ocp.transcripts:
        times, v0 = tr.trajectory.times, tr.test.speed
        x, v = tr.output("displacement"), tr.output("velocity")
        name = tr.test.name
        guess_t1 = OLC_FREE / (0.3 * v0)
        t1 = ocp.nlp.variable(f"{name}.olc.t1", 1, guess_t1, times[1], times[-1], scale=0.01)
        t2 = ocp.nlp.variable(f"{name}.olc.t2", 1, 3 * guess_t1, times[1], times[-1], scale=0.01)
        a = ocp.nlp.variable(f"{name}.olc.a", 1, v0**2, 0.0, np.inf, scale=v0**2)
        dt = t2 - t1
        ocp.nlp.constrain("olc", v0 * t1 - _interp(t1, times, x) - OLC_FREE, test=name, detail="free_flight")
        ocp.nlp.constrain(
            "olc", v0 * t2 - 0.5 * a * dt**2 - _interp(t2, times, x) - OLC_FREE - OLC_RESTRAINED, test=name, detail="restraint"
        )
        ocp.nlp.constrain("olc", v0 - a * dt - _interp(t2, times, v), test=name, detail="matched")
        ocp.nlp.constrain("olc", dt, 0.0, np.inf, test=name, detail="order")
        total += a / v0**2
    ocp.nlp.minimize(total)


DESIGN_OBJECTIVES: dict[str, Callable[[OptimalControl], None]] = {
    "peak_decel": peak_decel,
    "crush": max_front_end_crush,
    "olc": olc,
}


def design(case: Case, verbose: bool = False, progress: TextIO | None = sys.stdout, warm: np.ndarray | None = None) -> Solution:
    """Solve a design problem."""
    goal = (case.problem.design or Design()).minimize  # the file's design section, or the default one
    ocp = OptimalControl(case)
    DESIGN_OBJECTIVES[goal](ocp)
    if warm is not None:
        ocp.set_guess(warm)
    result = solve(ocp.nlp, case.problem.solver, verbose, None if verbose else progress)
    return finish(case, ocp, result, ocp.free.initial, [])
