"""The Python API: plain results equal to the command line's, round trips, immutable problems,
and fast unit tests of the NLP builder and the transcriptions (no IPOPT)."""

from __future__ import annotations

import dataclasses
import json
import pydoc
import subprocess
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import yaml
from builders import BASE, ROOT, merge, small_pickup_problem

import crashnlp
from crashnlp.base.errors import InputError
from crashnlp.cli import main
from crashnlp.numerics.nlp import DYNAMICS, NLPBuilder
from crashnlp.problem import ProblemError, problem_from_dict
from crashnlp.results.result import VOLATILE, Result, SolverStats


@pytest.fixture(scope="module")
def small_problem(tmp_path_factory):
    return small_pickup_problem(tmp_path_factory.mktemp("api"))


def _stable(result: dict) -> dict:
    for key in VOLATILE:
        result["solver"].pop(key)
    return result


@pytest.mark.integration
def test_api_result_equals_the_command_line(small_problem, tmp_path, compiled_nlp, monkeypatch):
    """The API in CasADi's virtual machine, the command line as users run it (compilation on),
    once the problem's library is compiled: the same result.json, but for how it was computed."""
    with monkeypatch.context() as mp:
        mp.setenv("CRASHNLP_COMPILE", "model")
        result = crashnlp.identify(crashnlp.load(small_problem))
    assert result.ok, result.status
    result.save(tmp_path / "api")
    now = crashnlp.identify(crashnlp.load(small_problem).with_values({"solver.compile": "now"}))
    assert now.solver.compiled and (now.status, now.solver.iterations) == (result.status, result.solver.iterations)
    for path, value in result.parameters.items():
        np.testing.assert_allclose(now.parameters[path], value, rtol=1e-12)
    assert main(["identify", str(small_problem), "--out", str(tmp_path / "cli")]) == 0
    api = json.loads((tmp_path / "api/result.json").read_text())
    cli = json.loads((tmp_path / "cli/result.json").read_text())
    assert cli["solver"]["compiled"] and not api["solver"]["compiled"]
    api, cli = _stable(api), _stable(cli)
    assert api.keys() == cli.keys()
    for path, value in cli["parameters"].items():
        np.testing.assert_allclose(api["parameters"][path], value, rtol=1e-6)
    assert api == cli
    files = {p.relative_to(tmp_path / "cli") for p in (tmp_path / "cli").rglob("*")}
    assert files == {p.relative_to(tmp_path / "api") for p in (tmp_path / "api").rglob("*")}


@pytest.mark.integration
def test_simulate_takes_a_fits_folder_as_the_command_does(small_problem, tmp_path, capsys):
    """A fit's folder (or its result.json) given as the problem: its own tests with its identified
    vehicle, as `crashnlp simulate FOLDER` and a Result in memory give them; with params too, or
    a folder without result.json, the command's refusals (InputError)."""
    result = crashnlp.identify(crashnlp.load(small_problem))
    result.save(tmp_path / "fit", figures=False)
    folder = tmp_path / "fit"
    for given in (folder, str(folder / "result.json")):
        (test,) = crashnlp.simulate(given, speed="50 km/h").values()
        (alone,) = crashnlp.simulate(crashnlp.Result.load(folder), speed="50 km/h").values()
        assert test.metrics == alone.metrics and test.intervals == alone.intervals
        assert test.source["result"]["path"] == str(given)
    with pytest.raises(InputError, match="is a result already; give a problem file with params="):
        crashnlp.simulate(folder, params=folder)
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="a folder without result.json"):
        crashnlp.simulate(tmp_path / "empty")
    assert main(["simulate", str(folder), "--params", str(folder), "--out", str(tmp_path / "o")]) == 2
    assert "is a result already; give a problem file with --params" in capsys.readouterr().err


@pytest.mark.integration
def test_result_loads_back_what_it_saved(small_problem, tmp_path):
    result = crashnlp.identify(small_problem)
    result.save(tmp_path, figures=False)
    back = crashnlp.Result.load(tmp_path)
    assert (back.status, back.not_identified) == (result.status, result.not_identified)
    for path, value in result.parameters.items():  # result.json keeps 10 significant digits
        np.testing.assert_allclose(back.parameters[path], value, rtol=1e-9)
    t, u = back.tests["56kph"], result.tests["56kph"]
    np.testing.assert_allclose(t.response["crush"], u.response["crush"], rtol=1e-8, atol=1e-12)
    assert t.energy == pytest.approx(u.energy)
    assert [c.name for c in back.active_constraints] == [c.name for c in result.active_constraints]


