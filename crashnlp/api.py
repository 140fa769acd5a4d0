"""The Python API: problems in, plain results out.

    import crashnlp
    problem = crashnlp.load("problems/pickup-56kph.yaml")      # validated, immutable
    result = crashnlp.identify(problem)                         # a crashnlp.Result
    faster = problem.with_values({"vehicle.speed": "64 km/h"})
    sims = crashnlp.simulate(faster, params=result)              # test -> PredictedTest (SI arrays)
    sims["56kph"].intervals["peak_decel_g"]; sims["56kph"].extrapolation
    crashnlp.simulate(problem, params=result, speed="64 km/h", mass="2700 kg")   # a what-if, every test

Every solve goes through crashnlp.optimize.pipeline (every check, then the steps), as the
command line's and a study's do; the command line is a thin layer for arguments,
console and exit codes over that pipeline.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from crashnlp.base.errors import InputError
from crashnlp.problem import Problem, load_problem
from crashnlp.results.result import Result

if TYPE_CHECKING:
    from crashnlp.optimize.comparison import Comparison
    from crashnlp.results.identified import IdentifiedModel
    from crashnlp.results.simulation import PredictedTest


def load(path: str | Path) -> Problem:
    """A problem file, validated (units converted to SI, data files checked)."""
    return load_problem(_path(path, "the path of a problem file"))


def _path(given: object, expected: str) -> str | Path:
    """`given`, a path (a str, or any os.PathLike); TypeError naming what was `expected` for anything
    else (a dict, None)."""
    if isinstance(given, str):
        return given
    if not isinstance(given, os.PathLike):
        raise TypeError(f"expected {expected} (str or Path), got {type(given).__name__}")
    return Path(given)


def _problem(problem: Problem | str | Path) -> Problem:
    return problem if isinstance(problem, Problem) else load_problem(_path(problem, "a Problem or the path of a problem file"))


def _source(problem: Problem | str | Path) -> str | None:
    """The file a problem was given as, which its input errors name (None: the problem's name)."""
    return None if isinstance(problem, Problem) else str(_path(problem, "a Problem or the path of a problem file"))


def _solve(problem: Problem | str | Path, kind: str, verbose: bool, progress: TextIO | None) -> Result:
    """crashnlp.optimize.pipeline.solve_problem on the problem, refusing another `kind` than the one asked
    for; its input errors name the file when it is given as one."""
    from crashnlp.optimize.pipeline import solve_problem

    validated = _problem(problem)
    if validated.kind != kind:
        other = "design" if kind == "identify" else "identify"
        raise InputError(f"{_source(problem) or validated.name}: kind is {validated.kind!r}; use crashnlp.{other}")
    return solve_problem(validated, _source(problem), verbose, progress)


def identify(problem: Problem | str | Path, verbose: bool = False, progress: TextIO | None = None) -> Result:
    """Fit the problem's estimated parameters to its tests' data."""
    return _solve(problem, "identify", verbose, progress)


def design(problem: Problem | str | Path, verbose: bool = False, progress: TextIO | None = None) -> Result:
    """Choose the problem's free parameters for its design goal."""
    return _solve(problem, "design", verbose, progress)


def simulate(
    problem: Problem | str | Path | Result,
    params: Result | str | Path | dict[str, Any] | None = None,
    dt: float | str | None = None,
    speed: float | str | None = None,
    mass: float | str | None = None,
) -> dict[str, PredictedTest]:
    """Forward simulation of every test: test name -> PredictedTest, a mapping of output key ->
    array in SI with the unit in the key ("time_s", "crush_m", "accel_mps2"; crashnlp.base.outputs
    lists them), with the test's crash metrics.

    `params` a Result, or a result.json (of any name) or its folder, read as `crashnlp simulate
    --params` reads it (crashnlp.results.params): the identified vehicle it carries is put
    into the problem first (crashnlp.results.identified.apply: the problem may be the minimal one
    it was fitted from, or name only a new speed, mass or duration; a problem file may leave out
    its vehicle and model, which then come from the result), and each test also gets 95 %
    intervals of its metrics, bands of its curves and how far it lies past the identified range
    (crashnlp.analysis.prediction); a fit that did not converge gives no intervals or bands, and
    a note says so.
    `params` a dict of dotted paths: those values replace the problem's, refused where the command
    line refuses a result.json's (crashnlp.problem.parameters: an InputError naming the key).
    `problem` a Result, or a fit's result.json or its folder (no `params`): its own tests with its
    identified vehicle, as `params`, as `crashnlp simulate FOLDER` reads it
    (crashnlp.report.folders.result_alone).
    `dt` ("0.1 ms"; a number is s): the output step, read and refused as `--dt` is
    (crashnlp.analysis.prediction.output_step).
    `speed`, `mass` ("64 km/h", "1650 kg"; a number is SI): a what-if, every test at that speed
    and mass. A test that then runs at other conditions than its data were recorded at gets no
    data (PredictedTest.data) and a note saying why.
    Each test's `source` records the problem file and the fit (crashnlp.results.source: a file's
    path, name, sha256, status and form; a Result in memory, the sha256 of its JSON form)."""
    from crashnlp.analysis.prediction import output_step, own_tests, traced
    from crashnlp.case.case import case_of
    from crashnlp.problem.schema import what_if
    from crashnlp.results.params import given_result, with_params
    from crashnlp.results.source import simulation_source

    if isinstance(params, os.PathLike) and not isinstance(params, Path):
        params = Path(params)
    if params is not None and not isinstance(params, (Result, str, Path, dict)):
        raise TypeError(
            "crashnlp.simulate: params: expected a Result, a result.json or its folder (str or Path), or a dict "
            f"of dotted paths to values, got {type(params).__name__}"
        )
    step = output_step(dt)
    new_speed, new_mass = what_if(speed, mass)
    source = None if isinstance(problem, Result) else _source(problem)
    given = given_result(source) if source is not None else None
    if isinstance(problem, Result):
        if params is not None:
            raise InputError("crashnlp.simulate: a Result is simulated alone (its own tests), or as params of a problem")
        simulated, identified = own_tests(problem, problem.name), problem.identified
        record = simulation_source(None, problem)
    elif given is not None:
        from crashnlp.report.folders import result_alone  # the report's package: not for a problem file's run

        named = params if params is None or isinstance(params, (str, Path)) else f"({type(params).__name__})"
        simulated, identified, read = result_alone(given, named, "params=")
        record = simulation_source(source, source, file=read)
    elif isinstance(params, (str, Path)):
        simulated, identified, read = with_params(problem, params)
        record = simulation_source(source, params, file=read)
    else:
        simulated, identified = _with_given(problem, params)
        record = simulation_source(
            source, params if isinstance(params, Result) else None, params if isinstance(params, dict) else None
        )
    return traced(case_of(simulated, source).at(new_speed, new_mass), identified, step, record)


def _with_given(problem: Problem | str | Path, params: Result | dict[str, Any] | None) -> tuple[Problem, IdentifiedModel | None]:
    """(problem, identified model) of a problem and a Result in memory or a dict of values: the
    Result's identified vehicle put into the problem, or its values (the dict's) entry by entry
    (crashnlp.problem.parameters, naming crashnlp.simulate); the identified model is None then."""
    from crashnlp.problem.parameters import with_parameters
    from crashnlp.results.identified import apply, load_applied

    identified = params.identified if isinstance(params, Result) else None
    if identified is not None:
        if isinstance(problem, Problem):
            return apply(problem, identified, problem.name), identified
        return load_applied(problem, identified, str(problem)), identified
    values = params.parameters if isinstance(params, Result) else params
    return (with_parameters(_problem(problem), values, "crashnlp.simulate") if values else _problem(problem)), None


def compare(
    problem: Problem | str | Path, progress: TextIO | None = None, forms: str | Sequence[str] | None = None
) -> Comparison:
    """Fit model forms (`forms`, default crashnlp.problem.forms.COMPARED and the problem's own
    `model.form`; a name alone is one form, as `--forms` takes it, and none is refused) to the
    problem's tests and choose one by
    what the fits did not see: leave-one-test-out prediction with two or more tests, BIC with one
    (crashnlp.optimize.comparison); `progress`: a stream for a line per fit."""
    from crashnlp.optimize.comparison import compare as compare_forms

    return compare_forms(_problem(problem), _source(problem), progress, forms)


def study(
    path: str | Path, executor: str = "local", workers: int | None = None, out: str | Path | None = None
) -> list[dict[str, Any]]:
    """Run a study file; its table as rows (also written to its folder, as the command writes it)."""
    from crashnlp.studies.run import run_study

    return run_study(path, out, executor=executor, workers=workers, progress=False)
