"""`crashnlp report`: a folder crashnlp wrote, as one self-contained HTML page to hand on.

A fit or design (result.json), a simulation (simulation.json) or a study (cases/) is read
through its loaders (crashnlp.report.folders) and rendered by the Jinja2 templates shipped beside this
module (templates/*.html.j2). Every figure is embedded as a base64 PNG: the folder's own
figures, and the maps drawn here (the estimates' correlations; a two-entry grid study's
objective and metrics). The style is inline and nothing is fetched, so the page reads offline,
travels as one file and prints (its print stylesheet). Numbers are SI inside and shown in the
units the console shows them in (crashnlp.base.outputs).
"""

from __future__ import annotations

import base64
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jinja2
import numpy as np

from crashnlp.base.outputs import OUTPUT, PLOTTED, PREDICTED, TABLED, Z95, shown_unit, significant
from crashnlp.report.folders import folder_kind, read_result, read_simulation, read_study
from crashnlp.results.files import OutputKind, atomic_open, check_writable_file, deriving, recorded_name
from crashnlp.results.identified import takes_in_zero_note
from crashnlp.results.response import RESPONSE_FIGURE
from crashnlp.results.result import (
    FIT_FIGURE,
    FORCE_CRUSH_FIGURE,
    RESIDUAL_FIGURE,
    UNSOLVED,
    Result,
    loading_curve_name,
    pull_texts,
    unconverged,
    unsolved_end,
)
from crashnlp.results.simulation import extrapolation_line
from crashnlp.results.source import UNRECORDED, source_line
from crashnlp.studies.table import number, read_through, shown_column

if TYPE_CHECKING:
    from crashnlp.results.simulation import PredictedTest

REPORT = "report.html"
GENERATOR = "crashnlp report"  # every page's generator (its <meta name="generator">)
REPORT_FILE = OutputKind("report")
RATINGS = ("corridor", "phase", "magnitude", "slope", "overall")  # ISO/TS 18571's sub-ratings and its overall rating

TEMPLATES = jinja2.Environment(  # the pages of crashnlp report and crashnlp compare-results
    loader=jinja2.PackageLoader("crashnlp.report", "templates"),
    autoescape=True,
    undefined=jinja2.StrictUndefined,  # a name the page uses and the context lacks fails here, not as a blank
    trim_blocks=True,
    lstrip_blocks=True,
)
TEMPLATES.globals["generator"] = GENERATOR


def write_report(folder: Path, out: Path | None = None) -> Path:
    """The report of `folder` written to `out` (default `folder`/report.html), whole or not at all;
    inside `folder`, listed in its record as derived from its run (crashnlp.results.files.deriving)."""
    kind = folder_kind(folder)
    out = check_writable_file(out or folder / REPORT, own=folder / REPORT, kind=REPORT_FILE)
    if kind == "result":
        page = result_page(read_result(folder), folder)
    elif kind == "simulation":
        page = simulation_page(*read_simulation(folder), folder)
    else:
        page = study_page(recorded_name(folder, "study") or folder.name, read_study(folder), folder)
    with deriving(folder, out), atomic_open(out, kind=REPORT_FILE) as fh:
        fh.write(page)
    return out


# --------------------------------------------------------------------------- a fit or design
def result_page(result: Result, folder: Path) -> str:
    """The page of a fit or design: the problem in brief, per test its figures, metrics and
    ratings, the estimates with their errors and intervals, their correlations, what sits at a
    bound or is not identified, and the notes (but the one on the values whose interval takes in
    zero, which the page gives with those at a bound); one that did not converge leads with the line
    its exports carry first (`unconverged`) and has no errors, intervals or correlations."""
    loose = takes_in_zero_note(result.takes_in_zero())
    figures = embedded_figures(folder, [FORCE_CRUSH_FIGURE], f"the {loading_curve_name(result.kind)}")
    correlation = result.correlation
    if correlation.get("labels") and result.ok:
        from crashnlp.results import plots  # matplotlib: only when a page draws

        matrix = np.array([[np.nan if v is None else v for v in row] for row in correlation["matrix"]], dtype=float)
        png = plots.correlation_png(list(correlation["labels"]), matrix, f"{result.name}: correlation of the estimates")
        figures.append({"uri": data_uri(png), "caption": "correlation of the estimates (sandwich covariance)"})
    return TEMPLATES.get_template("result.html.j2").render(
        title=f"{result.name}: {'fit' if result.kind == 'identify' else result.kind}",
        result=result,
        unconverged=unconverged(result.status),
        brief=_brief(result),
        tests=[_test(result, name, folder) for name in result.tests],
        figures=figures,
        parameters=_parameters(result, folder / "result.json"),
        not_identified=result.not_identified,
        loose=loose,
        at_bound=pull_texts(result),
        active=result.active_constraints,
        notes=tuple(note for note in result.notes if note != loose),
    )


