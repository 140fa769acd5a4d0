"""Predictions: a fitted vehicle simulated from its result, its intervals, its range, and the prior."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import yaml

import crashnlp
from bench.corpus import measured, random_vehicle, simulate, write_csv
from bench.robustness import minimal_problem
from crashnlp.cli import main
from crashnlp.metrics import crash_metrics
from crashnlp.optimize.free import FreeParameters
from crashnlp.optimize.prior import smoothness_prior

SMALL = {"method": "multiple-shooting", "intervals": 50, "substeps": 2}
WINDOW = 0.12  # s: past the stop and a little rebound


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A corpus vehicle (not the pendulum) at 48 km/h, fitted from a minimal problem file."""
    folder = tmp_path_factory.mktemp("prediction")
    v = dataclasses.replace(random_vehicle(3, 2030, speed=56 / 3.6), speed=48 / 3.6)
    truth = simulate(v)
    write_csv(folder / "t1.csv", measured(v, truth))
    raw = minimal_problem(v, "t1.csv", SMALL)
    raw["tests"][0]["data"]["window"] = [0.0, WINDOW]
    path = folder / "minimal.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    result = crashnlp.identify(path)
    assert result.ok
    result.save(folder / "fit", figures=False)
    return folder, path, raw, result, v


def _new_speed(folder, raw: dict, kmh: float):
    """The fitted problem with one test at `kmh` and no data: a speed and a duration only."""
    new = {**raw, "tests": [{"name": "new", "speed": f"{kmh} km/h", "duration": WINDOW}]}
    path = folder / f"at-{kmh:g}.yaml"
    path.write_text(yaml.safe_dump(new, sort_keys=False))
    return path


@pytest.mark.integration
def test_the_result_simulates_the_minimal_file_it_was_fitted_from(fitted, capsys):
    folder, path, _, result, _ = fitted
    out = folder / "sim"
    assert main(["simulate", str(path), "--params", str(folder / "fit" / "result.json"), "--out", str(out), "--no-figures"]) == 0
    sim = json.loads((out / "simulation.json").read_text())["tests"]["t1"]
    fit = result.tests["t1"].metrics
    # the forward simulation of the identified model is the fit's own response
    assert sim["metrics"]["max_crush_m"] == pytest.approx(fit["max_crush_m"], rel=2e-3)
    assert sim["metrics"]["time_zero_velocity_s"] == pytest.approx(fit["time_zero_velocity_s"], abs=1e-3)
    low, high = sim["intervals"]["max_crush_m"]
    assert low < sim["metrics"]["max_crush_m"] < high
    assert sim["extrapolation"] == {}  # the fit's own test is inside its range
    header = (out / "t1" / "response.csv").read_text().splitlines()[0].split(",")
    assert {"crush_m_low", "crush_m_high", "accel_g_low", "accel_g_high"} <= set(header)


@pytest.mark.integration
def test_a_problem_naming_only_a_new_speed_predicts_and_says_it_extrapolates(fitted):
    folder, _, raw, result, v = fitted
    prediction = crashnlp.simulate(_new_speed(folder, raw, 56), params=result)["new"]
    real = simulate(dataclasses.replace(v, speed=56 / 3.6))
    truth = crash_metrics(real["time"], real["accel"], real["velocity"], real["displacement"])
    assert prediction.metrics["max_crush_m"] == pytest.approx(truth.max_crush, rel=0.05)
    assert prediction.extrapolation["speed_mps"] == pytest.approx((56 - 48) / 3.6)
    assert prediction.extrapolation["crush_m"] > 0  # a faster impact crushes past the fitted crush
    low, high = prediction.intervals["max_crush_m"]
    assert low < prediction.metrics["max_crush_m"] < high
    band_low, band_high = prediction.bands["accel"]
    assert np.all(band_low <= prediction.response["accel"]) and np.all(prediction.response["accel"] <= band_high)
    slower = crashnlp.simulate(_new_speed(folder, raw, 48), params=result)["new"]
    assert slower.extrapolation == {}
    # past the fitted crush the force is the tail rule's guess: the interval widens beyond the parameters' share
    width = lambda t: np.diff(t.intervals["max_crush_m"])[0] / t.metrics["max_crush_m"]  # noqa: E731
    assert width(prediction) > 1.5 * width(slower)
    # a faster impact crushes more: the identified vehicle is one physical vehicle at both speeds
    assert prediction.metrics["max_crush_m"] > slower.metrics["max_crush_m"]


