"""Result files: result.json, response and force-crush tables, figures, from a plain Result.

Everything here is SI inside and converted to report units (g, deg, ms) only as
it is written. Figures are drawn after the result files.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crashnlp.case import Case
from crashnlp.files import write_columns
from crashnlp.jsonfile import write_json
from crashnlp.outputs import COLUMNS, MEASURABLE
from crashnlp.prediction import PredictedTest, response_columns
from crashnlp.result import Result
from crashnlp.simulation import Response, write_response_csv
from crashnlp.summary import data_curves

if TYPE_CHECKING:
    from crashnlp.plots import Job  # not at run time: matplotlib

# ignored by reproducibility checks: the only entries that change from run to run
VOLATILE = ("wall_s", "build_s", "compiled")  # how long and by which evaluator, not what: same bits either way


def read_response(path: Path) -> Response:
    """A response.csv back in SI (the registry's written outputs)."""
    table = np.genfromtxt(path, delimiter=",", names=True)
    outputs = {o.name: table[o.column] / o.factor for o in COLUMNS}
    return Response(np.asarray(table["time_s"]), outputs, np.zeros((0, table.size)))


def write_result(result: Result, out: Path, figures: bool = True) -> None:
    """result.json, per-test responses, the force-crush table, and the figures after them."""
    for name, t in result.tests.items():
        write_response_csv(out / name / "response.csv", t.response.time, t.response.outputs)
    fc = result.force_crush
    if fc is not None:
        write_columns(out / "force_crush.csv", {"crush_m": fc.crush, "spring_force_N": fc.force})
    write_json(out / "result.json", result.to_json())
    if figures:
        write_figures(result, out)


def write_figures(result: Result, out: Path) -> None:
    """Fit and residual figures per test, and the force-crush figure."""
    from crashnlp import plots  # matplotlib: a third of a second, only when drawing

    plots.draw(figure_jobs(result, out))


def figure_jobs(result: Result, out: Path) -> list[Job]:
    """The figures of a result as crashnlp.plots jobs: plain data, which a process that has
    imported matplotlib and nothing of the model draws (crashnlp.drawing)."""
    jobs: list[Job] = []
    for name, t in result.tests.items():
        model = {k: (t.response.time, t.response[k]) for k in MEASURABLE}
        jobs.append(("response_figure", (out / name / "fit.png", f"{result.name}: {name}", model, t.data)))
        residuals = {c: (f.times, f.model - f.data) for c, f in t.fit.items()}
        if residuals:
            jobs.append(("residual_figure", (out / name / "residuals.png", f"{result.name}: {name} residuals", residuals)))
    fc = result.force_crush
    if fc is not None:
        curves = {"identified loading curve": (fc.crush, fc.force)}
        if fc.reference is not None:
            curves["reference"] = fc.reference
        jobs.append(("force_crush_figure", (out / "force_crush.png", curves, (fc.breakpoints, fc.values), result.name)))
    return jobs


def write_simulation(name: str, tests: dict[str, PredictedTest], out: Path) -> dict:
    """response.csv (with the bands' columns), metrics, intervals and extrapolation of each
    simulated test, and simulation.json; the figures are `simulation_figure_jobs`, drawn by the
    caller (crashnlp.drawing)."""
    summary: dict[str, Any] = {"name": name, "tests": {}}
    for test in tests.values():
        r = test.response
        write_response_csv(out / test.name / "response.csv", r.time, r.outputs, response_columns(test))
        entry: dict[str, Any] = {"speed_mps": test.speed, "mass_kg": test.mass, "metrics": test.metrics}
        if test.intervals:
            entry["intervals"] = {k: None if v is None else list(v) for k, v in test.intervals.items()}
            entry["extrapolation"] = test.extrapolation
        if test.notes:
            entry["notes"] = list(test.notes)
        summary["tests"][test.name] = entry
    write_json(out / "simulation.json", summary)
    return summary


def simulation_figure_jobs(case: Case, tests: dict[str, PredictedTest], out: Path) -> list[Job]:
    """A response figure per simulated test, with its data behind it and its 95 % band shaded,
    as crashnlp.plots jobs."""
    jobs: list[Job] = []
    for test in case.tests:
        predicted = tests[test.name]
        r = predicted.response
        model = {k: (r.time, r[k]) for k in MEASURABLE}
        bands = {k: (r.time, *band) for k, band in predicted.bands.items()}
        title = f"{case.name}: {test.name}"
        jobs.append(("response_figure", (out / test.name / "response.png", title, model, data_curves(test), bands)))
    return jobs
