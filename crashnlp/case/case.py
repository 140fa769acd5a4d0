"""A problem made ready to compute: data loaded, the problem completed, parameters laid out, model built.

`Case(problem)` runs the steps in order (like PyBaMM's Simulation): load the tests'
data (crashnlp.case.testcase), complete what the problem leaves out from them
(crashnlp.case.completion), lay out the parameters, build the symbolic model. Shared by
simulate, identify, design and studies.
"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.base.records import Record
from crashnlp.case.checks import named
from crashnlp.case.completion import complete, measured_pulses
from crashnlp.case.testcase import TestCase, check_data, check_speed, load_tests
from crashnlp.models.form import CrashModel, build_model, form_class
from crashnlp.models.parameters import ParameterLayout
from crashnlp.models.simulation import simulate
from crashnlp.models.tail import Curve
from crashnlp.problem import Problem, load_problem
from crashnlp.problem.forms import READ_BY
from crashnlp.problem.schema import CollocationSpec, MultipleShootingSpec
from crashnlp.results.response import Response

__all__ = ["Case", "TestCase", "case_of", "check_speed"]


class Case:
    """Problem + data + parameter layout + symbolic model.

    What the problem leaves out (vehicle mass, breakpoints, spring values, unloading
    stiffness, estimate) is filled in from the data (crashnlp.case.completion); `problem` is the
    completed copy, and the problem it is given is not changed; `resolution` says how finely
    its spring law follows the data's loading curve and who chose that (None without data).
    """

    def __init__(self, problem: Problem):
        loaded, tests = load_tests(problem)
        self.problem, self.resolution = complete(loaded, measured_pulses(loaded, tests))
        self.tests = [dataclasses.replace(test, spec=spec) for test, spec in zip(tests, self.problem.tests)]
        self.layout = ParameterLayout.of(self.problem)
        self.base = self.layout.values(self.problem)
        form_class(self.problem.model.form).check(self.problem)
        self.model: CrashModel = build_model(self.problem.model, self.layout)

    def with_start(self, values: dict[str, Any]) -> Case:
        """The same case, its start (`base`) with `values` (dotted paths, SI) in place of the problem's."""
        other = copy.copy(self)
        other.base = self.layout.with_values(self.base, values)
        return other

    def at(self, speed: float | None = None, mass: float | None = None) -> Case:
        """The same case with every test at `speed` (m/s) and `mass` (kg) where given: a what-if.
        The data stay as they were loaded, with the conditions they were recorded at
        (TestCase.recorded), so that a prediction can tell they are another test's."""
        other = copy.copy(self)
        other.tests = [
            dataclasses.replace(
                test,
                speed=test.speed if speed is None else speed,
                overrides=test.overrides if mass is None else {**test.overrides, "vehicle.mass": mass},
            )
            for test in self.tests
        ]
        return other

    def with_transcription(self, transcription: MultipleShootingSpec | CollocationSpec) -> Case:
        """The same case (data, completed problem, start, model) transcribed otherwise."""
        other = copy.copy(self)
        other.problem = self.problem.model_copy(update={"transcription": transcription})
        return other

    @classmethod
    def load(cls, path: str | Path) -> Case:
        """The Case of a problem file."""
        return cls(load_problem(path))

    @property
    def name(self) -> str:
        return self.problem.name

    def unread_given(self) -> list[str]:
        """The entries of READ_BY (vehicle keys) the problem gives of which its model form reads
        nothing: an engine with any of its entries set, a crush offset other than 0."""
        vehicle, slices = self.problem.vehicle, self.layout.slices()
        unread = []
        for key in READ_BY:
            value = getattr(vehicle, key)
            if key not in vehicle.model_fields_set or not value:
                continue
            if isinstance(value, Record):
                paths = [f"vehicle.{key}.{k}" for k in value.model_fields_set if getattr(value, k) is not None]
            else:
                paths = [f"vehicle.{key}"]
            given = [path for path in paths if path in slices]
            if given and len(self.model.unread(given)) == len(given):
                unread.append(key)
        return unread

    def refuse_unread_given(self, source: str | None = None) -> None:
        """Refuse a vehicle entry the problem gives that its form reads nothing of (`unread_given`),
        naming `source` where given: a user who meant the form that reads it and left out
        `model.form` would get a fit or a simulation without it, and no word of it."""
        unread = self.unread_given()
        if unread:
            raise InputError(
                f"{f'{source}: ' if source else ''}vehicle.{unread[0]}: model.form {self.problem.model.form} does not read it "
                f"(model.form: {READ_BY[unread[0]]} does); leave it out, or give that form"
            )

    def check_data(self) -> None:
        """Refuse test data that contradict the problem's speed or mass, or end before a fit's duration
        (crashnlp.case.testcase.check_data)."""
        vehicle = self.problem.vehicle
        check_data(self.tests, vehicle.known_mass, vehicle.cg_above_impact < 0, vehicle.speed is not None)

    def test_parameters(self, test: TestCase, p: np.ndarray | None = None) -> np.ndarray:
        """Full parameter vector of one test: shared values with the test's own overrides."""
        return self.layout.with_values(self.base if p is None else p, test.overrides)

    def fit_window(self, test: TestCase) -> tuple[float, float]:
        """Time span the NLP covers for a test: the data window, else [0, duration]."""
        window = test.spec.data.window if test.spec.data is not None else None
        return (0.0, window[1]) if window else (0.0, test.duration)

    def loading_curve(self, p: np.ndarray) -> Curve:
        """The front end's loading force (N) as a function of crush (m, a numpy array) at the
        parameters `p`: the model's own law, smoothing and tail. The curve mapped over a number
        of crushes is built once per model and number (the uncertainty band asks for it twice
        per estimate)."""
        curve = self.model.loading_curve
        mapped = lambda n: self.model.cached(("loading_curve", n), lambda: curve.map(n))
        return lambda crush: np.asarray(mapped(crush.size)(crush, p)).ravel()

    def simulate(self, p: np.ndarray | None = None, dt: float | None = None) -> dict[str, Response]:
        """Forward simulation of every test with the separate integrator."""
        return {test.name: self.simulate_test(test, self.test_parameters(test, p), dt) for test in self.tests}

    def simulate_test(self, test: TestCase, p: np.ndarray, dt: float | None = None) -> Response:
        """One test simulated with the full parameter vector `p`, output every `dt` (default
        simulation.dt) from impact to the test's duration."""
        step = dt or self.problem.simulation.dt
        grid = np.arange(0.0, test.duration + 0.5 * step, step)
        return simulate(self.model, p, test.speed, grid, self.problem.simulation)


def case_of(problem: Problem, source: str | None = None) -> Case:
    """Case(problem), its input errors naming `source` (a file; the problem's name when None)."""
    with named(source or problem.name):
        return Case(problem)
