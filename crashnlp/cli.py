"""The `crashnlp` command: simulate, identify, design, compare, study, init, report, compare-results, export, schema.

One error path: bad input (a file, a key, an option) exits 2 with one line
naming it, and nothing is written; a failure the input did not cause (the
solver, the integrator, a cluster, the file system) exits 1 with one line;
SIGINT and SIGTERM exit 130 and 143 with one line; a reader of stdout that
left (`| head`) ends it with 141 and none. No traceback unless `--debug` asks for it.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import re
import signal
import sys
import threading
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager, nullcontext, redirect_stderr
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crashnlp import __version__
from crashnlp.base.choices import DATA_FORMATS
from crashnlp.base.errors import InputError, Interrupted, RunError
from crashnlp.base.outputs import METRIC, OUTPUT, PREDICTED, TABLED, Metric
from crashnlp.numerics.compile_job import release_compiles, stop_compiles
from crashnlp.results.files import (
    check_entries,
    check_output,
    check_writable,
    check_writable_file,
    claim,
    deriving,
    file_option,
    run_name,
)
from crashnlp.studies.cli import add_parser as add_study_parser

if TYPE_CHECKING:
    from crashnlp.optimize.comparison import FormScore  # at run time where compare runs

RESULTS = Path("results")


def _out(args, name: str) -> Path:
    return Path(args.out) if args.out else RESULTS / name


def cmd_simulate(args) -> int:
    with _figure_process(args) as figures:
        prepared = _simulation(args)
        if prepared is None:
            return 0
        case, identified, out, dt, source = prepared
        from crashnlp.analysis.prediction import simulation_figure_jobs, traced
        from crashnlp.results.simulation import write_simulation
        from crashnlp.results.source import source_line

        fit = _params_folder(source)
        with deriving(fit, out) if fit else nullcontext(), claim(out, run_name("simulate", case.name)):
            with _computing(args):
                predicted = traced(case, identified, dt, source)
            write_simulation(case.name, predicted, out)
            if figures is not None:
                figures.draw(simulation_figure_jobs(case.name, predicted, out), out)
    for test in predicted.values():
        _print_prediction(test)
    print(f"source: {source_line(source)}")
    print(f"wrote {out}/")
    return 0


def _params_folder(source: dict) -> Path | None:
    """The folder of the file a simulation took its parameters from, as its source records it
    (crashnlp.results.source), whatever that file is named (`--params other.json` too); None where
    they came from no file. The simulation's output counts as derived from the run in that folder
    (crashnlp.results.files.deriving). Unlike crashnlp.results.result.fit_folder, which refuses a
    file not named result.json (Result.load would not read it), it refuses nothing."""
    from crashnlp.results.result import result_file

    path = (source.get("result") or {}).get("path")
    if path is None:
        return None
    return result_file(path).parent


def _print_prediction(test) -> None:
    """One line of the metrics each simulated test gives, with their 95 % intervals when the
    identified model gave them (none where it gives none), after the speed and mass it ran at
    (PredictedTest.conditions: a what-if's are not its name's); one line for a test past the
    identified range, and its notes (which say why a metric is not given)."""
    from crashnlp.results.simulation import extrapolation_line

    parts = []
    for m in PREDICTED:
        value = test.metrics.get(m.key)
        if value is None:
            continue
        parts.append(prediction_part(m, value, test.intervals.get(m.key), test.response.accel_filter))
    if parts:
        intervals = " (95 % intervals)" if any(test.intervals.values()) else ""
        print(f"{test.name}, {test.conditions}: " + ", ".join(parts) + intervals)
    if test.extrapolation:
        print(f"{test.name}: {extrapolation_line(test.extrapolation)}")
    for note in test.notes:
        print(note)


def prediction_part(m: Metric, value: float, band: tuple[float, float] | list[float] | None, accel_filter: str | None) -> str:
    """One metric of a prediction's line, its 95 % interval where it has one, and the CFC class an
    acceleration's extreme was read through: "peak decel 19.6 [15.5, 23.8] g (CFC60)"."""
    through = f" ({cfc})" if (cfc := m.read_through(accel_filter)) else ""
    return f"{m.short} {m.cell(value, band)} {m.unit}{through}"


