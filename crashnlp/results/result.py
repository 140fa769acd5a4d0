"""The plain outcome of an identification or a design: frozen dataclasses, and its files.

A `Result` is built once, by the optimizer (crashnlp.optimize.outcome), from
the solved NLP; everything downstream (result files, figures, the console,
study tables, the Python API) reads it and nothing else. `Result.save(dir)`
writes what the command line writes (result.json, response and force-crush
tables, figures); `Result.load(dir)` reads it back. Everything is SI inside and
converted to report units (g, deg, ms) only as it is written.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crashnlp.base.errors import InputError, unreadable
from crashnlp.base.outputs import OUTPUT, PANELS, current_names, named_test
from crashnlp.results.files import claim, run_name, write_columns
from crashnlp.results.identified import EDITED, IdentifiedModel, same
from crashnlp.results.jsonfile import write_json
from crashnlp.results.response import (
    RESPONSE_FIGURE,
    RESPONSE_FILE,
    Response,
    read_columns,
    read_response,
    write_response_csv,
)

if TYPE_CHECKING:
    from crashnlp.problem.schema import Problem
    from crashnlp.results.plots import Job  # not at run time: matplotlib

# ignored by reproducibility checks: the only entries that change from run to run
VOLATILE = ("wall_s", "build_s", "compiled")  # how long and by which evaluator, not what: same bits either way
TAIL_SHOWN = 1.25  # the force-crush figure draws a fit's tail to this times its start


@dataclass(frozen=True)
class ChannelFit:
    """One measured channel against the model at the fitted nodes (SI)."""

    channel: str
    times: np.ndarray
    data: np.ndarray
    model: np.ndarray
    sigma: float
    rmse: float
    iso18571: dict[str, float] | None


@dataclass(frozen=True)
class ActiveConstraint:
    """An inequality at its bound: its kind, its test (None for shared), where and what it is worth.

    `multiplier` sums -lambda over the points: d objective / d bound (objective units per SI unit),
    negative where raising the bound lowers the objective; `max_multiplier` is the point's of
    largest magnitude (crashnlp.optimize.outcome.active_constraints)."""

    kind: str  # "bound", "monotone_crush", "monotone_spring", "design", "parameter_bound", ...
    name: str
    test: str | None
    points: int
    multiplier: float
    max_multiplier: float


@dataclass(frozen=True)
class SolverStats:
    return_status: str | None
    iterations: int
    objective: float | None
    wall_s: float | None
    build_s: float | None
    compiled: bool | None = None  # IPOPT called the compiled NLP functions


@dataclass(frozen=True)
class TestResult:
    """One test: the model's response on the NLP grid, the data, the fit and the audits."""

    name: str
    speed: float
    response: Response
    data: dict[str, tuple[np.ndarray, np.ndarray]]
    fit: dict[str, ChannelFit]
    metrics: dict[str, float | None]
    data_metrics: dict[str, float | None] | None
    loading_end: float
    energy: dict[str, float] | None = None
    forward_check: dict[str, Any] | None = None
    consistency: dict[str, Any] | None = None  # wall force against accelerometers (summary.channel_consistency)

    @property
    def mass(self) -> float | None:
        """The test's mass, from its energy audit (the impact energy, m v^2 / 2: result.json keeps
        no other); None without one."""
        return 2.0 * self.energy["impact_kinetic"] / self.speed**2 if self.energy else None


@dataclass(frozen=True)
class LoadingCurve:
    """The identified (or designed) loading curve, its breakpoints, a reference curve if the problem has one,
    per test with data its measured m |a| (spring and damper) against CG travel while loading,
    and the curve's 95 % band (low, high: None without a covariance)."""

    crush: np.ndarray
    force: np.ndarray
    breakpoints: np.ndarray
    values: np.ndarray
    reference: tuple[np.ndarray, np.ndarray] | None = None
    measured: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    band: tuple[np.ndarray, np.ndarray] | None = None


RESULT_FILE = "result.json"  # what `Result.save` writes into a fit's folder, and `Result.load` reads
FORCE_CRUSH_FILE = "force_crush.csv"  # the loading curve's table beside it
FORCE_CRUSH_FIGURE = "force_crush.png"
FIT_FIGURE, RESIDUAL_FIGURE = "fit.png", "residuals.png"  # a fitted test's figures in its folder
TEST_FILES = (RESPONSE_FILE, FIT_FIGURE, RESPONSE_FIGURE, RESIDUAL_FIGURE)  # in each test's folder: its response and figures