@pytest.mark.integration
def test_a_loaded_result_saves_the_files_it_was_loaded_from(small_problem, tmp_path):
    """Result.load reads force_crush.csv back too (it had left the loading curve out, and a loaded
    result saved again wrote no force-crush table or figure): saved again, a loaded result writes
    what it was loaded from, to the digits of its files, but the residual figures, which need the
    fitted nodes. A table whose first line says the fit did not converge reads back the same."""
    result = crashnlp.identify(small_problem)
    assert isinstance(result.identified.model["spring"].get("tail"), dict)  # the table's tail is read back too
    result.save(tmp_path / "a")
    back = crashnlp.Result.load(tmp_path / "a")
    back.save(tmp_path / "b")
    files = {folder: {p.relative_to(tmp_path / folder) for p in (tmp_path / folder).rglob("*")} for folder in "ab"}
    assert files["a"] - files["b"] == {Path("56kph/residuals.png")} and files["b"] <= files["a"]
    for name in ("result.json", "56kph/response.csv"):
        assert (tmp_path / "b" / name).read_bytes() == (tmp_path / "a" / name).read_bytes(), name
    table = [np.loadtxt(tmp_path / folder / "force_crush.csv", delimiter=",", skiprows=1) for folder in "ab"]
    np.testing.assert_allclose(table[1], table[0], rtol=2e-9)  # nine significant digits, the last maybe rounded again
    curve, read = result.force_crush, back.force_crush
    np.testing.assert_allclose(read.crush, curve.crush, rtol=1e-8)
    np.testing.assert_array_equal(read.breakpoints, curve.breakpoints)
    dataclasses.replace(back, status="solver failed: Maximum_Iterations_Exceeded").save(tmp_path / "c", figures=False)
    assert (tmp_path / "c/force_crush.csv").read_text().startswith("# NOT CONVERGED")
    np.testing.assert_array_equal(crashnlp.Result.load(tmp_path / "c").force_crush.force, table[1][:, 1])  # as b's


def test_dir_and_help_list_the_api_the_package_imports_on_first_use():
    """Tab completion (dir) offers the API and not the package's own imports; help() documents
    each function and the Result."""
    names = dir(crashnlp)
    assert set(crashnlp.__all__) <= set(names) and not {"Any", "TYPE_CHECKING", "annotations"} & set(names)
    text = pydoc.render_doc(crashnlp, renderer=pydoc.plaintext)
    for name in crashnlp.__all__:
        assert f"{name}(" in text, name


def test_with_values_returns_a_new_problem_and_leaves_the_old_one(small_problem):
    problem = crashnlp.load(small_problem)
    faster = problem.with_values({"vehicle.speed": "64 km/h"})
    assert faster.vehicle.speed == pytest.approx(64 / 3.6) and problem.vehicle.speed == pytest.approx(56 / 3.6)
    with pytest.raises(InputError, match="^with_values: vehicle.no_such_thing: pickup-56kph has no such entry$"):
        problem.with_values({"vehicle.no_such_thing": 1.0})


def test_a_speed_text_without_unit_is_refused_in_a_problem_as_in_a_what_if(small_problem, tmp_path):
    """A text "64" would be 64 m/s (230 km/h), and a simulation has no data to catch it: refused
    through with_values and in a problem file as simulate(speed="64") refuses it; a number is SI."""
    problem = crashnlp.load(small_problem)
    for path in ("vehicle.speed", "tests.0.speed"):
        with pytest.raises(InputError, match=f'^with_values: {path}: give its unit, e.g. "64 km/h" or "64 m/s"$'):
            problem.with_values({path: "64"})
        assert problem.with_values({path: 17.0}).speed(problem.tests[0]) in (17.0, problem.vehicle.speed)
    raw = yaml.safe_load(small_problem.read_text())
    raw["vehicle"]["speed"] = "64"
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(raw))
    with pytest.raises(InputError, match=f'^{tmp_path / "p.yaml"}: vehicle.speed: give its unit, e.g. "64 km/h"'):
        crashnlp.load(tmp_path / "p.yaml")


