"""Bad problem files: one line naming the key, exit status 2, no traceback, nothing written."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from types import UnionType
from typing import Annotated, Literal, Union, get_args, get_origin

import numpy as np
import pytest
import yaml
from builders import BASE, ROOT, merge, small_pickup_problem

from crashnlp.base.outputs import UNFINISHED
from crashnlp.base.records import Record
from crashnlp.cli import main
from crashnlp.problem.load import read_yaml
from crashnlp.problem.parse import UniqueKeyLoader
from crashnlp.results.files import RECORD, claim, deriving, write_columns
from crashnlp.results.jsonfile import write_json

DATA = {
    "file": str(ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv"),
    "format": "csv",
    "channels": {"displacement": {"column": "disp_x_m", "unit": "m"}},
}

CASES = {
    "unknown key": ({"vehicle": {"masss": "1 kg"}}, "vehicle.masss: unknown key"),
    "internal key": ({"base_dir": "/etc"}, "base_dir: unknown key"),
    "wrong type": ({"vehicle": {"suspension": "stiff"}}, "vehicle.suspension:"),
    "wrong unit": ({"vehicle": {"mass": "2550 m"}}, "vehicle.mass:"),
    "unreadable quantity": ({"vehicle": {"cg_to_impact": "far away"}}, "vehicle.cg_to_impact: cannot read"),
    "decimal comma": ({"vehicle": {"speed": "57,09 km/h"}}, "vehicle.speed: a comma in a number; write 57.09 km/h\n"),
    "missing file": ({"tests": [{"name": "a", "data": {**DATA, "file": "nowhere.csv"}}]}, "tests.0.data.file: file not found"),
    "breakpoints not increasing": (
        {"model": {"spring": {"crush_breakpoints": [0, 0.2, 0.1, 0.3, 0.4, 0.5, 0.6, 0.7]}}},
        "model.spring.crush_breakpoints: crush_breakpoints must be strictly increasing",
    ),
    "length mismatch": (
        {"model": {"damper": {"rate_breakpoints": [0, 8, 16]}}},
        "model.damper: values has 2 entries but rate_breakpoints has 3",
    ),
    "missing key": ({"vehicle": {"cg_to_impact": None}}, "vehicle.cg_to_impact: missing key"),
    "bad estimate path": ({"estimate": {"vehicle.colour": {"bounds": [0, 1]}}}, "estimate.vehicle.colour"),
    "estimate unit": ({"estimate": {"vehicle.mass": {"bounds": ["1 m", "2 m"]}}}, "does not convert to kg"),
    "bound unit": ({"constraints": {"bounds": {"pitch": [None, "12 kg"]}}}, "constraints:"),
    "ipopt option typo": ({"solver": {"ipopt": {"max_itr": 5}}}, "solver.ipopt.max_itr: no such IPOPT option"),
    "ipopt option type": ({"solver": {"ipopt": {"max_iter": 5.5}}}, "solver.ipopt.max_iter: 5.5 is not an integer"),
    "ipopt option range": ({"solver": {"ipopt": {"tol": -1}}}, "solver.ipopt.tol: -1 is outside IPOPT's range 0 < tol"),
    "ipopt option setting": ({"solver": {"ipopt": {"mu_strategy": "fast"}}}, "solver.ipopt.mu_strategy: 'fast' is none of"),
    "breakpoint count": (
        {"model": {"spring": {"crush_breakpoints": {"count": 50}, "values": None}}},
        "model.spring.crush_breakpoints: a list of crush values, or {count: N} with N from 2 to 30 (count: Input should be"
        " less than or equal to 30)\n",
    ),
    "breakpoints of no form": (
        {"model": {"spring": {"crush_breakpoints": "many", "values": None}}},
        "model.spring.crush_breakpoints: a list of crush values, or {count: N} with N from 2 to 30\n",
    ),
    "tail": (
        {"model": {"spring": {"tail": "trnd"}}},
        "model.spring.tail: trend, segment, or {start: a crush, slope: a stiffness}\n",
    ),
    "column": (
        {"tests": [{"name": "a", "data": {**DATA, "channels": {"accel": {"column": 1.5}}}}]},
        "tests.0.data.channels.accel.column: a column's name, or its number counted from 1\n",
    ),
    "column true": (
        {"tests": [{"name": "a", "data": {**DATA, "channels": {"accel": {"column": True}}}}]},
        "tests.0.data.channels.accel.column: a column's name, or its number counted from 1\n",
    ),
    "bias window past impact": (
        {"tests": [{"name": "a", "data": {**DATA, "bias_window": ["0 s", "0.05 s"]}}]},
        "tests.0.data.bias_window: ends at 0.05 s, after impact (t = 0)",
    ),
    "curves true": (
        {"tests": [{"name": "a", "data": {**DATA, "channels": {"accel": {"curves": [93, False]}}}}]},
        "tests.0.data.channels.accel.curves: a list of curve numbers, or all-valid-barrier-fx (1: Input should be a number,"
        " not true or false)\n",
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_bad_problem_file(name, tmp_path, capsys):
    changes, expected = CASES[name]
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(merge(BASE, changes)))
    out = tmp_path / "out"
    code = main(["simulate", str(path), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert expected in err, err
    assert str(path) in err
    assert not out.exists()


SPRING = {"model.spring.values": {"bounds": ["0 kN", "2 MN"]}}


@pytest.mark.parametrize(
    ("changes", "expected"),
    [
        (
            {
                "estimate": {"vehicle.cg_above_impact": {"bounds": [0, 0.6]}},
                "uncertainty": {"profile": ["vehicle.cg_above_impakt"]},
            },
            "uncertainty.profile: vehicle.cg_above_impakt is not an estimated entry (vehicle.cg_above_impact)",
        ),
        (
            {"estimate": {"vehicle.cg_above_impact": {"bounds": [0, 0.6]}}, "uncertainty": {"profile": ["vehicle.mass"]}},
            "uncertainty.profile: vehicle.mass is not an estimated entry (vehicle.cg_above_impact)",
        ),
        (
            {"estimate": {"model.spring.values": {"bounds": [0, "3 MN"]}}, "uncertainty": {"profile": ["model.spring.values"]}},
            "uncertainty.profile: model.spring.values is not an estimated entry (model.spring.values[0], ",
        ),
    ],
)
def test_a_profile_of_no_estimated_value_is_refused_by_check_naming_file_and_key(tmp_path, capsys, changes, expected):
    """A typo in uncertainty.profile, a value not estimated, a whole list: refused before any solve,
    by --check too, in one line naming the file and the key."""
    path = tmp_path / "profiled.yaml"
    path.write_text(yaml.safe_dump(merge(BASE, {"tests": [{"name": "a", "data": DATA}], **changes})))
    out = tmp_path / "out"
    assert main(["identify", str(path), "--out", str(out), "--check"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"crashnlp: error: {path}: {expected}") and err.count("\n") == 1, err
    assert not out.exists()


def test_a_profile_past_the_values_completed_from_the_data_is_refused_by_check(tmp_path, capsys):
    """The Camry's breakpoints are chosen from its data (14 of them): a profile of values[40] was
    let through at load, --check said ok, and the run solved, then exited 2 naming an internal
    function (`with_values`). It is refused before any solve, naming the file and the key."""
    problem = read_yaml(ROOT / "problems/nhtsa-10146.yaml")
    problem["uncertainty"] = {"profile": ["model.spring.values[40]"]}
    problem["tests"][0]["data"]["file"] = str(ROOT / "problems" / problem["tests"][0]["data"]["file"])
    path = tmp_path / "camry.yaml"
    path.write_text(yaml.safe_dump(problem))
    out = tmp_path / "out"
    for check in (["--check"], []):
        assert main(["identify", str(path), "--out", str(out), *check]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"crashnlp: error: {path}: uncertainty.profile: model.spring.values[40] is not"), err
        assert "with_values" not in err and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.parametrize(
    ("command", "changes", "expected"),
    [
        ("identify", {"estimate": SPRING}, "tests: no test has data to fit"),
        ("identify", {"tests": [{"name": "a", "data": DATA}]}, "estimate: names no parameter to identify"),
        ("design", {"kind": "design", "design": {"minimize": "peak_decel"}}, "estimate: names no design variable"),
        (
            "identify",
            {"model": {"form": "rigid-body"}, "tests": [{"name": "a", "data": DATA}], "estimate": {"vehicle.crush_offset": {}}},
            "estimate.vehicle.crush_offset: model.form rigid-body does not read it (no equation of the form depends on it);"
            " leave it out",
        ),
    ],
)
@pytest.mark.parametrize("check", [["--check"], []])
def test_nothing_to_solve_for_is_refused_naming_file_and_key_by_check_too(tmp_path, capsys, command, changes, expected, check):
    """A fit with no test data or no estimate, a design with no design variable, a fit of a value
    its form does not read (its std infinite, every prediction without intervals): `--check` says
    so as the run does (it said ok), the line naming the file and its key."""
    path = tmp_path / "nothing.yaml"
    path.write_text(yaml.safe_dump(merge(BASE, changes)))
    out = tmp_path / "out"
    assert main([command, str(path), "--out", str(out), *check]) == 2
    assert capsys.readouterr().err == f"crashnlp: error: {path}: {expected}\n"
    assert not out.exists()


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("name: [unclosed\n", "line 2 not valid YAML: expected ',' or ']', but got '<stream end>'"),
        ("name: x\nvehicle:\n\tmass: 1 kg\n", "line 3 not valid YAML: a tab, where YAML indents and separates with spaces"),
        ("name: x\nname: y\n", "line 2 not valid YAML: duplicate key 'name'"),
    ],
)
def test_bad_yaml_says_where_and_what(tmp_path, capsys, text, expected):
    path = tmp_path / "broken.yaml"
    path.write_text(text)
    assert main(["simulate", str(path)]) == 2
    assert capsys.readouterr().err == f"crashnlp: error: {path}: {expected}\n"


def _typed(value):
    """`value` with the type of every part beside it, floats by their repr: 1 and 1.0, True and 1,
    or -0.0 and 0.0 differ."""
    if isinstance(value, dict):
        return {k: _typed(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_typed(v) for v in value]
    return type(value).__name__, repr(value) if isinstance(value, float) else value


def test_a_file_read_again_gives_its_values_of_the_same_types_and_a_changed_file_its_new_ones(tmp_path, monkeypatch):
    """The second read of a text comes from the cache (not PyYAML), with the values and types
    PyYAML gave; a changed text, or a kept file that cannot be read, is parsed again."""
    monkeypatch.setenv("CRASHNLP_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "p.yaml"
    path.write_text("name: a\nvalues: [1, 2.5, -0.0, 1.0e+300, .inf, true, null, '3', 0x1f]\nnested: {k: [x, {y: 2}]}\n")
    parsed = yaml.load(path.read_text(), Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    first = read_yaml(path)
    (kept,) = (tmp_path / "cache").glob("yaml-*.json")
    kept.write_text(json.dumps({"name": "from the cache"}))
    assert read_yaml(path) == {"name": "from the cache"}  # the second read is the kept file's
    kept.unlink()
    assert _typed(read_yaml(path)) == _typed(first) == _typed(parsed)
    assert _typed(read_yaml(path)) == _typed(parsed)  # read back from the file just kept
    kept.write_text("{not json")
    assert _typed(read_yaml(path)) == _typed(parsed)
    path.write_text("name: b\n")
    assert read_yaml(path) == {"name": "b"}


def test_values_aliases_point_to_are_a_copy_at_each_place_on_every_read(tmp_path, monkeypatch):
    """As the shipped two-test pickup shares its channels: a change to one test's (a study's sweep)
    is that test's alone, whether the file was read before or not."""
    monkeypatch.setenv("CRASHNLP_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "p.yaml"
    path.write_text("a: &shared [1, 2]\nb: *shared\n")
    for _ in range(2):
        values = read_yaml(path)
        assert values == {"a": [1, 2], "b": [1, 2]} and values["a"] is not values["b"]
    assert len(list((tmp_path / "cache").glob("yaml-*.json"))) == 1


ALIAS_BOMB = "l0: &l0 [x]\n" + "".join(f"l{i}: &l{i} [*l{i - 1}, *l{i - 1}]\n" for i in range(1, 40))


@pytest.mark.parametrize(
    "text",
    [ALIAS_BOMB, "a: &x [1, *x]\n", "x: 0x" + "f" * 4000 + "\n", "x: " + "9" * 4400 + "\n"],
    ids=["aliases doubling 39 times", "a list holding itself", "a hex integer of 4,800 digits", "an integer of 4,400 digits"],
)
def test_a_file_json_would_blow_up_or_fail_on_is_one_line_at_once_and_not_kept(tmp_path, monkeypatch, capsys, text):
    """JSON would write the doubling aliases out 2^39 times, recurse for ever into the list that
    holds itself, and refuse the hex integer (Python's limit on digits turned into text); PyYAML
    refuses the decimal one."""
    monkeypatch.setenv("CRASHNLP_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "p.yaml"
    path.write_text(text)
    assert main(["simulate", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"crashnlp: error: {path}: ") and err.count("\n") == 1 and "Traceback" not in err
    assert not list((tmp_path / "cache").glob("yaml-*.json"))


@pytest.mark.parametrize(
    "text", ["when: 2026-12-05\n", "1: x\n", "at: 2026-12-05 10:00:00\n", "blob: !!binary aGk=\n", "s: !!set {a: null}\n"]
)
def test_yaml_values_json_cannot_hold_are_parsed_on_every_read(tmp_path, monkeypatch, text):
    monkeypatch.setenv("CRASHNLP_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "p.yaml"
    path.write_text(text)
    parsed = yaml.load(text, Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    assert read_yaml(path) == read_yaml(path) == parsed
    assert not list((tmp_path / "cache").glob("yaml-*.json"))


def test_bad_yaml_and_missing_problem(tmp_path, capsys):
    assert main(["identify", str(tmp_path / "none.yaml")]) == 2
    assert "file not found" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("command", "what"),
    [(["identify"], "a problem file (YAML)"), (["compare"], "a problem file (YAML)"), (["study"], "a study file (YAML)")],
)
def test_a_folder_given_for_a_yaml_file_is_called_a_folder(tmp_path, capsys, command, what):
    """A folder where a problem or a study file goes (a data folder, a fit's folder to compare) was
    said to be "file not found"."""
    assert main([*command, str(tmp_path)]) == 2
    assert capsys.readouterr().err == f"crashnlp: error: {tmp_path}: a folder; give {what}\n"


@pytest.mark.parametrize(
    "command",
    [
        ["identify", "p.yaml"],
        ["design", "p.yaml"],
        ["simulate", "p.yaml"],
        ["compare", "p.yaml"],
        ["init", "data.csv"],
        ["report", "fit"],
        ["compare-results", "fit", "sim"],
        ["export", "fit", "--format", "ls-dyna"],
    ],
)
def test_an_empty_out_is_refused_on_every_command_that_takes_it(tmp_path, monkeypatch, capsys, command):
    """`--out ""` was read as no --out: report and export wrote to their default path without a
    word. Every command that takes --out refuses it, one line naming it, exit 2, nothing written."""
    monkeypatch.chdir(tmp_path)
    assert main([*command, "--out", ""]) == 2
    assert capsys.readouterr().err == 'crashnlp: error: --out "": names nothing; name the folder or file to write\n'
    assert not list(tmp_path.iterdir())


def test_an_option_of_one_value_given_twice_is_refused(tmp_path, capsys):
    """argparse took the last of a repeated `--speed` silently; which was meant is the user's to say."""
    problem = str(ROOT / "problems/pickup-56kph.yaml")
    assert main(["simulate", problem, "--speed", "48 km/h", "--speed", "64 km/h", "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err == "crashnlp: error: --speed: given twice; give it once\n"
    assert not list(tmp_path.iterdir())


def test_bad_params_file(tmp_path, capsys):
    problem = tmp_path / "p.yaml"
    problem.write_text(yaml.safe_dump(BASE))
    params = tmp_path / "result.json"
    params.write_text(json.dumps({"parameters": {"model.spring.colour": 1}}))
    for given in (params, tmp_path):  # the file, or the fit's folder holding it
        assert main(["simulate", str(problem), "--params", str(given), "--out", str(tmp_path / "o")]) == 2
        assert "parameters.model.spring.colour" in capsys.readouterr().err
        assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("holds", [(), ("simulation.json",), ("cases/",)])
def test_simulate_of_a_folder_without_a_result_says_so(tmp_path, capsys, holds):
    folder = tmp_path / "folder"
    folder.mkdir()
    for name in holds:
        (folder / name).mkdir() if name.endswith("/") else (folder / name).write_text("{}")
    assert main(["simulate", str(folder), "--out", str(tmp_path / "o")]) == 2
    expected = f"{folder}: a folder without result.json; simulate a problem file, or a fit's folder"
    assert capsys.readouterr().err == f"crashnlp: error: {expected}\n"
    assert not (tmp_path / "o").exists()


def test_schema_lists_the_problem_keys(capsys):
    assert main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert {"vehicle", "model", "tests", "estimate", "constraints", "transcription"} <= set(schema["properties"])
    assert "base_dir" not in schema["properties"]  # where a loaded problem's paths start: the loader's, no file's key


def test_an_ipopt_option_typo_stops_identify_before_any_solve(tmp_path, capsys):
    fit = merge(BASE, {"tests": [{"name": "a", "data": DATA}], "solver": {"ipopt": {"max_itr": 5, "sb": "yes"}}})
    path = tmp_path / "fit.yaml"
    path.write_text(yaml.safe_dump(fit))
    code = main(["identify", str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert err == f"crashnlp: error: {path}: solver.ipopt.max_itr: no such IPOPT option (did you mean max_iter?)\n"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("option", "value", "expected"),
    [
        ("--speed", "64 kmh", "--speed 64 kmh: cannot read '64 kmh' as a quantity"),
        ("--speed", "64 kg", "--speed 64 kg: '64 kg' does not convert to m/s"),
        ("--speed", "-3 m/s", "--speed -3 m/s: must not be negative"),
        ("--speed", "nan", "--speed nan: not a finite number"),
        ("--mass", "3 g", "--mass 3 g: 0.003 kg is no vehicle's mass"),
        ("--speed", "64", '--speed 64: give its unit, e.g. "64 km/h" or "64 m/s"'),
        ("--speed", "0 km/h", "--speed 0 km/h: 0 m/s is no impact"),
        ("--speed", "40,5 km/h", "--speed 40,5 km/h: a comma in a number; write 40.5 km/h\n"),
        ("--mass", "1719,5 kg", "--mass 1719,5 kg: a comma in a number; write 1719.5 kg\n"),
    ],
)
def test_a_bad_what_if_is_refused_in_one_line_naming_the_option(option, value, expected, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["simulate", str(ROOT / "problems/pickup-56kph.yaml"), option, value, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert expected in err, err
    assert not out.exists()


@pytest.mark.parametrize("dt", ["0.5 ms", "0.0005"])
def test_dt_takes_a_unit_as_speed_and_mass_do(tmp_path, dt):
    """--dt "0.5 ms" is 0.5 ms; a plain number is seconds."""
    path, out = tmp_path / "p.yaml", tmp_path / "out"
    path.write_text(yaml.safe_dump(merge(BASE, {"tests": [{"name": "t", "duration": "0.05 s"}]})))
    assert main(["simulate", str(path), "--dt", dt, "--out", str(out), "--no-figures"]) == 0
    time = np.loadtxt(out / "t/response.csv", delimiter=",", skiprows=1, usecols=0)
    assert np.diff(time) == pytest.approx(5e-4, rel=1e-9) and time[-1] == pytest.approx(0.05)


def test_a_problem_file_written_in_json_is_simulated_as_its_yaml_twin(tmp_path):
    """JSON is YAML, and identify reads a problem written in it: simulate of that .json file (CLI
    and API) is a simulation of the problem, not a result.json with no parameters."""
    import crashnlp

    problem = merge(BASE, {"tests": [{"name": "t", "duration": "0.15 s"}]})
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(problem))
    (tmp_path / "p.json").write_text(json.dumps(problem))
    for name in ("p.yaml", "p.json"):
        assert main(["simulate", str(tmp_path / name), "--out", str(tmp_path / f"out-{name}"), "--no-figures"]) == 0
    written = [json.loads((tmp_path / f"out-{name}" / "simulation.json").read_text()) for name in ("p.yaml", "p.json")]
    assert "max_displacement_m" in written[1]["tests"]["t"]["metrics"]
    assert written[0]["tests"]["t"]["metrics"] == written[1]["tests"]["t"]["metrics"]
    assert crashnlp.simulate(tmp_path / "p.json")["t"].metrics == pytest.approx(written[1]["tests"]["t"]["metrics"])


@pytest.mark.integration
def test_a_fit_that_did_not_converge_prints_it_first_and_no_standard_errors(tmp_path, capsys):
    """Its values are a last iterate: the console says so before them and gives them no standard
    errors or pulls past a bound in them, as its report and `simulate` give none."""
    given = (ROOT / "problems/pickup-56kph.yaml").read_text().replace("file: data/", f"file: {ROOT}/problems/data/")
    problem = tmp_path / "stopped.yaml"
    problem.write_text(given + "solver: {ipopt: {max_iter: 3}}\n")
    assert main(["identify", str(problem), "--out", str(tmp_path / "out"), "--no-figures"]) == 1
    printed = capsys.readouterr().out.splitlines()
    at = next(i for i, line in enumerate(printed) if line.startswith("pickup-56kph: solver failed"))
    assert printed[at + 1].startswith("  NOT CONVERGED: the fit ended solver failed: Maximum_Iterations_Exceeded")
    assert printed[at + 2].startswith("  model.spring.values = [")
    assert not any("(std " in line or "how far past it the data pull" in line for line in printed)


def _simulated(tmp_path, name: str, tests: list[str], out) -> int:
    """`crashnlp simulate` of BASE named `name` with tests of 50 ms named `tests`, into `out`."""
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(merge(BASE, {"name": name, "tests": [{"name": t, "duration": "0.05 s"} for t in tests]})))
    return main(["simulate", str(path), "--out", str(out), "--no-figures"])


def test_an_output_folder_holds_one_run(tmp_path, capsys):
    """Run again, a run leaves the folder as it wrote it (the test renamed since: its folder
    removed; the user's own file kept); another problem's run into it is refused before it starts."""
    out = tmp_path / "out"
    assert _simulated(tmp_path, "a", ["t1", "t2"], out) == 0
    (out / "my-notes.txt").write_text("mine")
    assert _simulated(tmp_path, "a", ["t1", "t3"], out) == 0
    assert sorted(p.name for p in out.iterdir()) == [RECORD, "my-notes.txt", "simulation.json", "t1", "t3"]
    record = {"run": "simulate a", "entries": ["simulation.json", "t1/response.csv", "t3/response.csv"]}
    assert json.loads((out / RECORD).read_text()) == record
    capsys.readouterr()
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    assert _simulated(tmp_path, "b", ["t1"], out) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--out {out}: holds the results of another run (simulate a), not of simulate b" in err
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == before  # nothing of b written


@pytest.mark.parametrize(
    ("command", "entry", "kind"),
    [
        ("identify", "56kph", "file"),
        ("identify", "force_crush.csv", "folder"),
        ("identify", "56kph/fit.png", "folder"),
        ("simulate", "simulation.json", "folder"),
        ("simulate", "56kph", "file"),
    ],
)
def test_an_entry_in_the_way_of_a_runs_file_is_refused_before_any_solve(tmp_path, capsys, command, entry, kind):
    """A file where a run writes a folder (a test's), or a folder where it writes a file, was found
    only as the run wrote, after its solve, leaving it half written: it is refused before (a unit
    test: no NLP is solved), one line naming the entry, exit 2, nothing written."""
    problem, out = small_pickup_problem(tmp_path), tmp_path / "out"
    (out / entry).parent.mkdir(parents=True, exist_ok=True)
    (out / entry).mkdir() if kind == "folder" else (out / entry).write_text("mine")
    before = sorted(tmp_path.rglob("*"))
    assert main([command, str(problem), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{out / entry} is a {kind} where crashnlp writes" in err, err
    assert sorted(tmp_path.rglob("*")) == before


def test_a_record_naming_files_outside_its_folder_removes_nothing_there(tmp_path, capsys):
    out, outside = tmp_path / "out", tmp_path / "precious.txt"
    outside.write_text("mine")
    assert _simulated(tmp_path, "a", ["t1"], out) == 0
    (out / RECORD).write_text(json.dumps({"run": "simulate a", "entries": ["../precious.txt", "/etc/hostname"]}))
    assert _simulated(tmp_path, "a", ["t1"], out) == 0
    assert outside.read_text() == "mine"


@pytest.mark.integration
def test_what_derives_from_a_run_goes_with_it_when_a_run_replaces_it(tmp_path, capsys):
    """A report and a pulse export of a simulation are listed in its folder's record; the next
    run into the folder removes them and says so, but keeps a derived file changed since, the
    user's own file, and an export written outside the folder."""
    out, outside = tmp_path / "out", tmp_path / "pulse-of-mine.csv"
    assert _simulated(tmp_path, "a", ["t1"], out) == 0
    assert main(["report", str(out)]) == 0
    assert main(["export", str(out), "--format", "pulse"]) == 0
    assert main(["export", str(out), "--format", "pulse", "--out", str(outside)]) == 0
    assert main(["export", str(out), "--format", "pulse", "--out", str(out / "edited.csv")]) == 0
    assert set(json.loads((out / RECORD).read_text())["derived"]) == {"report.html", "t1-pulse.csv", "edited.csv"}
    (out / "my-notes.txt").write_text("mine")
    with open(out / "edited.csv", "a") as fh:
        fh.write("# my remark\n")
    capsys.readouterr()
    assert _simulated(tmp_path, "a", ["t1"], out) == 0
    err = capsys.readouterr().err
    assert f"crashnlp: {out}: removed report.html, t1-pulse.csv: derived from the run replaced" in err
    assert f"crashnlp: {out}: kept edited.csv: derived from the run replaced, but changed since" in err
    assert sorted(p.name for p in out.iterdir()) == [RECORD, "edited.csv", "my-notes.txt", "simulation.json", "t1"]
    assert outside.is_file()
    assert "derived" not in json.loads((out / RECORD).read_text())


def test_a_simulation_of_a_replaced_fit_goes_with_it_unless_run_again_since(tmp_path, capsys):
    """A simulation written inside a fit's folder from its result (crashnlp simulate FIT) goes when
    the fit is replaced; one written there afterwards from something else, and another run's
    folder there, stay."""
    fit = tmp_path / "fit"
    with claim(fit, "identify x"):
        write_json(fit / "result.json", {"fit": 1})
    derived, again, other = fit / "simulation", fit / "again", fit / "other"
    for sim in (derived, again):
        with deriving(fit, sim), claim(sim, "simulate x"):
            write_json(sim / "simulation.json", {"from": 1})
            write_json(sim / "t1" / "response.json", {"from": 1})
    with claim(again, "simulate x"):
        write_json(again / "simulation.json", {"from": "another problem"})
    with claim(other, "simulate y"):
        write_json(other / "simulation.json", {"from": 2})
    capsys.readouterr()
    with claim(fit, "identify x"):
        write_json(fit / "result.json", {"fit": 2})
    assert sorted(p.name for p in fit.iterdir()) == [RECORD, "again", "other", "result.json"]
    assert (again / "simulation.json").is_file() and (other / "simulation.json").is_file()
    err = capsys.readouterr().err
    assert "removed simulation/" in err and "kept again/" in err


def test_a_csv_column_writes_a_zero_as_0_not_minus_0(tmp_path):
    """A crush of -0.0 at t = 0 (a product of a negative and a zero) was written "-0"."""
    write_columns(tmp_path / "c.csv", {"time_s": np.array([0.0, 1e-3]), "crush_m": np.array([-0.0, -2.5e-7])})
    assert (tmp_path / "c.csv").read_text().splitlines() == ["time_s,crush_m", "0,0", "0.001,-2.5e-07"]


def test_a_run_that_fails_leaves_no_folder_it_made(tmp_path):
    deep = tmp_path / "new" / "deeper"
    with pytest.raises(RuntimeError), claim(deep, "simulate a"):
        raise RuntimeError("the integrator failed")
    assert list(tmp_path.iterdir()) == []


HOLD = """
import sys, time
from pathlib import Path
from crashnlp.results.files import claim
with claim(Path(sys.argv[1]), "simulate a"):
    print("held", flush=True)
    time.sleep(60)
"""


@pytest.mark.integration
def test_two_runs_into_one_folder_at_once_the_second_is_refused(tmp_path, capsys):
    out = tmp_path / "out"
    assert _simulated(tmp_path, "a", ["t1"], out) == 0
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        capsys.readouterr()
        assert _simulated(tmp_path, "a", ["t1"], out) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"--out {out}: another crashnlp run is writing in it now" in err
    finally:
        holder.kill()
        holder.wait()
    assert _simulated(tmp_path, "a", ["t1"], out) == 0  # the lock goes with the run that held it


def _cut_pickup(tmp_path, **test) -> tuple:
    """A problem whose test reads the shipped pickup cut at 45 ms (still moving at 6.5 m/s)."""
    rows = (ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv").read_text().splitlines()[:452]
    csv = tmp_path / "cut45.csv"
    csv.write_text("\n".join(rows) + "\n")
    data = {**DATA, "file": str(csv), **test.pop("data", {})}
    path = tmp_path / "cut.yaml"
    path.write_text(yaml.safe_dump(merge(BASE, {"tests": [{"name": "cut", "data": data, **test}]})))
    return path, tmp_path / "out"


@pytest.mark.parametrize(
    "command, test, key",
    [
        ("simulate", {"data": {"window": ["0 s", "0.2 s"]}}, "tests.0.data.window: runs to 200 ms"),
        ("identify", {"duration": "0.1 s"}, "tests.0.duration: runs to 100 ms"),
    ],
)
def test_a_span_past_the_data_is_refused(tmp_path, capsys, command, test, key):
    path, out = _cut_pickup(tmp_path, **test)
    assert main([command, str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    where = "the data of test cut end at 45 ms (cut45.csv, channel displacement)"
    assert err == f"crashnlp: error: {path}: {key}, but {where}; shorten it to the data, or give the whole record\n"
    assert not out.exists()


@pytest.mark.integration
def test_a_window_a_sample_past_the_data_is_taken(tmp_path):
    path, out = _cut_pickup(tmp_path, data={"window": ["0 s", "0.0451 s"]})
    assert main(["simulate", str(path), "--out", str(out), "--no-figures"]) == 0


@pytest.mark.integration
def test_a_fit_of_a_record_that_ends_moving_says_so(tmp_path, capsys):
    channels = {"accel": {"column": "accel_x_g", "unit": "g"}, "velocity": {"column": "vel_x_mps"}, **DATA["channels"]}
    path, out = _cut_pickup(tmp_path, data={"window": ["0 s", "0.045 s"], "channels": channels})
    fit = merge(yaml.safe_load(path.read_text()), {"estimate": {"model.spring.values": {"bounds": [0, "3 MN"]}}})
    path.write_text(yaml.safe_dump(merge(fit, {"transcription": {"method": "multiple-shooting", "intervals": 45}})))
    assert main(["identify", str(path), "--out", str(out), "--no-figures"]) == 0
    printed = capsys.readouterr().out
    for row in ("max displacement (mm)", "time of zero velocity (ms)", "peak deceleration (g, CFC60)", "rebound velocity (m/s)"):
        assert re.search(rf"{re.escape(row)} +- +-\n", printed)  # neither the model nor the data has it, one sign for both
    assert "nan" not in printed
    assert "the test record ends at 45.0 ms still moving toward the barrier at 6.5" in printed
    assert "the model ends at 45.0 ms still moving toward the barrier at 6.5" in printed
    saved = json.loads((out / "result.json").read_text())
    assert any(n.startswith("test cut: the record ends at 45.0 ms still moving") for n in saved["notes"])
    assert any(n.startswith("test cut: the model ends at 45.0 ms still moving") for n in saved["notes"])
    for who in ("model", "data"):  # the model's travel at 45 ms is no more its max displacement than the data's
        metrics = saved["tests"]["cut"]["metrics"][who]
        assert all(metrics[k] is None for k in UNFINISHED), who
        assert metrics["end_velocity_mps"] == pytest.approx(6.5, abs=0.05)


def _forms(annotation) -> list:
    """The forms a field's type allows (Optional's None left out, Annotated's metadata looked through)."""
    if get_origin(annotation) is Annotated:
        return _forms(get_args(annotation)[0])
    if get_origin(annotation) in (Union, UnionType):
        return [form for arg in get_args(annotation) for form in _forms(arg)]
    return [] if annotation is type(None) else [annotation]


def _union_keys(model: type[Record], seen: set) -> set[str]:
    """The keys of a model and the models inside it whose type allows more than one form."""
    keys = set()
    for name, info in model.model_fields.items():
        forms = _forms(info.annotation)
        keys |= {name} if len(forms) > 1 and not all(get_origin(f) is Literal for f in forms) else set()
        inner = [a for f in forms for a in (f, *get_args(f)) for a in _forms(a)]
        for sub in inner:
            if isinstance(sub, type) and issubclass(sub, Record) and sub not in seen:
                seen.add(sub)
                keys |= _union_keys(sub, seen)
    return keys


def test_every_key_of_several_forms_says_them_in_words():
    from crashnlp.problem.errors import UNION_FORMS
    from crashnlp.problem.schema import Problem

    named_by_tag = {"transcription"}  # its `method` picks the form, and the error names the methods
    assert _union_keys(Problem, set()) - named_by_tag == set(UNION_FORMS)


def test_a_blank_cell_names_its_column_and_line(tmp_path, capsys):
    lines = (ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv").read_text().splitlines()
    cells = lines[300].split(",")
    lines[300] = ",".join([*cells[:3], "", *cells[4:]])  # disp_x_m left blank
    csv = tmp_path / "blank.csv"
    csv.write_text("\n".join(lines) + "\n")
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(merge(BASE, {"tests": [{"name": "a", "data": {**DATA, "file": str(csv)}}]})))
    assert main(["simulate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    key = "tests.0.data.channels.displacement"
    assert err == f"crashnlp: error: {path}: {key}: {csv}: channel displacement (column disp_x_m): line 301: a blank cell\n"
    assert not (tmp_path / "out").exists()