def _brief(result: Result) -> list[tuple[str, str]]:
    """The problem and the solve in a few lines: (what, how)."""
    s = result.solver
    objective = "-" if s.objective is None else f"{s.objective:.6g}"
    lines = [
        ("status", f"{result.status} (IPOPT {s.return_status or '-'}, {s.iterations} iterations, objective {objective})"),
        ("transcription", ", ".join(f"{k} {v}" for k, v in result.transcription.items())),
        ("tests", ", ".join(f"{name} at {t.speed * 3.6:.1f} km/h" for name, t in result.tests.items())),
        ("estimated", ", ".join(result.parameters) or "nothing"),
    ]
    if result.identified is not None:
        vehicle, model = result.identified.vehicle, result.identified.model
        spring, unloading, damper = model["spring"], model["unloading"], model.get("damper")
        lines.insert(2, ("vehicle", f"{vehicle['mass']:.0f} kg, CG {vehicle['cg_to_impact']:.3g} m behind the impact point"))
        front = (
            f"{spring['law']} spring law over {len(spring['crush_breakpoints'])} breakpoints to "
            f"{1e3 * spring['crush_breakpoints'][-1]:.0f} mm, {unloading['law']} unloading"
        )
        front += ", a damper" if damper else ", no damper"
        lines.insert(3, ("front end", front))
    if result.covariance.get("method") and result.ok:
        lines.append(("standard errors", str(result.covariance["method"])))
    return lines


def _test(result: Result, name: str, folder: Path) -> dict[str, Any]:
    """One test: its figures, its metrics (model against test), RMSE and ISO 18571 ratings."""
    t = result.tests[name]
    data = t.data_metrics or {}
    read = t.response.accel_filter
    metrics = [(m.heading_through(read), m.tabled(t.metrics.get(m.key)), m.tabled(data.get(m.key))) for m in TABLED]
    fits = [
        {
            "channel": c,
            "rmse": OUTPUT[c].shown(f.rmse),
            "sigma": OUTPUT[c].shown(f.sigma),
            "ratings": [significant((f.iso18571 or {}).get(k), 1.0, 3) for k in RATINGS],
        }
        for c, f in t.fit.items()
    ]
    return {
        "name": name,
        "speed": f"{t.speed * 3.6:.1f} km/h",
        "figures": embedded_figures(folder / name, [FIT_FIGURE, RESPONSE_FIGURE, RESIDUAL_FIGURE], f"test {name}"),
        "metrics": metrics,
        "has_data": bool(t.data_metrics),
        "fits": fits,
        "ratings": RATINGS,
    }


def _parameters(result: Result, source: Path) -> list[dict[str, str]]:
    """Every estimated value, one number each: value, standard error and 95 % interval (the
    profile's where the fit profiled it, else value ± Z95 standard errors, cut at its bounds),
    its bounds, in the unit it reads in (`source`: the result.json, which a refusal names). A fit
    that did not converge has neither errors nor intervals: its values are a last iterate, whose
    covariance `crashnlp simulate` does not take either."""
    problem = result.identified.as_problem(result.name, str(source)) if result.identified is not None else None
    bounds = dict(zip(result.identified.labels, result.identified.bounds)) if result.identified is not None else {}
    rows = []
    for path, value in result.parameters.items():
        unit, factor = shown_unit(problem.unit_at(path)) if problem is not None else ("", 1.0)
        stds = result.std_errors.get(path) if result.ok else None
        values = value if isinstance(value, list) else [value]
        std_list = stds if isinstance(stds, list) else [stds] * len(values)
        without = "not identified" if path in result.std_errors else "no standard errors"  # a design has none
        without = without if result.ok else "none: not converged, a last iterate"
        for i, (v, s) in enumerate(zip(values, std_list)):
            label = f"{path}[{i}]" if isinstance(value, list) else path
            rows.append(_parameter(result, label, v, (s, without), bounds.get(label), (unit, factor)))
    return rows


