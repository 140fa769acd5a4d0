"""The `crashnlp` command: simulate, identify, design, study, init, schema.

Bad input exits with status 2 and one line; a solve that fails exits 1 and
says IPOPT's status; nothing is written for bad input.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from crashnlp.errors import InputError
from crashnlp.outputs import OUTPUT
from crashnlp.studies.cli import add_parser as add_study_parser

RESULTS = Path("results")


def _out(args, name: str) -> Path:
    return Path(args.out) if args.out else RESULTS / name


def _read_params(path: str) -> dict:
    p = Path(path)
    try:
        params = json.loads(p.read_text())["parameters"]
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except (json.JSONDecodeError, KeyError, TypeError):
        raise InputError(f"{p}: not a result.json with a 'parameters' entry") from None
    if not isinstance(params, dict):
        raise InputError(f"{p}: 'parameters' is not a mapping")
    return params


def cmd_simulate(args) -> int:
    from crashnlp.case import Case
    from crashnlp.problem import load_problem
    from crashnlp.results import write_simulation

    problem = load_problem(args.problem)
    if args.params:
        params = _read_params(args.params)
        try:
            problem = problem.with_values(params)
        except KeyError as exc:
            raise InputError(f"{args.params}: parameters.{exc.args[0]}: not a parameter of {problem.name}") from None
    case = Case(problem)
    responses = case.simulate(dt=args.dt)
    out = _out(args, case.name)
    summary = write_simulation(case, responses, out)
    for name, t in summary["tests"].items():
        m = t["metrics"]
        print(
            f"{name}: max crush {m['max_crush_m'] * 1e3:.1f} mm at {m['time_max_crush_s'] * 1e3:.1f} ms, "
            f"peak decel {m['peak_decel_g']:.1f} g, rebound {m['rebound_velocity_mps']:.2f} m/s, "
            f"max pitch {m['max_pitch_deg']:.2f} deg"
        )
    print(f"wrote {out}/")
    return 0


METRIC_ROWS = (  # result.json key, label, factor
    ("max_crush_m", "max dynamic crush (mm)", 1e3),
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


def _print_solution(result) -> None:
    """The console summary of a Result: status, parameters with std, metrics, fit, active constraints."""
    s = result.solver
    timing = f"solve {s.wall_s:.2f} s + build {s.build_s:.2f} s" if s.wall_s is not None else "not solved"
    objective = f"{s.objective:.6g}" if s.objective is not None else "-"
    print(f"{result.name}: {result.status} (IPOPT {s.return_status or '-'}, {s.iterations} iterations, objective {objective}, {timing})")
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
    for name, t in result.tests.items():
        model, data = t.metrics, t.data_metrics
        print(f"  test {name:<24}{'model':>10}{'test' if data else '':>10}")
        for key, label, f in METRIC_ROWS:
            print(f"    {label:<26}{_cell(model.get(key), f):>10}{_cell(data.get(key), f) if data else '':>10}")
        if t.fit:
            print("    rmse      " + ", ".join(f"{c} {f.rmse * OUTPUT[c].factor:.3g} {OUTPUT[c].report_unit}" for c, f in t.fit.items()))
            print("    ISO 18571 " + ", ".join(f"{c} {f.iso18571['overall']:.3f}" for c, f in t.fit.items() if f.iso18571))
        if t.energy:
            print(f"    energy balance error {t.energy['balance_error_relative']:.2e} of {t.energy['impact_kinetic'] / 1e3:.1f} kJ")
    for c in result.active_constraints:
        print(f"  active: {c.name} at {c.points} points, multiplier {c.multiplier:.4g}")


def _solve(args, kind: str) -> int:
    """identify and design: one NLP solve, its result files and a summary."""
    from crashnlp.api import solve
    from crashnlp.problem import load_problem

    problem = load_problem(args.problem)
    if problem.kind != kind:
        raise InputError(f"{args.problem}: kind is {problem.kind!r}; use 'crashnlp {problem.kind}'")
    result = solve(problem, verbose=args.verbose, progress=sys.stdout)
    out = _out(args, result.name)
    result.save(out)
    _print_solution(result)
    print(f"wrote {out}/")
    if not result.ok:
        print(f"crashnlp: {result.name}: {result.status}", file=sys.stderr)
        return 1
    return 0


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
    print(f"wrote {args.out}: {problem.name}, {len(problem.model.spring.values)} breakpoints to "
          f"{problem.model.spring.crush_breakpoints[-1] * 1e3:.0f} mm, estimates {', '.join(problem.estimate)}")
    return 0


def cmd_schema(args) -> int:
    from crashnlp.problem.schema import Problem

    print(json.dumps(Problem.model_json_schema(), indent=2))
    return 0


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="crashnlp",
        description="Elastic-pendulum models of frontal rigid-barrier crashes: simulate, identify, design, study.",
    )
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("simulate", help="simulate every test of a problem with the forward integrator")
    p.add_argument("problem", help="problem YAML file")
    p.add_argument("--params", help="result.json whose parameters replace the problem's values")
    p.add_argument("--out", help="output folder (default results/<problem name>)")
    p.add_argument("--dt", type=float, help="output step in s (default: the problem's simulation.dt)")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("identify", help="fit the estimated parameters to the tests' data by an NLP (IPOPT)")
    p.add_argument("problem", help="problem YAML file with data (kind: identify, the default)")
    p.add_argument("--out", help="output folder (default results/<problem name>)")
    p.add_argument("--verbose", action="store_true", help="show IPOPT's own log")
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("design", help="choose spring and damper values for a design goal by an NLP (no data)")
    p.add_argument("problem", help="problem YAML file with kind: design")
    p.add_argument("--out", help="output folder (default results/<problem name>)")
    p.add_argument("--verbose", action="store_true", help="show IPOPT's own log")
    p.set_defaults(func=cmd_design)

    add_study_parser(sub)

    p = sub.add_parser("init", help="write a complete, commented problem file from one test's data")
    p.add_argument("data", help="data file: CSV, NHTSA EV5 header (.EV5) or ISO-MME test (.mme, folder or .zip)")
    p.add_argument("--format", choices=("csv", "nhtsa-ev5", "iso-mme"), help="default: from the file name")
    p.add_argument("--mass", help='test mass, e.g. "1350 kg" (default: the data header)')
    p.add_argument("--speed", help='impact speed, e.g. "48 km/h" (default: the data header or velocity column)')
    p.add_argument("--column", action="append", default=[], metavar="CHANNEL=NAME[:UNIT]",
                   help="CSV column of a channel (time, accel, velocity, displacement, pitch), unit if its name has none")
    p.add_argument("--name", help="problem name (default: the data file's stem)")
    p.add_argument("--out", required=True, help="problem YAML file to write")
    p.set_defaults(func=cmd_init)

    p = sub.add_parser("schema", help="print the JSON Schema of problem files")
    p.set_defaults(func=cmd_schema)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        return args.func(args)
    except InputError as exc:
        print(f"crashnlp: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