def result_entries(tests: Iterable[str]) -> list[str]:
    """The files a fit's or a design's folder gets (`write_result`, its figures), by name within it,
    for the folder's check before the solve (crashnlp.results.files.check_entries)."""
    return [RESULT_FILE, FORCE_CRUSH_FILE, FORCE_CRUSH_FIGURE, *(f"{test}/{file}" for test in tests for file in TEST_FILES)]


def result_file(path: str | Path) -> Path:
    """The result.json a path names: the file itself, or the one in a fit's folder."""
    path = Path(path)
    return path / RESULT_FILE if path.is_dir() else path


@dataclass(frozen=True)
class ResultFile:
    """A result.json read once: its bytes (what a simulation's source hashes, crashnlp.results.source),
    its JSON document as written, and `current`, the same with today's names (current_names: a result
    written before a rename reads as one written now), for a command that reads it in several places."""

    data: bytes
    document: Any
    current: Any

    @classmethod
    def read(cls, file: Path) -> ResultFile:
        """`file` read and parsed as UTF-8 JSON; OSError, UnicodeDecodeError or json.JSONDecodeError
        as reading, decoding and parsing raise them."""
        data = file.read_bytes()
        document = json.loads(data.decode("utf-8"))
        return cls(data, document, current_names(document))


def read_params(path: str | Path) -> ResultFile:
    """A result.json (or a fit's folder's) read once, its content (a result written before a rename
    too: ResultFile.current) a mapping with a 'parameters' mapping; InputError naming the file
    for one that cannot be read or is not such a mapping."""
    p = result_file(path)
    try:
        file = ResultFile.read(p)
        params = file.current["parameters"]
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except (IsADirectoryError, NotADirectoryError, PermissionError) as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise unreadable(p, exc) from None
    except (KeyError, TypeError, IndexError):
        raise InputError(f"{p}: not a result.json with a 'parameters' entry") from None
    if not isinstance(params, dict):
        raise InputError(f"{p}: 'parameters' is not a mapping")
    return file


def fit_folder(path: str | Path) -> Path:
    """The folder of the fit a path names (a result.json or its folder), whose whole Result
    `Result.load` reads; InputError for a file of another name, which it would not read."""
    file = result_file(path)
    if file.name != RESULT_FILE:
        raise InputError(f"{path}: a result is read from its folder, as RESULT_DIR/{RESULT_FILE}")
    return file.parent