@pytest.mark.integration
def test_a_new_mass_changes_the_prediction_the_identified_front_end_stays(fitted):
    folder, _, raw, result, _ = fitted
    heavier = yaml.safe_load(_new_speed(folder, raw, 48).read_text())
    heavier["vehicle"]["mass"] = raw["vehicle"]["mass"] * 1.2
    path = folder / "heavier.yaml"
    path.write_text(yaml.safe_dump(heavier))
    base = crashnlp.simulate(_new_speed(folder, raw, 48), params=result)["new"]
    more = crashnlp.simulate(path, params=result)["new"]
    assert more.mass == pytest.approx(1.2 * base.mass)
    assert more.metrics["max_crush_m"] > base.metrics["max_crush_m"]  # more energy into the same front end
    assert more.extrapolation["mass_kg"] == pytest.approx(0.2 * base.mass)


@pytest.mark.integration
def test_another_vehicle_is_refused_in_one_line(fitted, capsys):
    folder, _, raw, _, _ = fitted
    other = {**raw, "vehicle": {**raw["vehicle"], "cg_to_impact": raw["vehicle"]["cg_to_impact"] + 0.4}}
    path = folder / "other.yaml"
    path.write_text(yaml.safe_dump(other))
    code = main(["simulate", str(path), "--params", str(folder / "fit" / "result.json"), "--out", str(folder / "o")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "vehicle.cg_to_impact" in err and "Traceback" not in err
    assert not (folder / "o").exists()


@pytest.mark.integration
def test_the_result_carries_its_complete_model_and_range(fitted):
    folder, _, _, result, v = fitted
    loaded = crashnlp.Result.load(folder / "fit")
    model = loaded.identified.model
    assert len(model["spring"]["crush_breakpoints"]) == len(model["spring"]["values"]) == 8  # completed from the data
    assert model["spring"]["values"] == pytest.approx(result.parameters["model.spring.values"], rel=1e-9)
    assert loaded.identified.range.speeds == (pytest.approx(v.speed), pytest.approx(v.speed))
    assert loaded.identified.range.max_crush == pytest.approx(result.tests["t1"].data_metrics["max_crush_m"], rel=0.01)


def test_the_prior_is_zero_on_a_straight_curve_and_follows_slope_changes():
    from builders import BASE

    from crashnlp.model.parameters import ParameterLayout
    from crashnlp.problem import problem_from_dict
    from crashnlp.problem.schema import EstimateSpec

    problem = problem_from_dict(BASE, ".")
    layout = ParameterLayout.of(problem)
    base = layout.values(problem)
    free = FreeParameters(layout, base, {"model.spring.values": EstimateSpec(bounds=(0.0, 3e6))})
    bps = np.asarray(problem.model.spring.crush_breakpoints)
    prior = smoothness_prior(free, bps)
    assert prior is not None and prior.count == bps.size - 2
    assert np.allclose(prior.matrix @ (2e6 * bps), 0.0)  # a straight line: no slope change, no penalty
    kinked = np.where(bps > 0.4, 1e6 + 4e6 * (bps - 0.4), 2.5e6 * bps)
    rows = prior.matrix @ kinked
    assert np.count_nonzero(np.abs(rows) > 1e-9) == 1  # the one kink, at its breakpoint


def test_the_tail_rule_error_is_zero_on_a_straight_curve_and_measures_a_miss():
    from crashnlp.prediction import tail_error

    x = np.array([0.0, 0.1, 0.2, 0.3, 0.4])
    assert tail_error(x, 1e6 * x) == pytest.approx(0.0, abs=1e-12)
    assert tail_error(x, np.full(5, 1e5)) == pytest.approx(0.0, abs=1e-12)  # flat: held
    # steps the rule cannot see: each of its three predictions misses by 1e5 N, mean force 1.5e5 N
    f = np.array([0.0, 1e5, 1e5, 2e5, 2e5])
    assert tail_error(x, f) == pytest.approx(1e5 / 1.5e5)
