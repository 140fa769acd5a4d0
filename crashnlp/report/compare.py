"""`crashnlp compare-results`: fits and simulations on one set of axes, with their bands.

Two or more folders crashnlp wrote, fits (result.json) or simulations (simulation.json) in any
mix, read through their loaders (crashnlp.report.folders): each test of each folder is one curve in its
own colour, named by its problem, its test and its speed (a pickup predicted at 48, 56 and
64 km/h; fit A against fit B of the same vehicle), its mass where that is not the fitted one, and
the status of a fit that did not converge (`labelled`). A simulation's 95 % bands are shaded; a fit's
folder holds none (its curve is the fit; `crashnlp simulate RESULT_DIR` gives its own tests'
bands). Written into the output folder: a figure per quantity (QUANTITIES, and the barrier force
against the crush), the crash metrics side by side (metrics.csv, with the intervals), and the
page of both (compare.html, through the report's templates). Every folder is read before
anything is written: a bad one is an InputError naming it, and nothing is written.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.base.outputs import OUTPUT, PREDICTED, Output, named_test
from crashnlp.report import TEMPLATES, embedded_figures
from crashnlp.report.folders import folder_kind, read_result, read_simulation
from crashnlp.results.files import atomic_open, check_output, claim, run_name
from crashnlp.results.response import Response
from crashnlp.results.result import unconverged_mark

PAGE = "compare.html"
METRICS = "metrics.csv"
QUANTITIES = ("accel", "velocity", "crush", "pitch")  # against time, one figure each
FORCE_CRUSH = "force_crush.png"
RUN = run_name("compare-results", "fits and simulations")  # what its output folder's record names


@dataclass(frozen=True)
class Curve:
    """One test of one folder as the comparison shows it: its legend, its response (SI), its 95 %
    bands (output -> (low, high) SI; none for a fit), its crash metrics and their intervals."""

    label: str
    folder: Path
    response: Response
    bands: dict[str, tuple[np.ndarray, np.ndarray]]
    metrics: dict[str, float | None]
    intervals: dict[str, tuple[float, float] | None]
    mass: float | None = None  # kg; None where the folder keeps none (a fit's without its energy audit)
    past_its_fit: bool = False  # a prediction at a mass past the masses its fit was fitted at
    status: str | None = None  # of the fit (a simulation's: of the fit it took its parameters from); None: of none


def compare_results(folders: list[Path], out: Path) -> list[Curve]:
    """The comparison of `folders` written into `out`, a folder of its own run (RUN: another
    run's folder, a fit's say, is refused, as every command refuses one: crashnlp.results.files);
    InputError, with nothing written, for fewer than two folders, or one that is not a fit's or a
    simulation's."""
    if len(folders) < 2:
        raise InputError(f"compare-results: {len(folders)} folder given: give two or more (fits or simulations)")
    out = check_output(out, RUN)
    curves = distinct(labelled([curve for folder in folders for curve in read_curves(folder)]))
    from crashnlp.results import plots  # matplotlib: only once every folder has read

    with claim(out, RUN):
        for name in QUANTITIES:
            plots.overlay_figure(out / f"{name}.png", *_over_time(name, curves))
        title, xlabel, ylabel, series = _force_crush(curves)
        banded = any(band is not None for *_, band in series)
        plots.overlay_figure(out / FORCE_CRUSH, title, xlabel, ylabel, series, FORCE_CRUSH_NOTE if banded else "")
        write_metrics(out / METRICS, curves)
        with atomic_open(out / PAGE) as fh:
            fh.write(page(curves, out))
    return curves


def read_curves(folder: Path) -> list[Curve]:
    """The curves of a fit's or a simulation's folder, one per test, each named by its problem, its
    test and its speed (`labelled` adds the rest)."""
    kind = folder_kind(folder)
    if kind == "study":
        raise InputError(f"{folder}: a study's folder: compare fits or simulations (a study's report maps its cases)")
    if kind == "result":
        result = read_result(folder)
        what = "fit" if result.kind == "identify" else result.kind
        return [
            Curve(_label(result.name, name, what, t.speed), folder, t.response, {}, t.metrics, {}, t.mass, status=result.status)
            for name, t in result.tests.items()
        ]
    name, tests = read_simulation(folder)
    return [
        Curve(
            _label(name, t.name, "predicted", t.speed),
            folder,
            t.response,
            t.bands,
            t.metrics,
            t.intervals,
            t.mass,
            "mass_kg" in t.extrapolation,
            (t.source.get("result") or {}).get("status"),
        )
        for t in tests.values()
    ]


def _label(name: str, test: str, what: str, speed: float) -> str:
    return f"{named_test(name, test)}, {what} at {speed * 3.6:.1f} km/h"


def labelled(curves: list[Curve]) -> list[Curve]:
    """The curves, each label naming its mass where that is not the fitted one (every curve's where
    the curves compared do not share one mass; a prediction's past its fit's masses, a what-if of
    the mass alone), and where its fit did not converge, its status."""
    masses = {round(c.mass) for c in curves if c.mass is not None}
    out = []
    for c in curves:
        mass = f", {c.mass:.0f} kg" if c.mass is not None and (len(masses) > 1 or c.past_its_fit) else ""
        out.append(replace(c, label=f"{c.label}{mass}{unconverged_mark(c.status)}"))
    return out


def distinct(curves: list[Curve]) -> list[Curve]:
    """The curves, each label that two share told apart by its folder."""
    labels = [c.label for c in curves]
    return [replace(c, label=f"{c.label} ({c.folder})") if labels.count(c.label) > 1 else c for c in curves]