@dataclass(frozen=True)
class Result:
    """What a solve produced, judged honestly, in SI."""

    name: str
    kind: str
    status: str
    solver: SolverStats
    transcription: dict[str, Any]
    parameters: dict[str, float | list[float]]
    std_errors: dict[str, float | list[float | None] | None]
    correlation: dict[str, Any]
    not_identified: tuple[str, ...]
    at_bound: dict[str, float | None]  # how far past the bound the data pull, in std; None: not identified
    active_constraints: tuple[ActiveConstraint, ...]
    tests: dict[str, TestResult]
    force_crush: LoadingCurve | None = None
    profiles: dict[str, dict] = field(default_factory=dict)
    covariance: dict[str, Any] = field(default_factory=dict)
    inequalities: tuple[str, ...] = ()  # every inequality block of the NLP, active or not
    notes: tuple[str, ...] = ()  # what was done to the problem on the way, e.g. a repaired start
    z: np.ndarray | None = field(default=None, repr=False)  # the NLP's solution vector, to warm-start a twin
    identified: IdentifiedModel | None = field(default=None, repr=False)  # the complete fitted vehicle, to predict with
    regularization: dict[str, Any] = field(default_factory=dict)  # the smoothness prior's weight and how it was chosen
    output_bounds: dict[str, tuple[float | None, float | None]] = field(default_factory=dict)  # constraints.bounds, SI
    resolution: dict[str, Any] = field(default_factory=dict)  # the spring law's breakpoints and how their number was chosen

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def takes_in_zero(self) -> tuple[str, ...]:
        """The labels of a converged fit's values whose 95 % interval takes in zero where zero means
        none (IdentifiedModel.takes_in_zero, with the fit's profiles); none for another result."""
        return self.identified.takes_in_zero(self.profiles) if self.identified is not None and self.ok else ()

    def to_json(self) -> dict[str, Any]:
        """The content of result.json (SI; metrics in the units their names say)."""
        return {
            "name": self.name,
            "kind": self.kind,
            "status": self.status,
            "solver": {"name": "ipopt", **vars(self.solver)},
            "transcription": self.transcription,
            "parameters": self.parameters,
            "std_errors": self.std_errors,
            "correlation": self.correlation,
            "not_identified": list(self.not_identified),
            "profiles": self.profiles,
            "covariance": self.covariance,
            "regularization": self.regularization,
            "output_bounds": {name: list(ends) for name, ends in self.output_bounds.items()},
            "resolution": self.resolution,
            "at_bound": self.at_bound,
            "notes": list(self.notes),
            "tests": {name: _test_json(t) for name, t in self.tests.items()},
            "active_constraints": [vars(c) for c in self.active_constraints],
            "identified_model": self.identified.to_json() if self.identified is not None else None,
        }

    def save(self, folder: str | Path, figures: bool = True) -> None:
        """result.json, responses, force-crush table and figures: what the command line writes,
        into a folder that then holds this result only (crashnlp.results.files.claim: InputError for a
        folder holding another run's results, being written by another run, or a file in its place)."""
        write_result(self, Path(folder), figures=figures)

    @classmethod
    def load(cls, folder: str | Path, file: ResultFile | None = None) -> Result:
        """A Result read back from a folder `save` wrote, or its result.json, as its files hold it:
        result.json's values to its 10 significant digits, each test's response from its
        response.csv (the outputs with a column there, to 9 digits), the loading curve from
        force_crush.csv (`_read_curve`); `file`, its result.json where the caller has read it
        already, is not read again. A path that holds no result.json is an InputError naming it
        (read_params, as `crashnlp.simulate(params=...)` reads one). What the folder does not hold,
        the loaded Result has not: the data and the fitted nodes (each channel's fit keeps its RMSE,
        sigma and ratings, its node arrays are empty), the outputs response.csv has no column for,
        and the NLP's solution vector and inequalities (`z` None, `inequalities` empty). Saved
        again, it writes the same files, to the digits of the tables, less the residual figures,
        which need the fitted nodes; its figures show no data."""
        raw = (file or read_params(folder)).current
        folder = fit_folder(folder)
        identified = IdentifiedModel.from_json(raw["identified_model"]) if raw.get("identified_model") else None
        tests = {}
        for name, t in raw["tests"].items():
            response = read_response(folder / name / RESPONSE_FILE, t.get("accel_filter"))
            tests[name] = TestResult(
                name,
                t["speed_mps"],
                response,
                {},
                {c: _fit_from_json(c, f) for c, f in t.get("fit", {}).items()},
                t["metrics"]["model"],
                t["metrics"]["data"],
                _number(t.get("loading_ends_s")),
                t.get("energy"),
                t.get("forward_check"),
                t.get("consistency"),
            )
        return cls(
            raw["name"],
            raw["kind"],
            raw["status"],
            SolverStats(
                *(raw["solver"].get(k) for k in ("return_status", "iterations", "objective", "wall_s", "build_s", "compiled"))
            ),
            raw["transcription"],
            raw["parameters"],
            raw["std_errors"],
            raw["correlation"],
            tuple(raw["not_identified"]),
            raw["at_bound"],
            tuple(ActiveConstraint(**c) for c in raw["active_constraints"]),
            tests,
            force_crush=_read_curve(folder / FORCE_CRUSH_FILE, identified),
            profiles=raw.get("profiles", {}),
            covariance=raw.get("covariance", {}),
            regularization=raw.get("regularization", {}),
            output_bounds={name: (lo, hi) for name, (lo, hi) in raw.get("output_bounds", {}).items()},
            resolution=raw.get("resolution", {}),
            notes=tuple(raw.get("notes", ())),
            identified=identified,
        )


