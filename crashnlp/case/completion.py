"""Fill in what a problem leaves out, from its tests' data: (problem, tests) -> measured pulses -> new problem.

The given problem is never changed. What is filled, and how:

- Crush from the data: the displacement channel, else the integral of velocity, else the
  integral of acceleration from the impact speed; samples from impact (t >= 0) on.
- `model.spring.crush_breakpoints` omitted or `{count: N}`: N breakpoints from 0 to the
  largest crush of all tests (REACH = 1), where the measured loading curve (m |a| against
  crush, all tests together) bends (crashnlp.case.segmentation): at the bumper's first peak, the
  ends of plateaus, the start of a stack-up, which evenly spaced breakpoints put corners
  inside. Omitted, N is the data's (`resolution`): the fewest from DEFAULT_COUNT up to
  MAX_COUNT whose piecewise-linear curve follows the measured one within LEVEL RMS per unit
  of mass (the discrepancy principle: as fine as the data ask, no finer). A problem's list
  or count is kept, and the data's choice said beside it. None lies past the largest crush,
  so the data reach every one: a breakpoint past it would carry a value the data barely see,
  which a fit runs to where model-form error pulls it and a prediction at a higher speed then
  meets. Past the last breakpoint the spring law continues its last segment.
- `values` omitted: the measured force-crush curve while loading (impact to largest crush),
  m |a| minus the damper's force, against the crush, averaged over the crush band nearest
  each breakpoint (halfway to its neighbours). A band the data do not reach takes the
  value of the last band they do. Secant stiffnesses are that force over the crush.
- `model.damper` omitted while the spring values come from the data: a constant
  c = DAMPING_PER_MASS (2 /s) times the mass up to 1.1 times the highest impact speed
  (5 kN s/m for a 2550 kg pickup, 3.4 kN s/m for a 1719 kg sedan).
- `model.unloading.stiffness` omitted: the front end's elastic energy F^2 / (2 k) at the
  largest crush comes back as the rebound, m v_r^2 / 2, so k = F^2 / (m v_r^2), F the
  measured force at the largest crush and v_r the rebound velocity, within UNLOADING_BOUNDS;
  without a measured rebound the nominal 30 MN/m.
- `estimate` omitted (identification): the spring values within [0, 5 times the largest
  initial value, at least 2 MN], the plastic unloading stiffness within UNLOADING_BOUNDS,
  and where a test has a pitch channel what the model's form estimates of its pitch (its
  `pitch_estimate`: the CG height above the impact point and the pitch inertia within physical
  bounds, and the pendulum's pitch lever); with tests at
  speeds more than SPEED_SPREAD apart also the damper, within [0, DAMPER_BOUND_FACTOR times
  the nominal one], since two speeds separate it from the spring; and what the form estimates
  of its own entries (`own_estimate`: the engine's gap).
- `estimate` given (identification): as given, and a form's own entry the problem leaves out,
  which the data then chose, estimated too (`own_estimate`: the engine's gap read off the pulse
  is its least exact value, and held it misfits).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.base.units import G0
from crashnlp.case.segmentation import BANDS, bends, misfit
from crashnlp.case.testcase import TestCase
from crashnlp.data.channels import TestData
from crashnlp.data.signal import cumtrapz, integrate
from crashnlp.models.form import form_class
from crashnlp.problem.schema import BreakpointCount, Damper, EstimateSpec, Problem, with_fields

DEFAULT_COUNT = 8  # the fewest breakpoints the data's resolution has
MAX_COUNT = BANDS // 4 + 1  # the most: four crush bands to a segment (18)
# The accuracy the loading curve is resolved to: 1 g of RMS misfit per unit of mass, half the
# accel channel's residual scale (crashnlp.optimize.fit.DEFAULT_SIGMA), so that the force law
# leaves the fit's accuracy to the dynamics (docs/identification.md, "Resolution").
LEVEL = 1.0 * G0  # m/s^2
REACH = 1.0
DAMPING_PER_MASS = 2.0  # 1/s: nominal damper per kg of vehicle
DAMPER_BOUND_FACTOR = 10.0  # the estimated damper's upper bound: this times the nominal one
SPEED_SPREAD = 0.1  # relative: tests at speeds further apart are at several speeds (`several_speeds`)
NOMINAL_UNLOADING = 3.0e7  # N/m
UNLOADING_BOUNDS = (2.0e6, 2.0e8)  # N/m
SPRING_BOUND_FACTOR, SPRING_BOUND_FLOOR = 5.0, 2.0e6  # upper bound of spring forces: 5 x the start, >= 2 MN


@dataclass(frozen=True)
class Pulse:
    """One test's measured crash pulse from impact on (SI, model frame)."""

    time: np.ndarray
    displacement: np.ndarray  # CG travel since impact (the crush of the measured loading curve), m
    rate: np.ndarray  # crush rate (the velocity toward the barrier), m/s
    force: np.ndarray  # m |a| while decelerating, N
    mass: float
    speed: float
    has_pitch: bool

    @property
    def loading(self) -> slice:
        """Samples from impact to the largest crush."""
        return slice(0, int(np.argmax(self.displacement)) + 1)

    @property
    def max_displacement(self) -> float:
        return float(np.max(self.displacement))


