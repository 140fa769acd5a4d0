"""The `crashnlp` command: simulate, identify, design, study, init, schema.

One error path: bad input (a file, a key, an option) exits 2 with one line
naming it, and nothing is written; a failure the input did not cause (the
solver, the integrator, a cluster, the file system) exits 1 with one line;
SIGINT and SIGTERM exit 130 and 143 with one line. No traceback unless
`--debug` asks for it.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import re
import signal
import sys
import threading
import traceback
import warnings
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext, redirect_stderr
from pathlib import Path

import numpy as np

from crashnlp.compile_job import stop_compiles
from crashnlp.errors import InputError, Interrupted, RunError
from crashnlp.files import check_writable
from crashnlp.outputs import OUTPUT
from crashnlp.studies.cli import add_parser as add_study_parser

RESULTS = Path("results")


def _out(args, name: str) -> Path:
    return Path(args.out) if args.out else RESULTS / name


def _read_params(path: str) -> dict:
    """The content of a result.json: a mapping with a 'parameters' mapping."""
    p = Path(path)
    try:
        raw = json.loads(p.read_text(encoding="utf-8"))
        params = raw["parameters"]
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except (IsADirectoryError, PermissionError) as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror})") from None
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, IndexError):
        raise InputError(f"{p}: not a result.json with a 'parameters' entry") from None
    if not isinstance(params, dict):
        raise InputError(f"{p}: 'parameters' is not a mapping")
    return raw


def _identified(source: str, raw: dict):
    """The identified vehicle of a result.json, or None for one that carries only parameters."""
    from crashnlp.identified import IdentifiedModel

    entry = raw.get("identified_model")
    if entry is None:
        return None
    try:
        return IdentifiedModel.from_json(entry)
    except (KeyError, TypeError, ValueError, AttributeError):
        raise InputError(f"{source}: identified_model: not the identified model a fit writes") from None


def _with_params(problem, source: str):
    """(problem, identified model) for a result.json: its identified vehicle put into the problem,
    or for a result that carries only parameters, its values entry by entry, refusing what does
    not fit (the identified model is then None)."""
    from crashnlp.identified import apply
    from crashnlp.problem.schema import LARGEST

    raw = _read_params(source)
    identified = _identified(source, raw)
    if identified is not None:
        return apply(problem, identified, source), identified
    params = raw["parameters"]
    for path, value in params.items():
        try:
            problem.unit_at(path)
        except ValueError:
            raise InputError(f"{source}: parameters.{path}: not a parameter of {problem.name}") from None
        try:
            array = np.atleast_1d(np.asarray(value, dtype=float))
        except (TypeError, ValueError):
            raise InputError(f"{source}: parameters.{path}: not a number or a list of numbers") from None
        current = problem.value_at(path)
        size = len(current) if isinstance(current, list) else 1
        if array.ndim != 1 or array.size != size:
            raise InputError(
                f"{source}: parameters.{path}: {array.size} values, but {problem.name} has {size} "
                f"(length mismatch: the result comes from another problem)"
            )
        if not np.all(np.isfinite(array)) or np.any(np.abs(array) > LARGEST):
            raise InputError(f"{source}: parameters.{path}: not finite, or beyond any physical value")
    try:
        return problem.with_values(params), None
    except KeyError as exc:
        raise InputError(f"{source}: parameters.{exc.args[0]}: not a parameter of {problem.name}") from None
    except InputError as exc:
        raise InputError(f"{source}: {str(exc).removeprefix('with_values: ')}") from None


MAX_STEPS = 1_000_000  # output steps a simulation may ask for


def _check_dt(dt: float | None, duration: float) -> None:
    """Refuse a --dt that is not a positive number of seconds, or asks for absurdly many steps."""
    if dt is None:
        return
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(f"--dt {dt:g}: must be a positive number of seconds")
    if duration / dt > MAX_STEPS:
        raise InputError(f"--dt {dt:g}: more than {MAX_STEPS:,} output steps over {duration:g} s")


def cmd_simulate(args) -> int:
    with _figure_process(args) as figures:
        simulated = _simulate(args)
        if simulated is None:
            return 0
        case, predicted, out = simulated
        from crashnlp.prediction import simulation_figure_jobs, write_simulation

        write_simulation(case.name, predicted, out)
        if figures is not None:
            figures.draw(simulation_figure_jobs(case, predicted, out), out)
    for test in predicted.values():
        _print_prediction(test)
    print(f"wrote {out}/")
    return 0


PREDICTED_ROWS = (  # metric key, what it is, factor to the printed unit, the unit, digits after the point
    ("max_crush_m", "max crush", 1e3, "mm", 1),
    ("time_zero_velocity_s", "zero velocity", 1e3, "ms", 2),
    ("peak_decel_g", "peak decel", 1.0, "g", 1),
    ("rebound_velocity_mps", "rebound", 1.0, "m/s", 2),
    ("olc_g", "OLC", 1.0, "g", 1),
    ("max_pitch_deg", "max pitch", 1.0, "deg", 2),
)


def _print_prediction(test) -> None:
    """One line of metrics per simulated test (with their 95 % intervals when the identified model
    gave them), and one line for a test past the identified range."""
    parts = []
    for key, label, factor, unit, digits in PREDICTED_ROWS:
        value = test.metrics.get(key)
        if value is None:
            continue
        text = f"{label} {value * factor:.{digits}f}"
        band = test.intervals.get(key)
        if band is not None:
            text += f" [{band[0] * factor:.{digits}f}, {band[1] * factor:.{digits}f}]"
        parts.append(f"{text} {unit}")
    print(f"{test.name}: " + ", ".join(parts) + (" (95 % intervals)" if test.intervals else ""))
    if test.extrapolation:
        print(f"{test.name}: {_extrapolation_line(test.extrapolation)}")
    for note in test.notes:
        print(note)


def _extrapolation_line(beyond: dict) -> str:
    """How far a prediction lies past the identified range, in words."""
    parts = []
    if "crush_m" in beyond:
        parts.append(f"max crush {beyond['crush_m'] * 1e3:.0f} mm ({beyond['crush_rel'] * 100:.0f} %) past the largest fitted")
    if "speed_mps" in beyond:
        side = "above the fastest" if beyond["speed_mps"] > 0 else "below the slowest"
        parts.append(f"speed {abs(beyond['speed_mps']) * 3.6:.1f} km/h {side} fitted test")
    if "mass_kg" in beyond:
        side = "above the heaviest" if beyond["mass_kg"] > 0 else "below the lightest"
        parts.append(f"mass {abs(beyond['mass_kg']):.0f} kg {side} fitted test")
    return "extrapolates: " + "; ".join(parts)


def _simulate(args):
    """(case, predicted tests, output folder) of the problem file, or None after `--check`."""
    from crashnlp.case import case_of
    from crashnlp.prediction import predict
    from crashnlp.problem import load_problem

    _check_dt(args.dt, 0.0)
    problem = load_problem(args.problem)
    identified = None
    if args.params:
        problem, identified = _with_params(problem, args.params)
    case = case_of(problem, args.problem)
    longest = max(t.duration for t in case.tests)
    _check_dt(args.dt, longest)
    if args.dt is None and longest / case.problem.simulation.dt > MAX_STEPS:
        raise InputError(
            f"{args.problem}: simulation.dt {case.problem.simulation.dt:g} s: more than {MAX_STEPS:,} "
            f"output steps over {longest:g} s (tests' duration)"
        )
    out = Path(args.out) if args.out else RESULTS / case.name / "simulation"
    check_writable(out)
    if getattr(args, "check", False):
        print(f"{args.problem}: ok ({len(case.tests)} tests; would write {out}/)")
        return None
    with _computing(args):
        return case, predict(case, identified, args.dt), out


def _figure_process(args):
    """The process that draws the command's figures (crashnlp.drawing), started now so that
    matplotlib loads while this one works; none with --no-figures or --check."""
    from crashnlp.drawing import FigureProcess

    return nullcontext() if args.no_figures or getattr(args, "check", False) else FigureProcess()


METRIC_ROWS = (  # result.json key, label, factor
    ("max_crush_m", "max dynamic crush (mm)", 1e3),
    ("max_front_end_crush_m", "max front-end crush (mm)", 1e3),
    ("time_max_crush_s", "time of max crush (ms)", 1e3),
    ("time_zero_velocity_s", "time of zero velocity (ms)", 1e3),
    ("peak_decel_g", "peak deceleration (g)", 1.0),
    ("rebound_velocity_mps", "rebound velocity (m/s)", 1.0),
    ("olc_g", "OLC (g)", 1.0),
    ("max_pitch_deg", "max pitch (deg)", 1.0),
)


def _numbers(value, digits: int) -> str:
    """A number or list of numbers to `digits` significant digits; None shows as nan."""
    items = value if isinstance(value, list) else [value]
    values = np.array([np.nan if v is None else v for v in items], dtype=float)
    text = " ".join(f"{v:.{digits}g}" for v in values)
    return text if not isinstance(value, list) else f"[{text}]"


def _cell(value, factor: float) -> str:
    return "-" if value is None else f"{value * factor:.4g}"


def _consistency_line(c: dict) -> str:
    """The one printed line of a channel consistency (crashnlp.summary.channel_consistency)."""
    parts = [
        f"{name} {s['impulse_Ns'] / 1e3:.2f} kN s, stop {s['time_zero_velocity_s'] * 1e3:.1f} ms"
        f" after {s['max_crush_m'] * 1e3:.0f} mm, rebound {s['rebound_velocity_mps']:.1f} m/s"
        for name, s in c.items()
        if isinstance(s, dict)
    ]
    return f"channel consistency (one mass): {'; '.join(parts)}; impulse wall / accelerometers {c['impulse_ratio']:.3f}"


def _print_solution(result) -> None:
    """The console summary of a Result: status, parameters with std, metrics, fit, active constraints."""
    s = result.solver
    how = " compiled" if s.compiled else ""
    timing = f"solve {s.wall_s:.2f} s{how} + build {s.build_s:.2f} s" if s.wall_s is not None else "not solved"
    objective = f"{s.objective:.6g}" if s.objective is not None else "-"
    print(
        f"{result.name}: {result.status} (IPOPT {s.return_status or '-'}, {s.iterations} iterations, "
        f"objective {objective}, {timing})"
    )
    for path, value in result.parameters.items():
        std = result.std_errors.get(path)
        text = _numbers(value, 5)
        if std is not None:
            text += f"  (std {_numbers(std, 2)})"
        print(f"  {path} = {text}")
    if result.not_identified:
        print(f"  not identified (infinite std): {', '.join(result.not_identified)}")
    if result.at_bound:
        pulls = ", ".join(f"{label} ({pull:.2g} std)" for label, pull in result.at_bound.items())
        print(f"  at a bound (how far past it the data pull): {pulls}")
    if result.resolution:
        print(f"  {result.resolution['note']}")
    for note in result.identified.tail_notes() if result.identified is not None else ():
        print(f"  {note}")
    for name, t in result.tests.items():
        model, data = t.metrics, t.data_metrics
        print(f"  test {name:<24}{'model':>10}{'test' if data else '':>10}")
        for key, label, f in METRIC_ROWS:
            print(f"    {label:<26}{_cell(model.get(key), f):>10}{_cell(data.get(key), f) if data else '':>10}")
        if t.fit:
            print(
                "    rmse      "
                + ", ".join(f"{c} {f.rmse * OUTPUT[c].factor:.3g} {OUTPUT[c].report_unit}" for c, f in t.fit.items())
            )
            print("    ISO 18571 " + ", ".join(f"{c} {f.iso18571['overall']:.3f}" for c, f in t.fit.items() if f.iso18571))
        if t.consistency:
            print(f"    {_consistency_line(t.consistency)}")
        if t.energy:
            print(
                f"    energy balance error {t.energy['balance_error_relative']:.2e} of {t.energy['impact_kinetic'] / 1e3:.1f} kJ"
            )
    for c in result.active_constraints:
        print(f"  active: {c.name} at {c.points} points, multiplier {c.multiplier:.4g}")


def _solve(args, kind: str) -> int:
    """identify and design: one NLP solve, its result files and a summary. The figure process
    starts first, so that matplotlib loads while this one reads the problem and solves."""
    with _figure_process(args) as figures:
        solved = _solve_case(args, kind)
        if solved is None:
            return 0
        result, out = solved
        result.save(out, figures=False)
        if figures is not None:
            from crashnlp.result import figure_jobs

            figures.draw(figure_jobs(result, out), out)
    _print_solution(result)
    print(f"wrote {out}/")
    if not result.ok:
        print(f"crashnlp: {result.name}: {result.status}", file=sys.stderr)
        return 1
    return 0


def _solve_case(args, kind: str):
    """(Result, output folder) of the problem file, or None after `--check`: crashnlp.pipeline's
    checks and steps, as crashnlp.api's solve runs them, its errors naming the file."""
    from crashnlp.pipeline import prepare_case, solve_case
    from crashnlp.problem import load_problem

    problem = load_problem(args.problem)
    if problem.kind != kind:
        raise InputError(f"{args.problem}: kind is {problem.kind!r}; use 'crashnlp {problem.kind}'")
    case = prepare_case(problem, args.problem)  # before any solve
    out = check_writable(_out(args, problem.name))
    if getattr(args, "check", False):
        print(f"{args.problem}: ok ({len(case.tests)} tests; would write {out}/)")
        return None
    with _computing(args):
        return solve_case(case, verbose=args.verbose, progress=sys.stdout), out


