"""Bad problem files: one line naming the key, exit status 2, no traceback, nothing written."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import yaml
from builders import BASE, ROOT, merge

from crashnlp.cli import main
from crashnlp.files import RECORD, claim

DATA = {
    "file": str(ROOT / "problems/data/synthetic-pickup/pickup-56kph.csv"),
    "format": "csv",
    "channels": {"displacement": {"column": "disp_x_m", "unit": "m"}},
}

CASES = {
    "unknown key": ({"vehicle": {"masss": "1 kg"}}, "vehicle.masss: unknown key"),
    "wrong type": ({"vehicle": {"suspension": "stiff"}}, "vehicle.suspension:"),
    "wrong unit": ({"vehicle": {"mass": "2550 m"}}, "vehicle.mass:"),
    "unreadable quantity": ({"vehicle": {"cg_to_impact": "far away"}}, "vehicle.cg_to_impact: cannot read"),
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


def test_bad_yaml_and_missing_problem(tmp_path, capsys):
    path = tmp_path / "broken.yaml"
    path.write_text("name: [unclosed\n")
    assert main(["simulate", str(path)]) == 2
    assert "not valid YAML" in capsys.readouterr().err
    assert main(["identify", str(tmp_path / "none.yaml")]) == 2
    assert "file not found" in capsys.readouterr().err


def test_bad_params_file(tmp_path, capsys):
    problem = tmp_path / "p.yaml"
    problem.write_text(yaml.safe_dump(BASE))
    params = tmp_path / "result.json"
    params.write_text(json.dumps({"parameters": {"model.spring.colour": 1}}))
    assert main(["simulate", str(problem), "--params", str(params), "--out", str(tmp_path / "o")]) == 2
    assert "parameters.model.spring.colour" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_schema_lists_the_problem_keys(capsys):
    assert main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert {"vehicle", "model", "tests", "estimate", "constraints", "transcription"} <= set(schema["properties"])


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
    ],
)
def test_a_bad_what_if_is_refused_in_one_line_naming_the_option(option, value, expected, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["simulate", str(ROOT / "problems/pickup-56kph.yaml"), option, value, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert expected in err, err
    assert not out.exists()


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


def test_a_record_naming_files_outside_its_folder_removes_nothing_there(tmp_path, capsys):
    out, outside = tmp_path / "out", tmp_path / "precious.txt"
    outside.write_text("mine")
    assert _simulated(tmp_path, "a", ["t1"], out) == 0
    (out / RECORD).write_text(json.dumps({"run": "simulate a", "entries": ["../precious.txt", "/etc/hostname"]}))
    assert _simulated(tmp_path, "a", ["t1"], out) == 0
    assert outside.read_text() == "mine"


def test_a_run_that_fails_leaves_no_folder_it_made(tmp_path):
    deep = tmp_path / "new" / "deeper"
    with pytest.raises(RuntimeError), claim(deep, "simulate a"):
        raise RuntimeError("the integrator failed")
    assert list(tmp_path.iterdir()) == []


HOLD = """
import sys, time
from pathlib import Path
from crashnlp.files import claim
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