def test_spring_values_alone_for_breakpoints_left_to_the_data_name_why_and_what_to_give(small_problem, tmp_path):
    """A fit's parameters for a problem that leaves its crush breakpoints to the data: refused
    saying so and what to give, not as another problem's length; with the breakpoints, taken."""
    raw = yaml.safe_load(small_problem.read_text())
    raw["model"]["spring"] = {"law": "force"}
    raw.pop("estimate")
    problem = problem_from_dict(raw, tmp_path)
    values = {"model.spring.values": [0.0, 4e5, 5e5]}
    with pytest.raises(
        InputError,
        match="^crashnlp.simulate: parameters.model.spring.values: pickup-56kph leaves its crush breakpoints to the data.*"
        "the fit's Result.*model.spring.crush_breakpoints with the values$",
    ):
        crashnlp.simulate(problem, params=values)
    given = {**values, "model.spring.crush_breakpoints": [0, 0.25, 0.6]}
    (test,) = crashnlp.simulate(problem, params=given, dt=1e-3).values()
    assert test.metrics == crashnlp.simulate(small_problem, dt=1e-3)["56kph"].metrics


BAD_CALLS = {
    "unknown entry": (
        lambda p: p.with_values({"vehicle.spede": 1}),
        InputError,
        "^with_values: vehicle.spede: pickup-56kph has no such entry$",
    ),
    "new key of a mapping": (
        lambda p: p.with_values({"solver.ipopt.max_iter": 5}),
        InputError,
        "^with_values: solver.ipopt.max_iter: pickup-56kph has no such entry; give solver.ipopt whole",
    ),
    "pairs for a mapping": (lambda p: p.with_values([("vehicle.mass", 2000)]), TypeError, "expected a mapping .* got list$"),
    "a path for a mapping": (lambda p: p.with_values("vehicle.mass"), TypeError, "expected a mapping .* got str$"),
    "params a list": (lambda p: crashnlp.simulate(p, params=[1, 2]), TypeError, "^crashnlp.simulate: params: expected a Result"),
    "params a number": (lambda p: crashnlp.simulate(p, params=5), TypeError, "dotted paths to values, got int$"),
    "design of an identify problem": (
        lambda p: crashnlp.design(p),
        InputError,
        "^pickup-56kph: kind is 'identify'; use crashnlp.identify$",
    ),
    "a dict for a file": (lambda p: crashnlp.load({"name": "x"}), TypeError, "^expected the path of a problem file .* got dict$"),
}


def test_any_path_like_names_a_problem(small_problem):
    """A path is a str or any os.PathLike (a Path, or a library's own path type), as open() takes it."""

    class Given:
        def __fspath__(self) -> str:
            return str(small_problem)

    assert crashnlp.load(Given()).name == crashnlp.load(str(small_problem)).name


@pytest.mark.parametrize("name", list(BAD_CALLS))
def test_bad_input_to_the_api_is_one_line_of_the_documented_error(small_problem, name):
    """Bad input is an InputError (docs/reference/api.md) naming the entry; a value of the wrong
    type, a TypeError saying what is expected: never a bare KeyError or AttributeError."""
    call, error, message = BAD_CALLS[name]
    with pytest.raises(error, match=message) as raised:
        call(crashnlp.load(small_problem))
    assert type(raised.value) in (error, ProblemError) and "\n" not in str(raised.value)