def cmd_identify(args) -> int:
    return _solve(args, "identify")


def cmd_design(args) -> int:
    return _solve(args, "design")


def cmd_init(args) -> int:
    from crashnlp.init import Options, init_problem
    from crashnlp.units import UnitError, to_si

    columns = {}
    for item in args.column:
        channel, sep, name = item.partition("=")
        if not sep or not name:
            raise InputError(f"--column {item}: expected CHANNEL=NAME[:UNIT]")
        columns[channel] = name
    try:
        mass, speed = (None if v is None else to_si(v, u) for v, u in ((args.mass, "kg"), (args.speed, "m/s")))
    except UnitError as exc:
        raise InputError(f"--mass/--speed: {exc}") from None
    problem = init_problem(Path(args.data), Path(args.out), Options(args.format, mass, speed, columns, args.name))
    print(
        f"wrote {args.out}: {problem.name}, {len(problem.model.spring.known_values)} breakpoints to "
        f"{problem.model.spring.placed_breakpoints[-1] * 1e3:.0f} mm, estimates {', '.join(problem.estimate)}"
    )
    return 0


def cmd_schema(args) -> int:
    from crashnlp.problem.schema import Problem

    print(json.dumps(Problem.model_json_schema(), indent=2))
    return 0


def parser() -> argparse.ArgumentParser:
    ap = Parser(
        prog="crashnlp",
        description="Elastic-pendulum models of frontal rigid-barrier crashes: simulate, identify, design, study.",
    )
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("simulate", help="simulate every test of a problem with the forward integrator")
    p.add_argument("problem", help="problem YAML file")
    p.add_argument("--params", help="result.json whose parameters replace the problem's values")
    p.add_argument("--out", help="output folder (default results/<problem name>/simulation)")
    p.add_argument("--dt", type=float, help="output step in s (default: the problem's simulation.dt)")
    p.add_argument("--no-figures", action="store_true", help="write the result files only (batch use)")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("identify", help="fit the estimated parameters to the tests' data by an NLP (IPOPT)")
    p.add_argument("problem", help="problem YAML file with data (kind: identify, the default)")
    p.add_argument("--out", help="output folder (default results/<problem name>)")
    p.add_argument("--verbose", action="store_true", help="show IPOPT's own log")
    p.add_argument("--no-figures", action="store_true", help="write the result files only (batch use)")
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("design", help="choose spring and damper values for a design goal by an NLP (no data)")
    p.add_argument("problem", help="problem YAML file with kind: design")
    p.add_argument("--out", help="output folder (default results/<problem name>)")
    p.add_argument("--verbose", action="store_true", help="show IPOPT's own log")
    p.add_argument("--no-figures", action="store_true", help="write the result files only (batch use)")
    p.set_defaults(func=cmd_design)

    add_study_parser(sub)

    p = sub.add_parser("init", help="write a complete, commented problem file from one test's data")
    p.add_argument("data", help="data file: CSV, NHTSA EV5 header (.EV5) or ISO-MME test (.mme, folder or .zip)")
    p.add_argument("--format", choices=("csv", "nhtsa-ev5", "iso-mme"), help="default: from the file name")
    p.add_argument("--mass", help='test mass, e.g. "1350 kg" (default: the data header)')
    p.add_argument("--speed", help='impact speed, e.g. "48 km/h" (default: the data header or velocity column)')
    p.add_argument(
        "--column",
        action="append",
        default=[],
        metavar="CHANNEL=NAME[:UNIT]",
        help="CSV column of a channel (time, accel, velocity, displacement, pitch), unit if its name has none",
    )
    p.add_argument("--name", help="problem name (default: the data file's stem)")
    p.add_argument("--out", required=True, help="problem YAML file to write")
    p.set_defaults(func=cmd_init)

    p = sub.add_parser("schema", help="print the JSON Schema of problem files")
    p.set_defaults(func=cmd_schema)
    _add_common(ap, sub)
    return ap