def _simulation(args):
    """(case, identified model or None, output folder, --dt in s or None, source:
    crashnlp.results.source) of the problem file, every check made and the folder checked
    (crashnlp.results.files.check_output), or None after `--check`."""
    from crashnlp.analysis.prediction import check_steps, output_step
    from crashnlp.case.case import case_of
    from crashnlp.problem import load_problem
    from crashnlp.problem.schema import what_if
    from crashnlp.results.params import given_result, with_params
    from crashnlp.results.simulation import simulation_entries
    from crashnlp.results.source import simulation_source

    dt = output_step(args.dt, "--dt")
    speed, mass = what_if(args.speed, args.mass, prefix="--")
    fit = args.params
    if (given := given_result(args.problem)) is not None:
        from crashnlp.report.folders import result_alone  # the report's package: not for a problem file's run

        problem, identified, read = result_alone(given, args.params, "--params")
        fit = args.problem
    elif args.params:
        problem, identified, read = with_params(args.problem, args.params)
    else:
        problem, identified, read = load_problem(args.problem), None, None
    case = case_of(problem, args.problem).at(speed, mass)
    check_steps(case, dt, "--dt", args.problem)
    if identified is None:  # a fit's vehicle is simulated as it was fitted
        case.refuse_unread_given(args.problem)
    out = Path(args.out) if args.out else RESULTS / case.name / "simulation"
    check_output(out, run_name("simulate", case.name), entries=simulation_entries(test.name for test in case.tests))
    if getattr(args, "check", False):
        print(f"{args.problem}: ok ({len(case.tests)} tests; would write {out}/)")
        return None
    return case, identified, out, dt, simulation_source(args.problem, fit, file=read)


def _figure_process(args):
    """The process that draws the command's figures (crashnlp.results.drawing), started now so that
    matplotlib loads while this one works; none with --no-figures or --check."""
    from crashnlp.results.drawing import FigureProcess

    return nullcontext() if args.no_figures or getattr(args, "check", False) else FigureProcess()


def _numbers(value, digits: int, missing: float = np.nan) -> str:
    """A number or list of numbers to `digits` significant digits; None (result.json's for a
    number that is not finite) shows as `missing`: nan for a value, inf for a standard error
    the data do not determine."""
    items = value if isinstance(value, list) else [value]
    values = np.array([missing if v is None else v for v in items], dtype=float)
    text = " ".join(f"{v:.{digits}g}" for v in values)
    return text if not isinstance(value, list) else f"[{text}]"


HEADINGS = max(len(m.heading_through("CFC1000")) for m in TABLED)  # the width of the metric table's first column


def metric_row(m: Metric, accel_filter: str | None, model: str, test: str) -> str:
    """A row of a fit's metric table: the metric's heading (the CFC class its acceleration was read
    through) and its model's and test's cells."""
    return f"    {m.heading_through(accel_filter):<{HEADINGS}}{model:>10}{test:>10}"


def _unit_suffix(unit: str) -> str:
    """What follows a value in `unit` on the console (" N/m"); nothing for a number without one."""
    return f" {unit}" if unit else ""


def _consistency_line(c: dict) -> str:
    """The one printed line of a channel consistency (crashnlp.analysis.summary.channel_consistency):
    each channel's impulse, and its metrics in their shown units, to the digits a one-mass reading merits."""
    parts = [
        f"{name} {s['impulse_Ns'] / 1e3:.2f} kN s, stop {_metric_text(s, 'time_zero_velocity_s', 1)}"
        f" after {_metric_text(s, 'max_displacement_m', 0)}, rebound {_metric_text(s, 'rebound_velocity_mps', 1)}"
        for name, s in c.items()
        if isinstance(s, dict)
    ]
    return f"channel consistency (one mass): {'; '.join(parts)}; impulse wall / accelerometers {c['impulse_ratio']:.3f}"


def _metric_text(metrics: Mapping[str, float], key: str, digits: int) -> str:
    """A crash metric with its unit, as the registry shows it, `digits` after the point: "62.3 ms"."""
    m = METRIC[key]
    return f"{m.shown(metrics[key], digits)} {m.unit}"