def test_a_result_s_paths_are_refused_in_one_line_and_its_result_json_loads(tmp_path):
    """Result.load takes a fit's folder or its result.json, as simulate(params=...) does, and names
    a path without one; save refuses a file in its folder's place, simulate a Result with params."""
    result = Result("r", "identify", "ok", SolverStats("Solve_Succeeded", 1, 0.0, 0.0, 0.0), {}, {}, {}, {}, (), {}, (), {})
    result.save(tmp_path / "fit", figures=False)
    assert crashnlp.Result.load(tmp_path / "fit" / "result.json") == crashnlp.Result.load(tmp_path / "fit") == result
    with pytest.raises(InputError, match=f"^{tmp_path / 'none'}: file not found$"):
        crashnlp.Result.load(tmp_path / "none")
    (tmp_path / "file").write_text("mine")
    with pytest.raises(InputError, match=f"^{tmp_path / 'file'}: exists and is not a folder$"):
        result.save(tmp_path / "file")
    with pytest.raises(InputError, match="^crashnlp.simulate: a Result is simulated alone"):
        crashnlp.simulate(result, params=result)
    assert (tmp_path / "file").read_text() == "mine"


def test_the_api_refuses_what_the_command_line_refuses(tmp_path, capsys):
    """One pipeline (crashnlp.optimize.pipeline): a test duration that the data window would override is
    refused by crashnlp.identify as by `crashnlp identify`, before anything is solved."""
    raw = yaml.safe_load((ROOT / "problems/pickup-56kph.yaml").read_text())
    raw["tests"][0]["data"]["file"] = str(ROOT / "problems" / raw["tests"][0]["data"]["file"])
    raw["tests"][0]["duration"] = "0.25 s"
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(raw))
    message = "tests.0.duration: 0.25 s would be ignored"
    with pytest.raises(InputError, match=message):
        crashnlp.identify(problem_from_dict(raw, tmp_path))
    with pytest.raises(InputError, match=f"{path}: {message}"):
        crashnlp.identify(path)
    assert main(["identify", str(path), "--check"]) == 2 and message in capsys.readouterr().err


def test_simulate_returns_named_arrays_in_si(small_problem):
    sims = crashnlp.simulate(small_problem, dt=1e-3)
    run = sims["56kph"]
    assert run["time_s"][0] == 0 and np.all(np.diff(run["time_s"]) > 0)
    assert run["velocity_mps"][0] == pytest.approx(56 / 3.6, rel=0.01)  # the CG starts at the impact speed
    assert run["crush_m"].max() > 0.1
    # in SI: the front end's work (N times m/s over s) is the kinetic energy (J) the vehicle
    # lost, but for the little the suspension and gravity take
    work = np.trapezoid(run["contact_force_N"] * run["crush_rate_mps"], run["time_s"])
    assert work + run["kinetic_J"][-1] == pytest.approx(run["kinetic_J"][0], rel=0.02)
    assert work > 0.8 * run["kinetic_J"][0]


def test_simulate_takes_a_what_if_speed_and_mass_for_every_test(small_problem):
    """speed and mass replace every test's; data recorded at other conditions are not its data."""
    run = crashnlp.simulate(small_problem, dt=1e-3, speed="64 km/h", mass="2700 kg")["56kph"]
    assert run["velocity_mps"][0] == pytest.approx(64 / 3.6, rel=0.01) and run.mass == 2700.0
    assert run.data == {} and run.notes[0].startswith("56kph: data not shown: recorded at 56.0 km/h")
    with pytest.raises(InputError, match="speed fast: cannot read 'fast'"):
        crashnlp.simulate(small_problem, speed="fast")


def test_simulate_refuses_a_speed_text_without_unit_as_the_command_does(small_problem):
    """A text "64" would be 64 m/s (230 km/h): refused as `crashnlp simulate --speed 64` is; a Python number is SI."""
    with pytest.raises(InputError, match='^speed 64: give its unit, e.g. "64 km/h" or "64 m/s"$'):
        crashnlp.simulate(small_problem, speed="64")
    assert crashnlp.simulate(small_problem, dt=1e-3, speed=17.0)["56kph"].speed == 17.0


@pytest.mark.parametrize(
    "dt, message",
    [
        (0.0, "dt 0: must be a positive"),
        (float("nan"), "dt nan: must be"),
        (1e-12, "dt 1e-12 s: more than"),
        (5e-3, "dt 0.005 s: 12 output steps over 0.06 s"),
    ],
)
def test_simulate_refuses_the_steps_the_command_refuses(small_problem, dt, message):
    """One check (crashnlp.analysis.prediction.check_steps) for `crashnlp.simulate` and `crashnlp simulate
    --dt`: a step that is not positive, or a million output steps and more, before any run."""
    with pytest.raises(InputError, match=message):
        crashnlp.simulate(small_problem, dt=dt)


