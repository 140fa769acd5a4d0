"""A problem made ready to compute: data loaded, parameters laid out, model built.

This ties the steps together (like PyBaMM's Simulation): problem file ->
validated problem -> data and symbolic model, shared by simulate, identify,
design and studies.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crashnlp.autoinit import case_pulses, complete
from crashnlp.data import TestData, load_test_data
from crashnlp.errors import InputError
from crashnlp.model.parameters import ParameterLayout
from crashnlp.model.pendulum import PendulumModel, build_model
from crashnlp.problem import Problem, Test, load_problem
from crashnlp.simulation import Response, simulate

SPEED_TOLERANCE = 0.05  # relative: data that start further from the test's speed contradict it


def check_speed(i: int, speed: float, test: Test, data: TestData) -> None:
    """Refuse a test speed the data contradict: the header's speed, or a measured velocity at impact.

    A plain number is m/s, so `speed: 56` meant as km/h is 3.6 times the data's: fitting that runs
    into the iteration limit without ever saying why.
    """
    where = f"tests.{i}.speed" if test.speed is not None else "vehicle.speed"
    header = data.meta.get("speed")
    if header and abs(speed - header) > SPEED_TOLERANCE * header:
        raise InputError(
            f"{where}: {speed:g} m/s, but the data header of test {test.name} says {header:g} m/s "
            f"(more than 5 % apart; a plain number is m/s)"
        )
    spec = test.data.channels.get("velocity") if test.data is not None else None
    velocity = data.channels.get("velocity")
    if test.data is None or velocity is None or spec is None or spec.derive is not None:
        return
    t0 = min(max(0.0, float(velocity.time[0])), float(velocity.time[-1]))
    start = float(np.interp(t0, velocity.time, velocity.values))
    if abs(start - speed) > SPEED_TOLERANCE * abs(speed):
        raise InputError(
            f"{where}: {speed:g} m/s, but the velocity data of test {test.name} start at {start:g} m/s "
            f"({test.data.file.name}); speed and data disagree by more than 5 % (a plain number is m/s)"
        )


@dataclass
class TestCase:
    """One test of a problem: its impact speed, horizon, data and parameter overrides."""

    spec: Test
    speed: float
    duration: float
    data: TestData | None
    overrides: dict[str, float]

    @property
    def name(self) -> str:
        return self.spec.name


class Case:
    """Problem + data + parameter layout + symbolic model.

    What the problem leaves out (vehicle mass, breakpoints, spring values, unloading
    stiffness, estimate) is filled in from the data (crashnlp.autoinit); `problem` is the
    completed copy, and the problem it is given is not changed.
    """

    def __init__(self, problem: Problem):
        loaded = [load_test_data(t.data, problem.speed(t)) if t.data else None for t in problem.tests]
        self.problem = self._with_vehicle_mass(problem, loaded)
        self.tests = [self._test_case(i, t, d) for i, (t, d) in enumerate(zip(problem.tests, loaded))]
        self.problem = complete(self.problem, case_pulses(self))
        for test, spec in zip(self.tests, self.problem.tests):
            test.spec = spec
        self.layout = ParameterLayout.of(self.problem)
        self.base = self.layout.values(self.problem)
        self.model: PendulumModel = build_model(self.problem.model, self.layout)

    @classmethod
    def load(cls, path: str | Path) -> Case:
        return cls(load_problem(path))

    @property
    def name(self) -> str:
        return self.problem.name

    @staticmethod
    def _with_vehicle_mass(problem: Problem, loaded: list[TestData | None]) -> Problem:
        """The problem, with the vehicle mass from a test or a data header when it gives none."""
        if problem.vehicle.mass is not None:
            return problem
        masses = [t.mass for t in problem.tests if t.mass] + [d.meta["mass"] for d in loaded if d and "mass" in d.meta]
        if not masses:
            raise InputError("vehicle.mass: not given and no data header gives it")
        return problem.with_values({"vehicle.mass": masses[0]})

    def _test_case(self, i: int, test: Test, data: TestData | None) -> TestCase:
        speed = self.problem.speed(test)
        if speed is None and data is not None:
            speed = data.meta.get("speed")
        if speed is None:
            raise InputError(f"tests.{i}.speed: no impact speed (give vehicle.speed, the test's speed or a data header)")
        if test.duration is not None:
            duration = test.duration
        elif data is not None and test.data is not None and test.data.window is not None:
            duration = test.data.window[1]
        elif data is not None:
            duration = max(float(ch.time[-1]) for ch in data.channels.values())
        else:
            duration = self.problem.simulation.duration
        overrides = {"vehicle.mass": test.mass} if test.mass is not None else {}
        return TestCase(test, float(speed), float(duration), data, overrides)

    def check_data(self) -> None:
        """Refuse test data that contradict the problem's speed (see check_speed). For fits: a
        simulation may well ask what a test would do at another speed."""
        for i, test in enumerate(self.tests):
            if test.data is not None:
                check_speed(i, test.speed, test.spec, test.data)

    def test_parameters(self, test: TestCase, p: np.ndarray | None = None) -> np.ndarray:
        """Full parameter vector of one test: shared values with the test's own overrides."""
        return self.layout.with_values(self.base if p is None else p, test.overrides)

    def fit_window(self, test: TestCase) -> tuple[float, float]:
        """Time span the NLP covers for a test: the data window, else [0, duration]."""
        window = test.spec.data.window if test.spec.data is not None else None
        return (0.0, window[1]) if window else (0.0, test.duration)

    def simulate(self, p: np.ndarray | None = None, dt: float | None = None) -> dict[str, Response]:
        """Forward simulation of every test with the separate integrator."""
        return {test.name: self.simulate_test(test, self.test_parameters(test, p), dt) for test in self.tests}

    def simulate_test(self, test: TestCase, p: np.ndarray, dt: float | None = None) -> Response:
        """One test simulated with the full parameter vector `p`, output every `dt` (default
        simulation.dt) from impact to the test's duration."""
        step = dt or self.problem.simulation.dt
        grid = np.arange(0.0, test.duration + 0.5 * step, step)
        return simulate(self.model, p, test.speed, grid, self.problem.simulation)