def _print_solution(result, units: Mapping[str, str] | None = None) -> None:
    """The console summary of a Result: status, parameters with their SI `units` (by path; none
    where not given) and std, metrics, fit, active constraints."""
    from crashnlp.analysis.summary import goes_on, let_go_words, pitch_words
    from crashnlp.results.identified import takes_in_zero_note
    from crashnlp.results.result import pull_texts, unconverged, unsolved_lines

    s = result.solver
    how = " compiled" if s.compiled else ""
    timing = f"solve {s.wall_s:.2f} s{how} + build {s.build_s:.2f} s" if s.wall_s is not None else "not solved"
    objective = f"{s.objective:.6g}" if s.objective is not None else "-"
    print(
        f"{result.name}: {result.status} (IPOPT {s.return_status or '-'}, {s.iterations} iterations, "
        f"objective {objective}, {timing})"
    )
    for line in unconverged(result.status):  # a last iterate: no standard errors, as its report and simulate give none
        print(f"  {line}")
    for path, value in result.parameters.items():
        text = _numbers(value, 5) + _unit_suffix((units or {}).get(path, ""))
        if path in result.std_errors and result.ok:
            text += f"  (std {_numbers(result.std_errors[path], 2, np.inf)})"
        print(f"  {path} = {text}")
    if result.not_identified:
        print(f"  not identified (infinite std): {', '.join(result.not_identified)}")
    if loose := result.takes_in_zero():
        print(f"  {takes_in_zero_note(loose)}")
    for line in unsolved_lines(result):
        print(f"  {line}")
    if result.at_bound and result.kind == "identify" and result.ok:
        pulls = ", ".join(f"{label} ({pull})" for label, pull in pull_texts(result).items())
        print(f"  at a bound (how far past it the data pull): {pulls}")
    elif result.at_bound:
        print(f"  at a bound: {', '.join(result.at_bound)}")
    if result.resolution:
        print(f"  {result.resolution['note']}")
    for note in result.identified.tail_notes() if result.identified is not None else ():
        print(f"  {note}")
    for name, t in result.tests.items():
        model, data = t.metrics, t.data_metrics
        print(f"  test {name:<{HEADINGS - 2}}{'model':>10}{'test' if data else '':>10}")
        for row in TABLED:
            cells = row.tabled(model.get(row.key)), row.tabled(data.get(row.key)) if data else ""
            print(metric_row(row, t.response.accel_filter, *cells))
        if words := _departs(t.forward_check):
            print(f"    {words}")
        for who, m in (("the model", model), ("the test record", data)):
            if m and (words := goes_on(m)):
                print(f"    {who} {words}")
        if words := let_go_words(t.response):
            print(f"    the model {words}")
        for words in pitch_words(t):
            print(f"    {words}")
        if t.fit:
            print("    rmse      " + ", ".join(f"{c} {OUTPUT[c].shown(f.rmse)}" for c, f in t.fit.items()))
            print("    ISO 18571 " + ", ".join(f"{c} {f.iso18571['overall']:.3f}" for c, f in t.fit.items() if f.iso18571))
        if t.consistency:
            print(f"    {_consistency_line(t.consistency)}")
        if t.energy:
            print(
                f"    relative energy balance error {t.energy['balance_error_relative']:.2e}"
                f" (impact energy {t.energy['impact_kinetic'] / 1e3:.1f} kJ)"
            )
    for c in result.active_constraints:
        print(f"  active: {c.name} at {c.points} points, multiplier {c.multiplier:.4g}")


def _departs(check: Mapping[str, Any] | None) -> str | None:
    """The words for a solution whose forward simulation departs from it past its tolerance (the
    forward check result.json keeps: an iterate IPOPT stopped at, infeasible, is no motion of the
    model); None where it keeps to it or was not checked."""
    if not check or check.get("worst_relative", 0.0) <= 1.0:
        return None
    errors, allowed = check["max_abs_error"], check["allowed"]
    key = max(errors, key=lambda k: errors[k] / allowed[k])
    return (
        f"the forward simulation departs from this solution ({key} by {OUTPUT[key].shown(errors[key])}, "
        f"{errors[key] / allowed[key]:.3g} times its tolerance): its metrics above are of the solver's last iterate, "
        "not of the model's motion"
    )


def _solve(args, kind: str) -> int:
    """identify and design: one NLP solve, its result files and a summary. The figure process
    starts first, so that matplotlib loads while this one reads the problem and solves; the
    output folder is claimed (crashnlp.results.files.claim) from the solve to the last figure."""
    with _figure_process(args) as figures:
        prepared = _prepared_case(args, kind)
        if prepared is None:
            return 0
        case, out = prepared
        from crashnlp.optimize.pipeline import solve_case
        from crashnlp.results.result import figure_jobs

        with claim(out, run_name(kind, case.name)):
            with _computing(args):
                result = solve_case(case, verbose=args.verbose, progress=sys.stdout)
            result.save(out, figures=False)
            if figures is not None:
                figures.draw(figure_jobs(result, out), out)
            if args.report:
                from crashnlp.report import write_report

                write_report(out)
    _print_solution(result, {path: case.problem.unit_at(path) for path in result.parameters})
    print(f"wrote {out}/")
    if not result.ok:
        print(f"crashnlp: {result.name}: {result.status}", file=sys.stderr)
        return 1
    return 0