def pulse(data: TestData, speed: float, mass: float) -> Pulse | None:
    """The crash pulse of one test's data from impact on; None without accel or velocity.

    Velocity without a velocity channel is the acceleration integrated from the impact speed at
    t = 0; displacement without a displacement channel is the velocity integrated, zero at t = 0."""
    ch = data.channels
    base = ch.get("accel") or ch.get("velocity")
    if base is None:
        return None
    t = base.time
    at = lambda name: np.interp(t, ch[name].time, ch[name].values)  # noqa: E731
    v = at("velocity") if "velocity" in ch else integrate(t, at("accel"), speed, max(0.0, t[0]))[0]
    a = at("accel") if "accel" in ch else np.gradient(v, t)
    x = at("displacement") if "displacement" in ch else cumtrapz(t, v)
    after = t >= 0.0
    x = x - np.interp(0.0, t, x) if t[0] <= 0.0 else x
    return Pulse(t[after], x[after], v[after], mass * np.maximum(-a[after], 0.0), mass, speed, "pitch" in ch)


@dataclass(frozen=True)
class Resolution:
    """How finely the spring law follows the measured loading curve, and who chose it.

    `chosen`: "data" (the problem left the breakpoints out: the fewest from DEFAULT_COUNT whose
    curve follows the data within `level`), "count" (the problem gave their number) or "list"
    (the problem gave them). `misfit`: RMS of the measured loading curve about the law's best
    piecewise-linear curve through the breakpoints, per unit of mass (m/s^2); `data_count`: the
    number the data would choose."""

    count: int
    chosen: Literal["data", "count", "list"]
    misfit: float
    level: float
    data_count: int

    def to_json(self) -> dict[str, float | int | str]:
        """result.json's `resolution`: the misfit and level in g, and the note."""
        return {
            "count": self.count,
            "chosen": self.chosen,
            "data_count": self.data_count,
            "misfit_g": round(self.misfit / G0, 4),
            "level_g": self.level / G0,
            "note": self.note,
        }

    @property
    def note(self) -> str:
        """One line: the number of breakpoints and how it was chosen."""
        if self.chosen == "data":
            met = "the fewest" if self.misfit <= self.level else "the most allowed, none"
            return (
                f"{self.count} breakpoints, chosen from the data: {met} of {DEFAULT_COUNT} to {MAX_COUNT} whose "
                f"curve follows the measured loading curve within {self.level / G0:g} g RMS ({self.misfit / G0:.2f} g)"
            )
        given = "their number" if self.chosen == "count" else "them"
        return (
            f"{self.count} breakpoints, the problem gives {given}: their curve follows the measured loading curve "
            f"within {self.misfit / G0:.2f} g RMS; the data would choose {self.data_count}"
        )


def resolution(pulses: list[Pulse], given: Sequence[float] | int | None = None) -> tuple[list[float], Resolution]:
    """The breakpoints (`given` as a list, else `given` of them, else as many as the data
    choose) and how they follow the pulses' loading curve. Placed breakpoints run from 0 to
    REACH times the largest crush of all pulses, where their measured loading curve (m |a|
    against crush) bends (crashnlp.case.segmentation)."""
    crush, force = loading_curve(pulses)
    top, mass = REACH * max(p.max_displacement for p in pulses), float(np.mean([p.mass for p in pulses]))
    chosen: list[float] = []
    for count in range(DEFAULT_COUNT, MAX_COUNT + 1):
        chosen = bends(crush, force, top, count)
        if misfit(crush, force, top, chosen) <= LEVEL * mass:
            break
    placed = bends(crush, force, top, given) if isinstance(given, int) else list(given) if given is not None else chosen
    how: Literal["data", "count", "list"] = "count" if isinstance(given, int) else "list" if given is not None else "data"
    return placed, Resolution(len(placed), how, misfit(crush, force, top, placed) / mass, LEVEL, len(chosen))