def refuse_edited(result: Result, source: str) -> Result:
    """`result` as read back from `source` (its result.json), refused (InputError naming the file
    and the entry, "a result.json edited by hand?") where it is not as crashnlp writes it: a status
    that is not text (a null would read as converged), a test's impact speed or impact energy that
    is not a number above zero, a standard error below zero or not a number, and an identified
    model a prediction could not take (IdentifiedModel.as_problem, which loads the problem schema:
    `Result.load` itself reads with numpy alone). What reads a fit's folder back for a prediction,
    an export or a report goes through this (crashnlp.report.folders.read_result)."""
    refuse_status(result.status, source)
    for name, t in result.tests.items():
        energy = [] if t.energy is None else [(f"tests.{name}.energy.impact_kinetic", t.energy.get("impact_kinetic"))]
        for entry, value in [(f"tests.{name}.speed_mps", t.speed), *energy]:
            if not _positive(value):
                raise InputError(f"{source}: {entry} is {value}: must be a number above zero {EDITED}")
    for path, errors in result.std_errors.items():
        for i, std in enumerate(errors if isinstance(errors, list) else [errors]):
            if std is not None and not (_positive(std) or std == 0):
                where = f"{path}[{i}]" if isinstance(errors, list) else path
                raise InputError(f"{source}: std_errors.{where} is {std}: must be a number, not negative, or null {EDITED}")
    identified = result.identified.as_problem(result.name, source) if result.identified is not None else None
    for path, given in result.parameters.items():
        _refuse_another_value(path, given, identified, source)
    return result


def _refuse_another_value(path: str, value: Any, identified: Problem | None, source: str) -> None:
    """An InputError naming `source` and the entry where result.json's `parameters` give `path`
    another value than the `identified` model has (as a prediction and an export take it; None
    where the result keeps none, an older result.json), or one it has not: the report shows
    these values. Without an identified model a value need only be a finite number, or a list
    of them."""
    values = value if isinstance(value, list) else [value]
    numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)
    if identified is None:
        if not numbers:
            raise InputError(f"{source}: parameters.{path} is {json.dumps(value)}: must be a number, or a list of them {EDITED}")
        return
    theirs = identified.value_at(path)
    listed = list(theirs) if isinstance(theirs, tuple) else [theirs]
    if theirs is None or not (numbers and len(listed) == len(values) and all(map(same, values, listed))):
        has = "no such entry" if theirs is None else json.dumps(theirs)
        raise InputError(
            f"{source}: parameters.{path} is {json.dumps(value)}, where identified_model has {has}: the report would "
            f"show the one, predictions and exports take the other {EDITED}"
        )


def refuse_status(status: Any, source: str) -> None:
    """An InputError naming `source` where a result's status is not text, as a fit or a design
    writes it ("ok", or why not): a null would read as converged (`unconverged`)."""
    if not isinstance(status, str):
        raise InputError(f"{source}: status is {json.dumps(status)}: a fit or a design writes its status as text {EDITED}")