def _prepared_case(args, kind: str):
    """(Case, output folder) of the problem file, or None after `--check`: crashnlp.optimize.pipeline's
    checks, as crashnlp.identify and crashnlp.design run them, its errors naming the file, and the folder's."""
    from crashnlp.optimize.pipeline import prepare_case
    from crashnlp.problem import load_problem
    from crashnlp.results.result import result_entries

    problem = load_problem(args.problem)
    if problem.kind != kind:
        raise InputError(f"{args.problem}: kind is {problem.kind!r}; use 'crashnlp {problem.kind}'")
    case = prepare_case(problem, args.problem)  # before any solve
    entries = result_entries(test.name for test in case.tests)
    out = check_output(_out(args, problem.name), run_name(kind, problem.name), entries=entries)
    if getattr(args, "check", False):
        print(f"{args.problem}: ok ({len(case.tests)} tests; would write {out}/)")
        return None
    return case, out


def cmd_identify(args) -> int:
    return _solve(args, "identify")


def cmd_design(args) -> int:
    return _solve(args, "design")


_PITCH, _TRAVEL = OUTPUT["pitch"], METRIC["max_displacement_m"]  # what a form's pitch RMSE and displacement error are of
FORM_ROWS = (  # the console's table of a comparison: label, FormScore attribute, factor, format
    ("objective", "objective", 1.0, ".4g"),
    (f"pitch RMSE ({_PITCH.report_unit})", "pitch_rmse_rad", _PITCH.factor, ".3f"),
    (f"displacement error ({_TRAVEL.unit})", "displacement_error_m", _TRAVEL.factor, ".1f"),
    ("identified parameters", "parameters", 1, "d"),
    ("held-out rel. RMSE", "held_out_score", 1.0, ".4f"),
    ("BIC", "bic", 1.0, ".1f"),
    ("lifts off at (ms)", "lift_off_s", 1e3, ".1f"),
)


def comparison_table(forms: Sequence[FormScore]) -> list[str]:
    """The console's table of a comparison: a column per form (its status ok or not, FORM_ROWS), then
    each form that is not ok with its whole status (IPOPT's, or the check that failed), and each
    held-out fit of a form that is ok that failed, with its status."""
    width = max([14, *(len(f.form) + 2 for f in forms)])  # a column's, two spaces at least before each name
    lines = [f"  {'':<24}" + "".join(f"{f.form:>{width}}" for f in forms)]
    lines.append(f"  {'status':<24}" + "".join(f"{'ok' if f.ok else 'not ok':>{width}}" for f in forms))
    for label, key, factor, fmt in FORM_ROWS:
        cells = [getattr(f, key) for f in forms]
        lines.append(f"  {label:<24}" + "".join(f"{'-' if v is None else format(v * factor, fmt):>{width}}" for v in cells))
    return lines + [line for f in forms for line in _not_ok(f)]


def _not_ok(form: FormScore) -> list[str]:
    """The lines under the comparison table for a form: its status where it is not ok, else each
    held-out fit that failed with its status (the form has no held-out score then)."""
    if not form.ok:
        return [f"  {form.form}: {form.status}"]
    return [f"  {form.form}: predicting {h.test} from the other tests: {h.status}" for h in form.held_out if h.status != "ok"]


def cmd_compare_forms(args) -> int:
    """Every model form fitted and scored (crashnlp.optimize.comparison): compare.json and a table."""
    from crashnlp.optimize.comparison import COMPARE_FILE, check_comparable, compare, compared
    from crashnlp.problem import load_problem
    from crashnlp.results.jsonfile import write_json

    problem = load_problem(args.problem)
    forms = args.forms or compared(problem)
    check_comparable(problem, args.problem, forms, "--forms")
    run = run_name("compare", problem.name)
    out = check_output(_out(args, f"{problem.name}-compare"), run, entries=[COMPARE_FILE])
    if args.check:
        print(f"{args.problem}: ok ({len(problem.tests)} tests; would write {out}/{COMPARE_FILE})")
        return 0
    with claim(out, run):
        with _computing(args):
            comparison = compare(problem, args.problem, progress=sys.stdout, forms=forms)
        write_json(out / COMPARE_FILE, comparison.to_json())
    print("\n".join(comparison_table(comparison.forms)))
    print(f"choice ({comparison.criterion}): {comparison.reason}")
    print(f"wrote {out}/{COMPARE_FILE}")
    if comparison.choice is None:
        print(f"crashnlp: {problem.name}: {comparison.reason}", file=sys.stderr)
        return 1
    return 0