def _parameter(
    result: Result,
    label: str,
    value: float,
    error: tuple[float | None, str],
    bounds: tuple[float, float] | None,
    unit: tuple[str, float],
) -> dict[str, str]:
    """One estimated value's row; `error`: its standard error (None: none) and why there is none."""
    (std, without), (name, factor) = error, unit
    ends, how = _interval(result.profiles.get(label, {}) if result.ok else {}, value, std, bounds) or (None, without)
    return {
        "label": label,
        "value": significant(value, factor, 5),
        "std": significant(std, factor, 2),
        "interval": "-" if ends is None else "[" + ", ".join(_end(k, end, factor) for k, end in zip(ENDS, ends)) + "]",
        "how": how,
        "bounds": "-" if bounds is None else f"[{significant(bounds[0], factor)}, {significant(bounds[1], factor)}]",
        "unit": name,
        "at_bound": pull_texts(result).get(label, ""),
    }


End = tuple[float, str]  # an interval's end, and what it is where the profile did not close there ("" where it did)
ENDS = ("lower", "upper")
OPEN = "open past the furthest value profiled"


def _interval(
    profile: dict[str, Any], value: float, std: float | None, bounds: tuple[float, float] | None
) -> tuple[tuple[End, End], str] | None:
    """A value's 95 % interval and where it comes from: its profile where it has one, else value
    ± Z95 standard errors cut at its bounds; None without either."""
    lo, hi = bounds or (-math.inf, math.inf)
    if profile.get("points"):
        ends = _profile_end(profile, "lower", lo), _profile_end(profile, "upper", hi)
        return ends, "profile" + "".join(f", {key} end {what}" for key, (_, what) in zip(ENDS, ends) if what)
    if std is None or not math.isfinite(std):
        return None
    low, high = max(value - Z95 * std, lo), min(value + Z95 * std, hi)
    cut = (low, high) != (value - Z95 * std, value + Z95 * std)
    return ((low, ""), (high, "")), f"± {Z95:.2f} std" + (", cut at a bound" if cut else "")


def _profile_end(profile: dict[str, Any], key: str, bound: float) -> End:
    """The `key` ("lower", "upper") end of a profile's interval, and what it is where the profile
    did not close there (crashnlp.optimize.profile writes null where the objective's rise never
    reached the threshold within the values profiled): the bound where the profile ran to it
    (its next step would have passed it, or it had no room for one: the estimate at the bound),
    else the furthest value profiled, past which the interval runs on (OPEN); an end resting on a
    solve IPOPT did not finish is that first (`unsolved_end`)."""
    unsolved = unsolved_end(profile, key)
    if profile.get(key) is not None:
        return profile[key], unsolved or ""
    side, estimate = (-1.0 if key == "lower" else 1.0), profile["estimate"]
    walked = sorted((side * (v - estimate) for v, _ in profile["points"] if side * (v - estimate) > 0))
    if not walked or walked[-1] + walked[0] > side * (bound - estimate):  # steps are equal: the first is one
        return bound, unsolved or "at the bound"
    return estimate + side * walked[-1], unsolved or OPEN


def _end(key: str, end: End, factor: float) -> str:
    """An interval's `key` end as shown; one the profile left open says which way it runs on ("< 2.1",
    "> 3.4"), one resting on a solve IPOPT did not finish says so ("2.1 (unsolved)")."""
    value, what = end
    shown = ("" if what != OPEN else "< " if key == "lower" else "> ") + significant(value, factor)
    return f"{shown} (unsolved)" if what.startswith(UNSOLVED) else shown


# --------------------------------------------------------------------------- a simulation
def simulation_page(name: str, tests: dict[str, PredictedTest], folder: Path) -> str:
    """The page of a simulation: where it came from (the problem, the fit whose parameters it
    took: crashnlp.results.source), per predicted test its metrics with their 95 % intervals (no
    table where it has none: its notes say why), how far it lies past the identified range, its
    notes and its figure with the bands."""
    pages = []
    for test in tests.values():
        rows = []
        for m in PREDICTED:
            value, band = test.metrics.get(m.key), test.intervals.get(m.key)
            if value is None:
                continue
            heading = m.heading_through(test.response.accel_filter, short=True)
            rows.append((heading, m.shown(value), "-" if band is None else m.band(band)))
        pages.append(
            {
                "name": test.name,
                "speed": f"{test.speed * 3.6:.1f} km/h",
                "mass": f"{test.mass:.0f} kg",
                "rows": rows,
                "intervals": bool(test.intervals),
                "extrapolation": _extrapolation(test),
                "notes": test.notes,
                "figures": embedded_figures(folder / test.name, [RESPONSE_FIGURE], _figure_caption(test)),
            }
        )
    source = source_line(next((test.source for test in tests.values() if test.source), {}))
    return TEMPLATES.get_template("simulation.html.j2").render(
        title=f"{name}: simulation", tests=pages, source=source or UNRECORDED
    )


