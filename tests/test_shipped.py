"""The shipped pickup problem: both transcriptions reach the fit the issue asks for and agree."""

from __future__ import annotations

import numpy as np
import pytest
from builders import ROOT

from crashnlp.base.units import G0
from crashnlp.case.case import Case
from crashnlp.optimize.identify import identify
from crashnlp.problem import load_problem

pytestmark = pytest.mark.integration

LIMITS = {"displacement": 0.005, "velocity": 0.15, "accel": 2 * G0, "pitch": np.radians(1.0)}


@pytest.fixture(scope="module")
def solutions():
    out = {}
    for method in ("multiple-shooting", "collocation"):
        problem = load_problem(ROOT / "problems/pickup-56kph.yaml")
        if method == "collocation":
            n = problem.transcription.intervals
            spec = {"method": "collocation", "intervals": n, "degree": 3, "scheme": "radau"}
            problem = problem.with_values({"transcription": spec})
        out[method] = identify(Case(problem), progress=None)
    return out


@pytest.mark.parametrize("method", ["multiple-shooting", "collocation"])
def test_shipped_pickup_fit_meets_the_targets(solutions, method):
    sol = solutions[method]
    assert sol.ok, sol.status
    ts = sol.tests[0]
    for r in sol.residuals:
        rmse = np.sqrt(np.mean((ts.outputs[r.channel][r.columns] - r.data) ** 2))
        assert rmse <= LIMITS[r.channel], (r.channel, rmse)


@pytest.mark.slow
def test_the_compiled_nlp_fits_the_shipped_problem_as_the_virtual_machine_does(solutions, compiled_nlp):
    """The shipped problem as users run it, its NLP compiled (into the run's cache): the same
    optimum, iterations, multipliers and standard errors (the covariance's functions are in
    the library too) as in CasADi's virtual machine; and the next run (compile: auto) finds
    the library and uses it."""
    vm = solutions["multiple-shooting"]
    problem = load_problem(ROOT / "problems/pickup-56kph.yaml")
    now = identify(Case(problem.with_values({"solver.compile": "now"})), progress=None)
    later = identify(Case(problem), progress=None)
    assert not vm.result.compiled and now.result.compiled and later.result.compiled
    for sol in (now, later):
        assert sol.status == vm.status == "ok"
        assert sol.result.iterations == vm.result.iterations
        assert sol.result.objective == pytest.approx(vm.result.objective, rel=1e-12)
        for mine, theirs in ((sol.result.z, vm.result.z), (sol.result.lam_g, vm.result.lam_g)):
            assert np.max(np.abs(mine - theirs)) <= 1e-9 * np.max(np.abs(theirs))
        np.testing.assert_allclose(sol.theta, vm.theta, rtol=1e-9)
        np.testing.assert_allclose(sol.std_errors, vm.std_errors, rtol=1e-9)


def test_transcriptions_agree_on_the_shipped_objective(solutions):
    a, b = (solutions[m].result.objective for m in ("multiple-shooting", "collocation"))
    assert b == pytest.approx(a, rel=0.01)


@pytest.mark.slow
def test_shipped_barrier_fit_meets_the_wall_and_the_accelerometers():
    from crashnlp.optimize.outcome import result_of

    result = result_of(identify(Case(load_problem(ROOT / "problems/nhtsa-10146-barrier.yaml")), progress=None))
    assert result.ok, result.status
    (test,) = result.tests.values()
    assert test.fit["barrier_force"].iso18571["overall"] >= 0.9
    wall, accel = test.consistency["wall"], test.consistency["accelerometers"]
    assert wall["time_zero_velocity_s"] == pytest.approx(0.0730, abs=5e-4)
    assert accel["time_zero_velocity_s"] == pytest.approx(0.07396, abs=5e-4)
    stop = test.metrics["time_zero_velocity_s"]
    assert abs(stop - accel["time_zero_velocity_s"]) <= 1e-3 and abs(stop - wall["time_zero_velocity_s"]) <= 1e-3
    assert wall["max_displacement_m"] <= test.metrics["max_displacement_m"] <= accel["max_displacement_m"]
    assert test.consistency["impulse_ratio"] == pytest.approx(1.056, abs=0.005)