def cmd_init(args) -> int:
    from crashnlp.init import Options, init_problem
    from crashnlp.problem.schema import what_if

    columns: dict[str, str] = {}
    for item in args.column:
        channel, sep, name = item.partition("=")
        if not sep or not name:
            raise InputError(f"--column {item}: expected CHANNEL=NAME[:UNIT]")
        if channel in columns:
            raise InputError(f"--column {item}: {channel} is given twice (--column {channel}={columns[channel]})")
        columns[channel] = name
    speed, mass = what_if(args.speed, args.mass, prefix="--")  # as simulate's what-if: one message for one mistake
    options = Options(args.format, mass, speed, columns, args.name, args.force)
    paths = [Path(p) for p in args.data]
    problem, notes = init_problem(paths, file_option(args.out), options)
    print(
        f"wrote {args.out}: {problem.name}, {len(problem.model.spring.known_values)} breakpoints to "
        f"{problem.model.spring.placed_breakpoints[-1] * 1e3:.0f} mm, estimates {', '.join(problem.estimate)}"
    )
    for note in notes:
        print(f"  {note}")
    return 0


def cmd_schema(args) -> int:
    from crashnlp.problem.schema import Problem

    print(json.dumps(Problem.model_json_schema(), indent=2))
    return 0


def cmd_report(args) -> int:
    """The page of a fit's, a simulation's or a study's folder (crashnlp.report)."""
    from crashnlp.report import write_report

    print(f"wrote {write_report(Path(args.folder), file_option(args.out) if args.out else None)}")
    return 0


def cmd_compare_results(args) -> int:
    """Fits and simulations side by side (crashnlp.report.compare): figures, metrics, a page."""
    from crashnlp.report.compare import PAGE, compare_results, metric_table

    out = Path(args.out) if args.out else RESULTS / "compare"
    head, rows = metric_table(compare_results([Path(f) for f in args.folders], out))
    for i, label in enumerate(head[1:]):
        print(f"[{i + 1}] {label}")
    print(f"  {'':<24}" + "".join(f"{f'[{i + 1}]':>24}" for i in range(len(head) - 1)))
    for row in rows:
        print(f"  {row[0]:<24}" + "".join(f"{cell:>24}" for cell in row[1:]))
    print(f"wrote {out}/ ({PAGE}, metrics.csv, a figure per quantity)")
    return 0


def cmd_export(args) -> int:
    """The identified curves (ls-dyna, csv) of a fit's folder, or a test's pulse (a fit's or a simulation's)."""
    from crashnlp.report.folders import folder_kind

    folder = Path(args.folder)
    kind = folder_kind(folder)
    if kind == "study" or (kind == "simulation" and args.format != "pulse"):
        what = "identified curves" if kind == "simulation" else "curves or pulses"
        raise InputError(f"{folder}: a {kind}'s folder holds no {what}: export a fit's folder (result.json)")
    return _export_pulse(args, folder, kind) if args.format == "pulse" else _export_curves(args, folder)


PULSE_OPTIONS = ("--rate", "--cfc", "--test")  # export's options of --format pulse alone
RATE = "10 kHz"  # a pulse's sample rate without --rate


def _export_curves(args, folder: Path) -> int:
    """The identified model's curves as LS-DYNA keywords or CSV files."""
    from crashnlp.report import export
    from crashnlp.report.folders import read_result, reading

    result = read_result(folder)
    if result.identified is None:
        raise InputError(f"{folder / 'result.json'}: no identified_model (a result written before crashnlp kept it)")
    with reading(folder / "result.json"):  # one edited, or cut short, past what the schema reads is one line
        curves = export.identified_curves(result.identified, result.not_identified, result.takes_in_zero())
    given = [option for option in PULSE_OPTIONS if getattr(args, option.lstrip("-")) is not None]
    if given:
        raise InputError(f"{given[0]}: an option of --format pulse; --format {args.format} writes no pulse")
    if args.format == "csv":
        own = folder / "curves"
        out = check_writable(Path(args.out) if args.out else own)
        names = export.curve_files(curves)
        check_entries(out, names)
        for name in names:  # a user's own file of the name, or one edited since crashnlp wrote it, is not written over
            check_writable_file(out / name, own=own / name, kind=export.CURVE_FILE)
        _say_unconverged(result.status)
        with deriving(folder, out):
            print("wrote " + ", ".join(str(p) for p in export.write_curves_csv(out, result.name, folder, curves, result.status)))
        return 0
    own = folder / f"{result.name}.k"
    out = check_writable_file(file_option(args.out) if args.out else own, own=own, kind=export.KEYWORD_FILE)
    _say_unconverged(result.status)
    with deriving(folder, out):
        export.write_keyword_file(out, result.name, folder, curves, result.status)
    print(f"wrote {out}")
    return 0


def _say_unconverged(status: str | None) -> None:
    """An export of a fit that did not converge says so on the console, as its file does."""
    from crashnlp.results.result import unconverged

    for line in unconverged(status):
        print(f"crashnlp: {line}")