def _figure_caption(test: PredictedTest) -> str:
    """A predicted test's figure caption: its bands where it has them."""
    return f"test {test.name}, " + ("95 % bands shaded" if test.bands else "no bands")


def _extrapolation(test: PredictedTest) -> str:
    return extrapolation_line(test.extrapolation) if test.extrapolation else ""


# --------------------------------------------------------------------------- a study
def study_page(name: str, rows: list[dict], folder: Path) -> str:
    """The page of a study: its table (swept values as written, status, IPOPT's return status,
    objective, iterations, metrics and bound multipliers in the units a person reads), its figures, and for a complete
    two-entry grid a map of the objective and of each metric it plots over the grid."""
    keys = list(dict.fromkeys(k for r in rows for k in r))  # a failed case's row lacks the metrics
    swept = [k for k in keys if f"{k}_si" in keys]
    classes = read_through(rows)
    metrics = [(k, *shown) for k in keys if (shown := shown_column(k, classes)) is not None]
    solver = ["return_status"] if "return_status" in keys else []  # IPOPT's, beside a case's own status (older tables have none)
    columns = ["case", *swept, "status", *solver, "objective", "iterations"]
    head = columns + [label for _, label, _ in metrics]
    body = [[_text(r.get(c)) for c in columns] + [significant(number(r.get(k)), f) for k, _, f in metrics] for r in rows]
    figures = embedded_figures(folder / "figures", sorted(p.name for p in (folder / "figures").glob("*.png")), "")
    maps = _maps(name, rows, swept, metrics) if len(swept) == 2 else []
    return TEMPLATES.get_template("study.html.j2").render(
        title=f"{name}: study",
        head=head,
        body=body,
        texts=len(columns) - 2,  # the columns of words, left-aligned: all but objective and iterations
        figures=maps + figures,
        cases=len(rows),
        swept=swept,
    )


def _maps(name: str, rows: list[dict], swept: list[str], metrics: list[tuple[str, str, float]]) -> list[dict[str, str]]:
    """Maps over a complete grid of two swept entries: the objective and the metrics a study plots (PLOTTED),
    a cell per case (empty where it failed); none when the cases do not fill the grid (zip)."""
    from crashnlp.results import plots

    axes = [_axis(rows, k) for k in swept]
    if len(rows) != len(axes[0]) * len(axes[1]):
        return []
    cell = {(r[swept[0]], r[swept[1]]): r for r in rows}
    shown = [("objective", "objective", 1.0)] + [m for m in metrics if m[0].endswith(PLOTTED)]
    out = []
    for key, label, factor in shown:
        grid = np.array([[_oknumber(cell[(x, y)], key) * factor for x in axes[0]] for y in axes[1]])
        png = plots.map_png(
            [str(v) for v in axes[0]], [str(v) for v in axes[1]], grid, (swept[0], swept[1], label), f"{name}: {label}"
        )
        out.append({"uri": data_uri(png), "caption": f"{label} over the grid"})
    return out


def _axis(rows: list[dict], key: str) -> list[Any]:
    """The values a swept entry takes, as written, in the order of their SI values."""
    si = {r[key]: number(r.get(f"{key}_si")) for r in rows}
    return sorted(si, key=lambda value: si[value])


def _oknumber(row: dict, key: str) -> float:
    return number(row.get(key)) if row.get("status") == "ok" else math.nan


# --------------------------------------------------------------------------- pieces
def embedded_figures(folder: Path, names: list[str], caption: str) -> list[dict[str, str]]:
    """The named PNG files of `folder` that exist, as data URIs with a caption."""
    return [
        {"uri": data_uri((folder / n).read_bytes()), "caption": f"{caption}: {n}" if caption else n}
        for n in names
        if (folder / n).is_file()
    ]


def data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _text(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return "" if value is None else str(value)