def test_simulate_reads_dt_with_its_unit_and_refuses_it_as_the_command_does(small_problem, tmp_path, capsys):
    """`dt="1 ms"` (and "1e-3", text as YAML or a shell gives it) is the step 1e-3 is, as `--dt "1 ms"`
    is: one reading (crashnlp.analysis.prediction.output_step) for both, and one line for a step
    that is no time, the same but for the option's name."""
    times = [crashnlp.simulate(small_problem, dt=dt)["56kph"]["time_s"] for dt in (1e-3, "1 ms", "1e-3")]
    assert all(np.array_equal(times[0], t) for t in times[1:])
    with pytest.raises(InputError) as api:
        crashnlp.simulate(small_problem, dt="1 km")
    assert str(api.value) == "dt 1 km: '1 km' does not convert to s"
    out = tmp_path / "o"
    assert main(["simulate", str(small_problem), "--dt", "1 km", "--out", str(out)]) == 2
    assert capsys.readouterr().err == f"crashnlp: error: --{api.value}\n" and not out.exists()


@pytest.mark.integration
@pytest.mark.slow
def test_the_example_runs_as_written(tmp_path):
    # from a folder of its own holding the problems, where it writes its results/
    (tmp_path / "problems").symlink_to(ROOT / "problems")
    example = str(ROOT / "examples/quickstart.py")
    done = subprocess.run([sys.executable, example], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "max displacement at 64 km/h" in done.stdout
    assert (tmp_path / "results/pickup-56kph/result.json").is_file()


# --------------------------------------------------------------------------- fast units, no IPOPT
def test_nlp_builder_scales_variables_and_types_constraints():
    nlp = NLPBuilder()
    x = nlp.variable("x", (2, 3), init=4.0, lb=0.0, ub=8.0, scale=2.0)
    nlp.constrain("bound", x[0, :], -np.inf, 1.0, test="t1", detail="crush.upper")
    nlp.constrain(DYNAMICS, x[1, :] - 1, test="t1", detail="continuity")
    b = nlp.bounds()
    np.testing.assert_allclose(b["x0"], 2.0)  # stored scaled: 4 / 2
    np.testing.assert_allclose(b["ubx"], 4.0)
    (bound, dyn) = nlp.constraints
    assert (bound.name, bound.local, bound.kind, bound.test, bound.size) == (
        "t1.bound.crush.upper",
        "bound.crush.upper",
        "bound",
        "t1",
        3,
    )
    assert (dyn.kind, dyn.start) == (DYNAMICS, 3)
    z = np.arange(6.0)
    np.testing.assert_allclose(nlp.value("x", z), 2 * z.reshape(2, 3, order="F"))


@pytest.mark.parametrize("method, per_interval", [("multiple-shooting", 0), ("collocation", 3)])
def test_transcription_adds_states_and_dynamics_of_the_right_size(method, per_interval):
    from crashnlp.case.case import Case
    from crashnlp.optimize.ocp import OptimalControl

    n = 40
    spec = {"method": method, "intervals": n, **({"substeps": 1} if method == "multiple-shooting" else {"degree": 3})}
    ocp = OptimalControl(
        Case(problem_from_dict(merge(BASE, {"transcription": spec, "estimate": {"vehicle.crush_offset": {}}}), ROOT))
    )
    states, nx = ocp.nlp.blocks["t56.x"], ocp.case.model.nx
    assert states.shape == (nx, n)  # the first node is the state just after impact, not a variable
    dynamics = sum(c.size for c in ocp.nlp.constraints if c.kind == DYNAMICS)
    # impact interval + the other n - 1 intervals (and their collocation points)
    assert dynamics == nx * (1 + (n - 1) * (1 + per_interval))
    # at the initial guess (a forward simulation) the dynamics nearly hold
    (g,) = ocp.nlp.evaluate([ca.vertcat(*ocp.nlp.g)], ocp.nlp.bounds()["x0"])
    assert np.max(np.abs(np.asarray(g).ravel()[:dynamics])) < 0.05