def _export_pulse(args, folder: Path, kind: str) -> int:
    """One test's fitted or predicted pulse, and its velocity-change check."""
    from crashnlp.report import export
    from crashnlp.report.folders import read_result, read_simulation

    status: str | None
    if kind == "result":
        result = read_result(folder)
        name, status = result.name, result.status
        test = export.fitted_test(folder, result, _chosen_test(folder, result.tests, args.test))
    else:
        name, tests = read_simulation(folder)
        status = next(((t.source.get("result") or {}).get("status") for t in tests.values()), None)
        test = export.predicted_test(folder, tests[_chosen_test(folder, tests, args.test)])
    pulse = export.pulse(test.response, test.speed, _rate(RATE if args.rate is None else args.rate), args.cfc)
    own = folder / f"{test.name}-pulse.csv"
    out = check_writable_file(file_option(args.out) if args.out else own, own=own, kind=export.PULSE_FILE)
    _say_unconverged(status)
    if test.warning:
        print(f"crashnlp: {test.warning}")
    with deriving(folder, out):
        export.write_pulse(out, name, test, pulse, status)
    print(pulse.check_line())
    print(pulse.filter_line())
    print(f"wrote {out}")
    return 0


def _chosen_test(folder: Path, tests: Mapping[str, object], test: str | None) -> str:
    """The test named by --test, or the folder's only one (`tests`: the folder's, by name)."""
    if test is None and len(tests) == 1:
        return next(iter(tests))
    if test is not None and test in tests:
        return test
    names = ", ".join(tests)
    raise InputError(f"--test {test}: {folder} has tests {names}" if test else f"{folder}: tests {names}: choose one with --test")


def _rate(text: str) -> float:
    """--rate as a number of Hz ("10 kHz", "10000")."""
    return _quantity_option("--rate", text, "Hz")


def _quantity_option(option: str, text: str, unit: str) -> float:
    """An option's quantity in SI `unit` ("10 kHz", "0.1 ms"; a plain number is SI)."""
    from crashnlp.base.units import UnitError, to_si

    try:
        return to_si(text, unit)
    except UnitError as exc:
        raise InputError(f"{option} {text}: {exc}") from None


def _solve_parser(sub, kind: str, about: str, problem: str, func) -> None:
    """The subcommand `kind` (identify or design, `about` its help): one NLP solve of a problem
    file (`problem` its argument's help)."""
    p = sub.add_parser(kind, help=about)
    p.add_argument("problem", help=problem)
    p.add_argument("--out", help="output folder (default results/<problem name>)")
    p.add_argument("--verbose", action="store_true", help="show IPOPT's own log")
    p.add_argument("--no-figures", action="store_true", help="write the result files only (batch use)")
    p.add_argument("--report", action="store_true", help="write report.html too (crashnlp report)")
    p.set_defaults(func=func)


