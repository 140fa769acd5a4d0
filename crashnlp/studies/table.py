"""A study's table.csv and figures."""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crashnlp.base.outputs import METRICS, OUTPUT, PLOTTED, shown_unit
from crashnlp.engine.schedule import map_all
from crashnlp.results.files import atomic_open
from crashnlp.studies.plan import PlannedCase
from crashnlp.studies.spec import Study, SweepEntry

if TYPE_CHECKING:
    from crashnlp.engine.executors import Executor

ACCEL_FILTER = "accel_filter"  # a test's column ("56kph.accel_filter"): the CFC class its accelerations were read through
MULTIPLIER = re.compile(r"multiplier\.(?:(?P<test>[^.]+)\.)?bound\.(?P<output>\w+)\.(?P<side>upper|lower)")  # of an output bound


def show(value: Any) -> str:
    """A swept value as the user wrote it, in YAML flow style ([null, 4 deg])."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {show(v)}" for k, v in value.items()) + "}"
    return str(value)


def write_table(path: Path, rows: list[dict[str, Any]]) -> None:
    """table.csv: the union of the rows' columns, in first-seen order; missing cells empty."""
    columns = list(dict.fromkeys(k for r in rows for k in r))
    with atomic_open(path) as fh:
        writer = csv.DictWriter(fh, columns, restval="")
        writer.writeheader()
        writer.writerows([{k: "" if v is None else v for k, v in r.items()} for r in rows])


def write_figures(
    folder: Path, study: Study, cases: list[PlannedCase], rows: list[dict], executor: Executor | None = None
) -> None:
    """The figures of `figure_jobs`, drawn on the executor's workers (else here), written to `folder`."""
    jobs = figure_jobs(study, cases, rows)
    drawn = map_all(executor, draw_figure, jobs) if executor is not None else enumerate(map(draw_figure, jobs))
    for i, png in drawn:
        if isinstance(png, BaseException):
            raise png
        folder.mkdir(parents=True, exist_ok=True)
        with atomic_open(folder / jobs[i]["file"], "wb") as fh:
            fh.write(png)


def figure_jobs(study: Study, cases: list[PlannedCase], rows: list[dict]) -> list[dict[str, Any]]:
    """Objective, metrics and swept multipliers of the solved cases against each swept entry, as plain
    data for `draw_figure`, each failed case marked at its swept value (as a grid's map marks its
    cell). With several varied entries in a grid, one figure per combination of the others.
    """
    solved = [(c, r) for c, r in zip(cases, rows) if r["status"] == "ok"]
    if not solved:
        return []
    names = ["objective"] + [
        k for k in dict.fromkeys(k for _, r in solved for k in r) if k.endswith(PLOTTED) or k.startswith("multiplier.")
    ]
    jobs = []
    for i, entry in enumerate(study.entries):
        if len(entry.values) < 2:
            continue
        groups: dict[tuple, list] = {}
        for c, r in zip(cases, rows):
            others = tuple(show(v) for j, v in enumerate(c.values) if j != i)
            groups.setdefault(others, []).append((c, r))
        for k, (others, members) in enumerate(groups.items()):
            suffix = f"-{k}" if len(groups) > 1 else ""
            where = ", ".join(f"{e.path} = {v}" for e, v in zip([e for j, e in enumerate(study.entries) if j != i], others))
            job = _curves(entry, i, members, names)
            jobs.append({"file": f"{entry.path}{suffix}.png", "title": f"{study.name}: {where or entry.path}", **job})
    return jobs


def read_through(rows: list[dict[str, Any]]) -> dict[str, str]:
    """Each test's CFC class its accelerations were read through, where its cases agree on one
    (rows written before the table kept it have none)."""
    classes: dict[str, set] = {}
    for r in rows:
        for k, v in r.items():
            if k.endswith(f".{ACCEL_FILTER}") and v:
                classes.setdefault(k.removesuffix(f".{ACCEL_FILTER}"), set()).add(v)
    return {test: cfc.pop() for test, cfc in classes.items() if len(cfc) == 1}


def shown_column(name: str, classes: dict[str, str] | None = None) -> tuple[str, float] | None:
    """A table column that is a crash metric ("56kph.peak_decel_g") or the multiplier of an output
    bound ("multiplier.56kph.bound.pitch.upper", per SI unit) as a person reads it: its label
    ("56kph: peak deceleration (g, CFC60)", the CFC class from `classes` (read_through) as the
    console's table names it; "56kph: d objective / d pitch upper bound (1/deg)") and the factor
    from the column's value to that unit; None for any other column."""
    for m in METRICS:
        if name.endswith(f".{m.key}"):
            test = name.removesuffix("." + m.key)
            return f"{test}: {m.heading_through((classes or {}).get(test))}", m.factor
    bound = MULTIPLIER.fullmatch(name)
    if bound is not None and bound["output"] in OUTPUT:
        unit, factor = shown_unit(OUTPUT[bound["output"]].unit)
        where = f"{bound['test']}: " if bound["test"] else ""
        return f"{where}d objective / d {bound['output']} {bound['side']} bound (1/{unit})", 1.0 / factor
    return None


def _curves(entry: SweepEntry, i: int, members: list, names: list[str]) -> dict[str, Any]:
    """x (in the unit a person reads the entry in, else the value number) of the solved members,
    the series sorted along it (metrics in the console's units, under its labels), the x label,
    and the x of the failed members (`failed`, on the same scale)."""
    unit, factor = shown_unit(entry.unit) if entry.unit else ("", 1.0)
    x = np.array([entry.si(c.values[i]) for c, _ in members]) * factor
    xlabel = f"{entry.path} ({unit})" if unit else entry.path
    if np.all(np.isnan(x)):
        x = np.array([float(c.index[0] if len(c.index) == 1 else c.index[i]) for c, _ in members])
        xlabel = f"{entry.path} (value number)"
    ok = np.array([r["status"] == "ok" for _, r in members])
    order = np.argsort(x[ok], kind="stable")
    series = {}
    classes = read_through([r for _, r in members])
    for n in names:
        label, scale = shown_column(n, classes) or (n, 1.0)
        series[label] = np.array([number(r.get(n)) * scale for _, r in members if r["status"] == "ok"])[order]
    return {"x": x[ok][order], "series": series, "xlabel": xlabel, "failed": np.sort(x[~ok])}


def draw_figure(job: dict[str, Any]) -> bytes:
    """A figure job as PNG bytes (in a worker, where matplotlib is imported on first use)."""
    from crashnlp.results import plots

    return plots.xy_png(job["x"], job["series"], job["xlabel"], job["title"], job["failed"])


def number(value: Any) -> float:
    """A table cell as a number: NaN for an empty or non-numeric one."""
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan
