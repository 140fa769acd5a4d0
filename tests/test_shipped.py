"""The shipped pickup problem: both transcriptions reach the fit the issue asks for and agree."""

from __future__ import annotations

import numpy as np
import pytest
from builders import ROOT

from crashnlp.case import Case
from crashnlp.optimize.identify import identify
from crashnlp.problem import load_problem
from crashnlp.units import G0

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


def test_transcriptions_agree_on_the_shipped_objective(solutions):
    a, b = (solutions[m].result.objective for m in ("multiple-shooting", "collocation"))
    assert b == pytest.approx(a, rel=0.01)