def parser() -> argparse.ArgumentParser:
    ap = Parser(
        prog="crashnlp",
        description="Frontal rigid-barrier crash models (pendulum, rigid body, engine on mounts):"
        " simulate, identify, compare, design, study.",
    )
    ap.add_argument("--version", action="version", version=f"crashnlp {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("simulate", help="simulate every test of a problem with the forward integrator")
    p.add_argument(
        "problem",
        help="problem YAML file, or a fit's result.json (or its folder) alone: its own tests, with its identified vehicle",
    )
    p.add_argument("--params", help="a fit's result.json (or its folder) whose parameters replace the problem's values")
    p.add_argument("--speed", help='a what-if: every test at this impact speed, e.g. "64 km/h" (with its unit)')
    p.add_argument("--mass", help='a what-if: every test at this mass, e.g. "1650 kg"')
    p.add_argument("--out", help="output folder (default results/<problem name>/simulation)")
    p.add_argument("--dt", help='output step, e.g. "0.1 ms" (a plain number is s; default: the problem\'s simulation.dt)')
    p.add_argument("--no-figures", action="store_true", help="write the result files only (batch use)")
    p.set_defaults(func=cmd_simulate)

    about = "fit the estimated parameters to the tests' data by an NLP (IPOPT)"
    _solve_parser(sub, "identify", about, "problem YAML file with data (kind: identify, the default)", cmd_identify)
    about = "choose spring and damper values for a design goal by an NLP (no data)"
    _solve_parser(sub, "design", about, "problem YAML file with kind: design", cmd_design)

    about = (
        "fit the model forms (pendulum, rigid body and the problem's own model.form, or those --forms names)"
        " and choose one by held-out prediction or BIC"
    )
    p = sub.add_parser("compare", help=about)
    p.add_argument("problem", help="problem YAML file with data (kind: identify)")
    p.add_argument("--out", help="output folder (default results/<problem name>-compare)")
    p.add_argument(
        "--forms",
        nargs="+",
        metavar="FORM",
        help="the model forms to fit (model.form; default: pendulum rigid-body and the problem's own model.form,"
        " so the engine-on-mounts form when the problem names it)",
    )
    p.set_defaults(func=cmd_compare_forms)

    add_study_parser(sub)

    p = sub.add_parser("init", help="write a complete, commented problem file from one test's data")
    p.add_argument(
        "data",
        nargs="+",
        help="data file: CSV, NHTSA EV5 header (.EV5), ISO-MME test (.mme, folder or .zip), or one or more NHTSA"
        " channel files vNNNNNtsv.CCC of one test (or their folder)",
    )
    p.add_argument("--format", choices=DATA_FORMATS, help="default: from the file name")
    p.add_argument("--mass", help='test mass, e.g. "1350 kg" (default: the data header)')
    p.add_argument("--speed", help='impact speed, e.g. "48 km/h", with its unit (default: the data header or velocity column)')
    p.add_argument(
        "--column",
        action="append",
        default=[],
        metavar="CHANNEL=NAME[:UNIT]",
        help="a channel's (time, accel, velocity, displacement, pitch) CSV column, by name or number from 1, and its"
        " unit if its name has none; NHTSA channel files: CHANNEL=CCC[,CCC...]:UNIT, the files' numbers or names",
    )
    p.add_argument("--name", help="problem name (default: the data file's stem)")
    p.add_argument("--out", required=True, help="problem YAML file to write")
    p.add_argument("--force", action="store_true", help="write over an existing --out (never over a data file)")
    p.set_defaults(func=cmd_init)

    p = sub.add_parser("report", help="one self-contained HTML page of a fit's, a simulation's or a study's folder")
    p.add_argument("folder", help="a folder crashnlp wrote: a fit or design (result.json), a simulation, a study")
    p.add_argument("--out", help="HTML file to write (default FOLDER/report.html)")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("compare-results", help="fits and simulations on one set of axes with their bands, metrics side by side")
    p.add_argument("folders", nargs="+", help="two or more folders of fits (result.json) or simulations (simulation.json)")
    p.add_argument("--out", help="output folder (default results/compare)")
    p.set_defaults(func=cmd_compare_results)

    p = sub.add_parser("export", help="a fit's curves for LS-DYNA or as CSV, or a test's crash pulse for a sled test")
    p.add_argument("folder", help="a fit's folder (result.json); for --format pulse also a simulation's")
    p.add_argument(
        "--format",
        required=True,
        choices=("ls-dyna", "csv", "pulse"),
        help="ls-dyna: a .k file of *DEFINE_CURVE (mm, ms, kg, kN); csv: the curves in SI; pulse: acceleration against time",
    )
    p.add_argument("--out", help="file to write (csv: a folder; default in FOLDER: NAME.k, curves/, TEST-pulse.csv)")
    p.add_argument("--rate", help=f"pulse: sample rate, e.g. '{RATE}' (default) or 20000 (Hz)")
    p.add_argument(
        "--cfc",
        type=int,
        choices=(60, 180, 600, 1000),
        help="pulse: SAE J211 filter class (default: the class the model's acceleration is read through, as its tests'"
        " accelerometers recorded it; none where no class reads it, as a design's)",
    )
    p.add_argument("--test", help="pulse: the test (default the folder's only one)")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("schema", help="print the JSON Schema of problem files")
    p.set_defaults(func=cmd_schema)
    _add_common(ap, sub)
    return ap


def _add_common(ap: argparse.ArgumentParser, sub) -> None:
    """Options every command has: --debug (anywhere on the line) and --check (all but schema, init,
    report, compare-results and export)."""
    ap.add_argument("--debug", action="store_true", help="show the traceback of a failure (anywhere on the line)")
    for name, p in sub.choices.items():
        if name not in ("schema", "init", "report", "compare-results", "export"):
            p.add_argument(
                "--check",
                action="store_true",
                help="check the input and the output folder, then stop: solve nothing, write nothing",
            )


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (an InputError, exit 2) instead of usage text, and an
    option of one value given twice is refused (`Once`), where argparse would take the last."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        for name in (None, "store"):  # argparse's default action, and by its name
            self.register("action", name, Once)

    def error(self, message: str):
        raise InputError(message)


class Once(argparse._StoreAction):
    """An option's value, stored; the same option given again on the line is an InputError: which
    of `--speed "48 km/h" --speed "64 km/h"` was meant is for the user to say."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = namespace.__dict__.setdefault("_given", set())
        if self.dest in given:
            raise InputError(f"{option_string}: given twice; give it once")
        given.add(self.dest)
        super().__call__(parser, namespace, values, option_string)


# --------------------------------------------------------------------------- the one error path
SIGNALS = {signal.SIGINT: 130, signal.SIGTERM: 143}
_received: list[Interrupted] = []


@contextmanager
def _signals() -> Iterator[None]:
    """SIGINT and SIGTERM raise `Interrupted` in the main thread while a command runs."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        exc = Interrupted(signal.Signals(signum).name, SIGNALS[signum])
        _received.append(exc)
        raise exc

    previous = {s: signal.signal(s, handler) for s in SIGNALS}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextmanager
def _computing(args) -> Iterator[None]:
    """Around a solve or a simulation: CasADi's warnings (it writes them to sys.stderr) stay off the
    one line unless --debug, and a signal that CasADi caught and turned into a failed solve still
    ends the run as interrupted, before anything is written."""
    if getattr(args, "debug", False):
        yield
    else:
        with redirect_stderr(io.StringIO()):
            yield
    if _received:
        raise _received[0]


def describe(exc: BaseException) -> str:
    """One line for a failure the input did not cause."""
    if isinstance(exc, RunError):
        return str(exc)
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if exc.filename else ""
        return f"{where}{exc.strerror or exc}"
    text = str(exc)
    code = re.search(r"\b(CV_[A-Z_]+|IDA_[A-Z_]+)\b", text)
    if code:
        return f"the integrator failed ({code.group(1)}): the model cannot be integrated with these values"
    lines = [re.sub(r"^\S+\.[ch]pp:\d+:\s*", "", line).strip() for line in text.splitlines()]
    lines = [line for line in lines if line]
    detail = lines[-1] if lines else ""
    return f"{type(exc).__name__}: {detail[:300]}" if detail else type(exc).__name__


def _fail(message: str, code: int, debug: bool) -> int:
    if debug:
        import traceback  # here, not at the top: a command without --debug has no use for it

        traceback.print_exc()
    print(f"crashnlp: {message}", file=sys.stderr)
    return code


PIPE_CLOSED = 141  # 128 + SIGPIPE's 13: a shell's status for a writer ended by its reader leaving (`| head`)


def main(argv: list[str] | None = None) -> int:
    """Run one command; every ending is an exit status and at most one line on stderr. A command
    that succeeded, or whose reader of stdout left (PIPE_CLOSED, no line), lets the compiles it
    started finish for the next run, at nice 19 and saying so on a line of its own
    (crashnlp.numerics.compile_job.release_compiles; CRASHNLP_KEEP_COMPILING=0 stops them); any other
    ending stops them, its one line the only one."""
    code = 1
    try:
        code = _command(list(sys.argv[1:] if argv is None else argv))
        return code
    finally:
        if code in (0, PIPE_CLOSED):
            release_compiles()
        else:
            stop_compiles()


def _quiet_stdout() -> None:
    """Send what is still to be written to stdout, its reader gone, to the null device, so that
    the interpreter's flush at exit raises no BrokenPipeError of its own."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def _refuse_empty_out(args) -> None:
    """Refuse `--out ""` on any command that takes --out: the commands read an empty one as not
    given and wrote to their default path, and `init` to the working folder, without a word."""
    if getattr(args, "out", None) == "":
        raise InputError('--out "": names nothing; name the folder or file to write')


def _command(argv: list[str]) -> int:
    """The command's exit status, any failure turned into its one line."""
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    _received.clear()
    try:
        with _signals(), warnings.catch_warnings():
            if not debug:  # a library's warning is not the one line the user gets
                warnings.simplefilter("ignore")
            args = parser().parse_args(argv)
            args.debug = debug
            _refuse_empty_out(args)
            return args.func(args)
    except SystemExit as exc:  # --help and --version
        return exc.code if isinstance(exc.code, int) else 0
    except Interrupted as exc:
        return _fail(f"interrupted ({exc.signame}){exc.detail}", exc.code, debug)
    except KeyboardInterrupt:
        return _fail("interrupted (SIGINT)", 130, debug)
    except InputError as exc:
        return _fail(f"error: {' '.join(str(exc).split())}", 2, debug)
    except BrokenPipeError:  # stdout's reader left: not the run's failure (Python's note on SIGPIPE)
        _quiet_stdout()
        return PIPE_CLOSED
    except Exception as exc:  # noqa: BLE001 - the one place that turns any failure into one line
        if _received:  # a signal that arrived inside compiled code comes back as another exception
            return _fail(f"interrupted ({_received[0].signame})", _received[0].code, debug)
        return _fail(f"error: {describe(exc)}", 1, debug)


if __name__ == "__main__":
    sys.exit(main())