def _add_common(ap: argparse.ArgumentParser, sub) -> None:
    """Options every command has: --debug (anywhere on the line) and --check (all but schema and init)."""
    ap.add_argument("--debug", action="store_true", help="show the traceback of a failure (anywhere on the line)")
    for name, p in sub.choices.items():
        if name not in ("schema", "init"):
            p.add_argument(
                "--check",
                action="store_true",
                help="check the input and the output folder, then stop: solve nothing, write nothing",
            )


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (an InputError, exit 2) instead of usage text."""

    def error(self, message: str):
        raise InputError(message)


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
        traceback.print_exc()
    print(f"crashnlp: {message}", file=sys.stderr)
    return code


def main(argv: list[str] | None = None) -> int:
    """Run one command; every ending is an exit status and at most one line on stderr."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    _received.clear()
    try:
        with _signals(), warnings.catch_warnings():
            if not debug:  # a library's warning is not the one line the user gets
                warnings.simplefilter("ignore")
            args = parser().parse_args(argv)
            args.debug = debug
            return args.func(args)
    except SystemExit as exc:  # --help and --version
        return exc.code if isinstance(exc.code, int) else 0
    except Interrupted as exc:
        return _fail(f"interrupted ({exc.signame}){exc.detail}", exc.code, debug)
    except KeyboardInterrupt:
        return _fail("interrupted (SIGINT)", 130, debug)
    except InputError as exc:
        return _fail(f"error: {' '.join(str(exc).split())}", 2, debug)
    except Exception as exc:  # noqa: BLE001 - the one place that turns any failure into one line
        if _received:  # a signal that arrived inside compiled code comes back as another exception
            return _fail(f"interrupted ({_received[0].signame})", _received[0].code, debug)
        return _fail(f"error: {describe(exc)}", 1, debug)
    finally:
        stop_compiles()  # none outlives the command unless CRASHNLP_KEEP_COMPILING=1 asked for that


if __name__ == "__main__":
    sys.exit(main())