def loading_curve(pulses: list[Pulse], damper: Damper | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every pulse's samples while loading, together: crush, and m |a| less the damper's force."""
    crush = np.concatenate([p.displacement[p.loading] for p in pulses])
    force = np.concatenate([p.force[p.loading] - _damper_force(damper, p.rate[p.loading]) for p in pulses])
    return crush, force


def measured_force(bps: Sequence[float], pulses: list[Pulse], damper: Damper | None = None) -> np.ndarray:
    """Mean measured spring force while loading over the crush band nearest each breakpoint."""
    crush, force = loading_curve(pulses, damper)
    edges = np.concatenate([[-np.inf], 0.5 * (np.asarray(bps[1:]) + np.asarray(bps[:-1])), [np.inf]])
    band = np.searchsorted(edges, crush, side="right") - 1
    values = np.full(len(bps), np.nan)
    for i in range(len(bps)):
        if np.any(band == i):
            values[i] = max(float(np.mean(force[band == i])), 0.0)
    reached = np.flatnonzero(np.isfinite(values))
    if reached.size == 0:
        raise InputError("model.spring.values: the data reach none of the crush breakpoints")
    return np.interp(np.arange(len(bps)), reached, values[reached])


def _damper_force(damper: Damper | None, rate: np.ndarray) -> np.ndarray:
    if damper is None:
        return np.zeros_like(rate)
    return np.interp(np.abs(rate), damper.rate_breakpoints, damper.values) * np.maximum(rate, 0.0)


def spring_values(bps: Sequence[float], pulses: list[Pulse], law: str, damper: Damper | None) -> list[float]:
    """Initial spring values at the breakpoints from the measured force-crush curve."""
    force = measured_force(bps, pulses, damper)
    if law == "force":
        return [float(f) for f in force]
    x = np.asarray(bps, dtype=float)
    first = np.flatnonzero(x > 0)[0]
    secant = force / np.where(x > 0, x, x[first])
    secant[x <= 0] = secant[first]
    return [float(k) for k in secant]


def nominal_damper(pulses: list[Pulse], mass: float) -> Damper:
    """Constant damping DAMPING_PER_MASS * mass up to 1.1 times the highest impact speed."""
    c = DAMPING_PER_MASS * mass
    return Damper(rate_breakpoints=[0.0, 1.1 * max(p.speed for p in pulses)], values=[c, c])


def unloading_stiffness(pulses: list[Pulse]) -> float:
    """k = F^2 / (m v_r^2) from the force at the largest crush and the rebound, averaged over tests."""
    estimates = []
    for p in pulses:
        peak = p.loading.stop - 1
        rebound = -float(np.min(p.rate[peak:]))
        if rebound < 0.02 * p.speed:
            continue
        near = np.abs(p.time - p.time[peak]) <= 2e-3
        force = float(np.mean(p.force[near]))
        estimates.append(force**2 / (p.mass * rebound**2))
    return float(np.clip(np.mean(estimates), *UNLOADING_BOUNDS)) if estimates else NOMINAL_UNLOADING


def several_speeds(pulses: list[Pulse]) -> bool:
    """Whether the tests' impact speeds lie far enough apart (SPEED_SPREAD) to count as several:
    they tell the crush-rate damper from the crush spring (at one speed crush and crush rate move
    together), and they ask one loading curve to serve several pitches (crashnlp.models.pendulum.pitch_lever_bounds)."""
    speeds = [p.speed for p in pulses]
    return len(speeds) > 1 and max(speeds) > (1 + SPEED_SPREAD) * min(speeds)


def default_estimate(problem: Problem, pulses: list[Pulse]) -> dict[str, EstimateSpec]:
    """What an identification estimates when the problem does not say (see the module notes)."""
    spring, mass = problem.model.spring, problem.vehicle.known_mass
    top = max(SPRING_BOUND_FACTOR * max(spring.known_values), SPRING_BOUND_FLOOR if spring.law == "force" else 0.0)
    out = {"model.spring.values": EstimateSpec(bounds=(0.0, top))}
    if problem.model.unloading.law == "plastic":
        out["model.unloading.stiffness"] = EstimateSpec(bounds=UNLOADING_BOUNDS)
    if problem.model.damper is not None and several_speeds(pulses):
        out["model.damper.values"] = EstimateSpec(bounds=(0.0, DAMPER_BOUND_FACTOR * DAMPING_PER_MASS * mass))
    form = form_class(problem.model.form)
    if any(p.has_pitch for p in pulses):
        out.update(form.pitch_estimate(problem, several_speeds(pulses)))
    out.update(form.own_estimate(problem))
    return out


def _required(pulses: list[Pulse], what: str) -> list[Pulse]:
    if not pulses:
        raise InputError(f"{what}: not given, and no test has accel or velocity data to derive it from")
    return pulses


def complete(problem: Problem, pulses: list[Pulse]) -> tuple[Problem, Resolution | None]:
    """A copy of `problem` with breakpoints, spring values, damper, unloading stiffness and
    estimate filled in from the pulses where the problem leaves them out, and the resolution of
    its spring law (None without pulses). A filled-in entry counts as set in its own section
    (`model_fields_set`), the sections around it do not."""
    model = problem.model
    spring, unloading = model.spring, model.unloading
    set_in_model: dict[str, Damper] = {}
    given = spring.crush_breakpoints
    placed: Resolution | None = None
    if pulses or not isinstance(given, tuple):
        count = given.count if isinstance(given, BreakpointCount) else given
        bps, placed = resolution(_required(pulses, "model.spring.crush_breakpoints"), count)
        spring = spring.model_copy(update={"crush_breakpoints": bps})
    if spring.values is None:
        measured = _required(pulses, "model.spring.values")
        damper = model.damper if model.damper is not None else nominal_damper(measured, problem.vehicle.known_mass)
        if model.damper is None:
            set_in_model["damper"] = damper
        values = spring_values(spring.placed_breakpoints, measured, spring.law, damper)
        spring = spring.model_copy(update={"values": values})
    if unloading.stiffness is None:
        unloading = unloading.model_copy(update={"stiffness": unloading_stiffness(pulses)})
    out = with_fields(problem, model=with_fields(model, spring=spring, unloading=unloading).model_copy(update=set_in_model))
    form = form_class(out.model.form)
    out = form.complete(out, pulses)
    if out.kind == "identify" and pulses:
        chosen = {path: spec for path, spec in form.own_estimate(out).items() if _left_out(problem, path)}
        estimate = {**chosen, **out.estimate} if out.estimate else default_estimate(out, pulses)
        out = out.model_copy(update={"estimate": estimate})
    return out, placed


def _left_out(problem: Problem, path: str) -> bool:
    """Whether `problem` leaves the entry at the dotted `path` out (it, or a section holding it, is
    None): a form's own entry the data then chose, which a fit estimates even where the problem's
    estimate does not name it (an engine's gap read off the pulse, held, misfits by a fifth)."""
    node: Any = problem
    for key in path.split("."):
        node = getattr(node, key, None)
        if node is None:
            return True
    return False


def repaired_start(problem: Problem, tests: Sequence[TestCase]) -> dict[str, Any]:
    """Spring values at the problem's own breakpoints and unloading stiffness from its tests' data.

    For a start whose spring stops the model short of the measured crush (parameters with a
    zero derivative): `case.with_start(repaired_start(case.problem, case.tests))`, as
    crashnlp.optimize.identify.repair_start does.
    """
    pulses = measured_pulses(problem, tests)
    spring, damper = problem.model.spring, problem.model.damper
    return {
        "model.spring.values": spring_values(
            spring.placed_breakpoints, _required(pulses, "model.spring.values"), spring.law, damper
        ),
        "model.unloading.stiffness": unloading_stiffness(pulses),
    }


def measured_pulse(problem: Problem, test: TestCase) -> Pulse | None:
    """The measured pulse of one test of a problem; None without accel or velocity data."""
    if test.data is None:
        return None
    return pulse(test.data, test.speed, test.overrides.get("vehicle.mass", problem.vehicle.known_mass))


def measured_pulses(problem: Problem, tests: Sequence[TestCase]) -> list[Pulse]:
    """The measured pulse of every test that has accel or velocity data."""
    return [p for test in tests if (p := measured_pulse(problem, test)) is not None]