def _positive(value: Any) -> bool:
    """Whether `value` is a number above zero, finite (a bool is no number here)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and 0.0 < value < math.inf


def pull_texts(result: Result) -> dict[str, str]:
    """Each value at a bound, and how far past it the data pull as the console and the report give
    it: in standard errors, or that the data do not determine the value (`Result.at_bound`'s None);
    a design's, which has no data and no standard errors, only sits there."""
    if result.kind != "identify":
        return dict.fromkeys(result.at_bound, "at its bound")
    return {label: "not identified" if pull is None else f"{pull:.2g} std" for label, pull in result.at_bound.items()}


UNSOLVED = "rests on a solve IPOPT did not finish"  # a profile interval's end whose objective is not the profile's


def unsolved_end(profile: dict[str, Any], key: str) -> str | None:
    """The words for a profile interval's `key` ("lower", "upper") end that rests on a solve IPOPT
    did not finish (crashnlp.optimize.profile's `unsolved`: its objective is not the profile's,
    nor the end a 95 % end), as the console and the report give them; None for one that does not."""
    statuses = (profile.get("unsolved") or {}).get(key)
    return f"{UNSOLVED} ({', '.join(statuses)})" if statuses else None


def unsolved_lines(result: Result) -> list[str]:
    """A line for each profile interval end of `result` that rests on a solve IPOPT did not finish."""
    return [
        f"profile interval of {label}: its {key} end {words}"
        for label, profile in result.profiles.items()
        for key in ("lower", "upper")
        if (words := unsolved_end(profile, key))
    ]


def loading_curve_name(kind: str) -> str:
    """What a result's loading curve is: identified from data, or designed."""
    return "identified loading curve" if kind == "identify" else "designed loading curve"


def _read_curve(file: Path, identified: IdentifiedModel | None) -> LoadingCurve | None:
    """The loading curve of a force_crush.csv (None without one), its force the table's (past the
    tail's start, the tail's line), its breakpoints the identified model's within the table's
    crush, their forces read off the table; no reference, measured pulses or band, which the
    folder does not hold."""
    if not file.exists():
        return None
    columns = read_columns(file)
    crush, force = columns["crush_m"], columns["spring_force_N"]
    spring = identified.model.get("spring", {}) if identified is not None else {}
    breakpoints = np.asarray(spring.get("crush_breakpoints", ()), dtype=float)
    inside = breakpoints[breakpoints <= crush[-1]]
    return LoadingCurve(crush, force, inside, np.interp(inside, crush, force))


def _number(value: Any) -> float:
    return float("nan") if value is None else float(value)


def _test_json(t: TestResult) -> dict[str, Any]:
    out = {
        "speed_mps": t.speed,
        "loading_ends_s": t.loading_end,
        "forward_check": t.forward_check,
        "energy": t.energy,
        "metrics": {"model": t.metrics, "data": t.data_metrics},
        "fit": {c: _fit_json(f) for c, f in t.fit.items()},
        "accel_filter": t.response.accel_filter,
    }
    return out | ({"consistency": t.consistency} if t.consistency is not None else {})


def _fit_json(f: ChannelFit) -> dict[str, Any]:
    out = OUTPUT[f.channel]
    return {"rmse": f.rmse * out.factor, "unit": out.report_unit, "sigma": f.sigma * out.factor, "iso18571": f.iso18571}


def _fit_from_json(channel: str, raw: dict[str, Any]) -> ChannelFit:
    """A channel's fit as result.json keeps it (`_fit_json`), back in SI, without its nodes."""
    factor, empty = OUTPUT[channel].factor, np.zeros(0)
    return ChannelFit(channel, empty, empty, empty, raw["sigma"] / factor, raw["rmse"] / factor, raw["iso18571"])


def unconverged(status: str | None) -> tuple[str, ...]:
    """The line a file of a fit that did not converge carries first (its IPOPT status): the
    force-crush table beside its result.json, its exports (crashnlp.report.export) and its report; none for
    one that did, nor for None, the status of a simulation of a problem alone, which names no
    fit (a result.json's own status is text: `refuse_status`)."""
    if status in (None, "ok"):
        return ()
    return (f"{_ended(status)}; these values are its last iterate, not an identified model",)


def unconverged_mark(status: str | None) -> str:
    """What a figure's title or a curve's label adds for a fit that did not converge, or for a
    prediction from one, in the words of `unconverged`: '' for one that did, or for None."""
    return "" if status in (None, "ok") else f" ({_ended(status)})"


def _ended(status: str | None) -> str:
    return f"NOT CONVERGED: the fit ended {status}"


def write_result(result: Result, out: Path, figures: bool = True) -> None:
    """result.json, per-test responses, the force-crush table, and the figures after them, into a
    folder that then holds this result only (crashnlp.results.files.claim: refused where it holds another
    run's)."""
    with claim(out, run_name(result.kind, result.name), option=None):
        for name, t in result.tests.items():
            write_response_csv(out / name / RESPONSE_FILE, t.response)
        fc = result.force_crush
        if fc is not None:
            force = along_the_tail(fc, identified_tail(result), fc.crush)
            write_columns(out / FORCE_CRUSH_FILE, {"crush_m": fc.crush, "spring_force_N": force}, unconverged(result.status))
        write_json(out / RESULT_FILE, result.to_json())
        if figures:
            write_figures(result, out)


def write_figures(result: Result, out: Path) -> None:
    """Fit and residual figures per test, and the force-crush figure."""
    from crashnlp.results import plots  # matplotlib: a third of a second, only when drawing

    plots.draw(figure_jobs(result, out))


def figure_jobs(result: Result, out: Path) -> list[Job]:
    """The figures of a result as crashnlp.results.plots jobs: plain data, which a process that has
    imported matplotlib and nothing of the model draws (crashnlp.results.drawing)."""
    jobs: list[Job] = []
    for name, t in result.tests.items():
        model = {k: (t.response.time, t.response[k]) for k in PANELS}
        fit = result.kind == "identify"
        title = f"{named_test(result.name, name)}: {'fit to the data' if t.data else 'model' if fit else 'design'}"
        path = out / name / (FIT_FIGURE if fit else RESPONSE_FIGURE)
        bounds, read = result.output_bounds, t.response.accel_filter
        jobs.append(("response_figure", (path, title, model, t.data, None, _fit_notes(t), bounds, read)))
        residuals = {c: (f.times, f.model - f.data) for c, f in t.fit.items() if f.times.size}  # none read back
        if residuals:
            title = f"{named_test(result.name, name)}: residuals (model - data)"
            jobs.append(("residual_figure", (out / name / RESIDUAL_FIGURE, title, residuals)))
    if result.force_crush is not None:
        jobs.append(_force_crush_job(result, result.force_crush, out))
    return jobs


def _fit_notes(t: TestResult) -> dict[str, str]:
    """Each fitted channel's RMSE (in its panel's unit) and ISO 18571 rating, as its panel shows them."""
    notes = {}
    for c, f in t.fit.items():
        rating = f", ISO 18571 {f.iso18571['overall']:.3f}" if f.iso18571 else ""
        notes[c] = f"RMSE {OUTPUT[c].shown(f.rmse)}{rating}"
    return notes


def identified_tail(result: Result) -> dict[str, float] | None:
    """The identified loading curve's tail (its start, m, and slope, N/m), None without one."""
    return result.identified.tail_line if result.identified is not None else None


def along_the_tail(fc: LoadingCurve, tail: dict[str, float] | None, crush: np.ndarray) -> np.ndarray:
    """The loading curve at `crush` as the predictions and the exports take it: the fitted curve
    `fc` up to the tail's start, past it the tail's line from the curve's force there (its trend
    past the crush the fitted tests reached: crashnlp.models.tail)."""
    force = np.interp(crush, fc.crush, fc.force)
    if tail is None:
        return force
    at_start = float(np.interp(tail["start"], fc.crush, fc.force))
    return np.where(crush <= tail["start"], force, at_start + tail["slope"] * (crush - tail["start"]))


def _force_crush_job(result: Result, fc: LoadingCurve, out: Path) -> Job:
    """The force-crush figure: the identified or designed loading curve (to the tail's start, then the tail
    predictions follow) and its 95 % band, the unloading from each test's largest crush, the
    reference, and behind them each test's measured m |a| while loading."""
    model = result.identified.model if result.identified is not None else {}
    tail = identified_tail(result)
    inside = fc.crush <= tail["start"] if tail is not None else np.ones(fc.crush.size, bool)
    curves = {loading_curve_name(result.kind): (fc.crush[inside], fc.force[inside])}
    if tail is not None:
        x = np.linspace(tail["start"], TAIL_SHOWN * tail["start"], 20)
        curves["past the fitted crush: its trend"] = (x, along_the_tail(fc, tail, x))
    unloading = model.get("unloading", {})
    if unloading.get("law") == "plastic":
        stiffness = float(unloading["stiffness"])
        for name, t in result.tests.items():
            top = float(np.max(t.response["crush"]))
            force = float(np.interp(top, fc.crush, fc.force))
            label = f"unloading at {stiffness / 1e6:.3g} kN/mm" + (f" ({name})" if len(result.tests) > 1 else "")
            curves[label] = (np.array([top - force / stiffness, top]), np.array([0.0, force]))
    if fc.reference is not None:
        curves["reference"] = fc.reference
    several = len(fc.measured) > 1
    measured = {"measured m|a| vs CG travel" + (f" ({name})" if several else ""): c for name, c in fc.measured.items()}
    title = f"{result.name}: {loading_curve_name(result.kind)}"
    band = (fc.crush[inside], fc.band[0][inside], fc.band[1][inside]) if fc.band is not None else None
    return ("force_crush_figure", (out / FORCE_CRUSH_FIGURE, curves, (fc.breakpoints, fc.values), title, measured, band))