Series = tuple[str, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray] | None]  # label, x, y, band's outline


def _outline(x: np.ndarray, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The outline of the band from `low` to `high` over `x`, as a polygon (x, y)."""
    return np.concatenate([x, x[::-1]]), np.concatenate([low, high[::-1]])


def shared_class(curves: list[Curve]) -> str | None:
    """The CFC class every curve's acceleration was read through; None where they differ or none has one."""
    classes = {c.response.accel_filter for c in curves}
    return next(iter(classes)) if len(classes) == 1 else None


def _over_time(name: str, curves: list[Curve]) -> tuple[str, str, str, list[Series]]:
    """One output against time for every curve, in its figure's unit: (title, x label, y label, series),
    the acceleration's label naming the CFC class the curves share, as the metric table does."""
    output = OUTPUT[name]
    f = output.plot_factor
    series: list[Series] = []
    for c in curves:
        t = c.response.time * 1e3
        band = c.bands.get(name)
        if band is None:
            series.append((c.label, t, c.response[name] * f, None))
        else:
            series.append((f"{c.label}, 95 % band", t, c.response[name] * f, _outline(t, band[0] * f, band[1] * f)))
    return f"{output.label.split(' (')[0]} against time", "time (ms)", output.label_through(shared_class(curves)), series


# what a force-crush figure's band is: each instant's band of a prediction, not the loading curve's
FORCE_CRUSH_NOTE = (
    "A band is a prediction's 95 % band at each instant of its simulation, its form terms (mostly the peak's) included:\n"
    "not an uncertainty of the loading curve, which the fit's own force_crush.png shades from its parameters."
)


def _force_crush(curves: list[Curve]) -> tuple[str, str, str, list[Series]]:
    """The barrier force against the crush for every curve (in their figures' units), and while the crush grows
    (to its max: a band that turns back would cover itself) the force's band along the crush,
    else the crush's band across the force, whichever the prediction has."""
    x, y = OUTPUT["crush"], OUTPUT["barrier_force"]
    series: list[Series] = []
    for c in curves:
        crush, force = c.response["crush"] * x.plot_factor, c.response["barrier_force"] * y.plot_factor
        loading = slice(0, int(np.argmax(crush)) + 1)
        band: tuple[np.ndarray, np.ndarray] | None = None
        label = c.label
        if "barrier_force" in c.bands:
            low, high = (b[loading] * y.plot_factor for b in c.bands["barrier_force"])
            band, label = _outline(crush[loading], low, high), f"{label}, {_band_of(y)}"
        elif "crush" in c.bands:
            low, high = (b[loading] * x.plot_factor for b in c.bands["crush"])
            band, label = _outline(force[loading], low, high)[::-1], f"{label}, {_band_of(x)}"
        series.append((label, crush, force, band))
    return "barrier force against crush", x.label, y.label, series


def _band_of(output: Output) -> str:
    """A force-crush curve's band in its legend: of which output, at each instant (FORCE_CRUSH_NOTE)."""
    return f"95 % band of the {output.label.split(' (')[0]} at each instant"


def metric_table(curves: list[Curve]) -> tuple[list[str], list[list[str]]]:
    """The crash metrics side by side, as the console prints a prediction's: (head, rows), a cell
    "value [low, high]" where the curve has a 95 % interval, "-" where it has no value; the peak's
    row names the CFC class the curves' accelerations were read through, or where they differ,
    each cell its own ("unfiltered" for none)."""
    head = ["metric", *(c.label for c in curves)]
    shared = shared_class(curves)  # else each cell of a peak names its own class
    rows = []
    for m in PREDICTED:
        cells = []
        for c in curves:
            cell = m.cell(c.metrics.get(m.key), c.intervals.get(m.key))
            own = m.read_through(c.response.accel_filter or "unfiltered") if shared is None else None
            cells.append(f"{cell} ({own})" if own else cell)
        rows.append([m.heading_through(shared, short=True), *cells])
    return head, rows


def write_metrics(path: Path, curves: list[Curve]) -> None:
    """metrics.csv: a row per curve, its folder, then each metric in the console's unit with its
    interval's ends (empty where there is none)."""
    head = ["curve", "folder", "accel_filter"]  # the CFC class the curve's acceleration, and its peak, were read through
    for m in PREDICTED:
        head += [m.column, f"{m.column}_low", f"{m.column}_high"]
    with atomic_open(path) as fh:
        writer = csv.writer(fh)
        writer.writerow(head)
        for c in curves:
            row = [c.label, str(c.folder), c.response.accel_filter or ""]
            for m in PREDICTED:
                value, band = c.metrics.get(m.key), c.intervals.get(m.key)
                row += [_number(value, m.factor), *(_number(end, m.factor) for end in (band or (None, None)))]
            writer.writerow(row)


def _number(value: float | None, factor: float) -> str:
    return "" if value is None else f"{value * factor:.9g}"


def page(curves: list[Curve], out: Path) -> str:
    """compare.html: the folders, the metrics side by side and the figures written into `out`, embedded."""
    head, rows = metric_table(curves)
    names = [f"{name}.png" for name in QUANTITIES] + [FORCE_CRUSH]
    figures = embedded_figures(out, names, "")
    return TEMPLATES.get_template("compare.html.j2").render(
        title=f"comparison of {len(curves)} curves", curves=curves, head=head, rows=rows, figures=figures
    )
