"""`crashnlp init`: problem files from EV5, CSV and ISO-MME data that identify as they stand."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from builders import ROOT
from test_readers import CODE_X, _mme_set

from bench.corpus import random_vehicle, simulate, write_csv
from crashnlp.cli import _print_solution, main
from crashnlp.init import Options, csv_draft, init_problem, unit_in_name

EV5 = ROOT / "problems" / "data" / "nhtsa-10146" / "v10146.EV5"
CAMRY_DATA = {"crush_mm": 746.0, "stop_ms": 73.96}  # the data's own metrics (README)


def _identify(problem_file, out) -> dict:
    assert main(["identify", str(problem_file), "--out", str(out)]) == 0
    return json.loads((out / "result.json").read_text())


@pytest.mark.integration
def test_init_on_the_ev5_reproduces_the_camry_fit(tmp_path):
    out = tmp_path / "camry.yaml"
    assert main(["init", str(EV5), "--out", str(out)]) == 0
    text = out.read_text()
    assert "mass: 1719 kg" in text and "VEHTWT" in text and "57.09 km/h" in text
    assert "curves: [93, 94]" in text and "REAR SEAT CROSSMEMBER" in text
    assert "# barrier_force: {curves: all-valid-barrier-fx, sign: -1}" in text and "174 valid load cells" in text
    assert "cg_to_front_axle: 1.246 m" in text and "cg_to_impact: 2.219 m" in text and "estimate" in text
    (test,) = _identify(out, tmp_path / "res")["tests"].values()
    model = test["metrics"]["model"]
    assert model["max_crush_m"] * 1e3 == pytest.approx(CAMRY_DATA["crush_mm"], rel=0.02)
    assert abs(model["time_zero_velocity_s"] * 1e3 - CAMRY_DATA["stop_ms"]) <= 2.0


@pytest.fixture(scope="module")
def compact_csv(tmp_path_factory):
    """A corpus vehicle recorded with x pointing away from the wall (every sign flipped), time in ms, speed in km/h."""
    v = random_vehicle(3, seed=11)
    truth = simulate(v)
    path = tmp_path_factory.mktemp("csv") / "compact.csv"
    write_csv(
        path,
        {
            "Time [ms]": truth["time"] * 1e3,
            "acc_x_g": -truth["accel"] / 9.80665,
            "speed_kph": -truth["velocity"] * 3.6,
            "disp_mm": -truth["displacement"] * 1e3,
        },
    )
    return v, truth, path


def test_csv_columns_units_and_signs_are_recognised(compact_csv):
    _, _, path = compact_csv
    draft = csv_draft(path, {})
    assert draft.data["time"] == {"column": "Time [ms]", "unit": "ms"}
    assert {ch: (c["column"], c["unit"]) for ch, c in draft.data["channels"].items() if "column" in c} == {
        "accel": ("acc_x_g", "g"),
        "velocity": ("speed_kph", "km/h"),
        "displacement": ("disp_mm", "mm"),
    }
    assert unit_in_name("a_mps2") == "m/s^2" and unit_in_name("accel") is None


@pytest.mark.integration
def test_init_on_a_csv_given_mass_and_speed_identifies(compact_csv, tmp_path):
    v, truth, path = compact_csv
    out = tmp_path / "compact.yaml"
    assert main(["init", str(path), "--mass", f"{v.mass} kg", "--speed", f"{v.speed * 3.6} km/h", "--out", str(out)]) == 0
    written = yaml.safe_load(out.read_text())
    assert all(written["tests"][0]["data"]["channels"][ch]["sign"] == -1 for ch in ("accel", "velocity", "displacement"))
    (test,) = _identify(out, tmp_path / "res")["tests"].values()
    model = test["metrics"]["model"]
    crush = float(np.max(truth["displacement"]))
    stop = float(truth["time"][np.flatnonzero(truth["velocity"] <= 0)[0]])
    assert model["max_crush_m"] == pytest.approx(crush, rel=0.02)
    assert abs(model["time_zero_velocity_s"] - stop) <= 2e-3


def test_csv_without_units_asks_for_them(tmp_path, capsys):
    path = tmp_path / "plain.csv"
    path.write_text("time,accel\n0,0\n0.001,-1\n")
    assert main(["init", str(path), "--mass", "1000 kg", "--speed", "40 km/h", "--out", str(tmp_path / "p.yaml")]) == 2
    assert "column 'time' (time): no unit in its name; give --column time=time:UNIT" in capsys.readouterr().err
    assert not (tmp_path / "p.yaml").exists()


def test_init_on_iso_mme_reads_mass_speed_and_the_cg_accelerometer(tmp_path):
    _mme_set(tmp_path / "T001", n=2000)
    problem = init_problem(tmp_path / "T001", tmp_path / "mme.yaml", Options())
    assert problem.vehicle.mass == 1500 and problem.vehicle.speed == 15.0
    assert problem.tests[0].data.channels["accel"].code == CODE_X
    assert problem.vehicle.cg_to_front_axle == pytest.approx(0.44 * 2.65)  # a 1500 kg compact's typical geometry


def test_print_solution_shows_a_solve_that_never_ran(capsys):
    from crashnlp.result import Result, SolverStats

    result = Result(
        "x",
        "identify",
        "solver failed: Invalid_Number_Detected",
        SolverStats(None, 0, None, None, None),
        {},
        {"model.spring.values": [1.0, None]},
        {},
        {},
        (),
        {},
        (),
        {},
    )
    _print_solution(result)
    out = capsys.readouterr().out
    assert "(IPOPT -, 0 iterations, objective -, not solved)" in out and "[1 nan]" in out
