"""Shared pieces of the benchmarks: loading cases, the fit targets and one common evaluator.

The evaluator judges any parameter set the same way: a fine forward simulation
(crashnlp's CVODES integrator at the problem's tolerances) sampled at the NLP's
node times, scored by the identification objective

    sum over tests and channels of weight / n_c * sum_k ((model_k - data_k) / sigma_c)^2

so that crashnlp's and the scipy baseline's answers are compared on equal terms.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from crashnlp.base.outputs import OUTPUT
from crashnlp.case.case import Case, TestCase
from crashnlp.data.signal import resample
from crashnlp.models.simulation import simulate
from crashnlp.optimize.fit import DEFAULT_SIGMA
from crashnlp.optimize.oracle import compiles_running
from crashnlp.problem import load_problem
from crashnlp.problem.schema import CollocationSpec, MultipleShootingSpec, Problem

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "problems"
RESULTS = ROOT / "results"
PICKUP_56 = PROBLEMS / "pickup-56kph.yaml"
PICKUP_40 = PROBLEMS / "pickup-40kph.yaml"
TRANSCRIPTIONS = ("multiple-shooting", "collocation")


def transcription(method: str, intervals: int) -> MultipleShootingSpec | CollocationSpec:
    """Transcription section: multiple shooting (1 RK4 substep) or Radau collocation of degree 3."""
    if method == "multiple-shooting":
        return MultipleShootingSpec(method=method, intervals=intervals, substeps=1)
    return CollocationSpec(method=method, intervals=intervals, degree=3, scheme="radau")


def load(
    path: Path = PICKUP_56,
    method: str | None = None,
    intervals: int | None = None,
    max_iter: int | None = None,
    compile: str | None = None,
    from_data: bool = False,
) -> Problem:
    """A fresh problem, optionally with another transcription, interval count, IPOPT iteration cap
    or NLP compilation (solver.compile); `from_data`: the spring values left out, so that both
    fits start from the measured force-crush curve (crashnlp.case.completion), not the problem's guess."""
    problem = load_problem(path)
    changes: dict[str, Any] = {}
    if from_data:
        changes["model.spring.values"] = None
    if method is not None or intervals is not None:
        spec = transcription(method or problem.transcription.method, intervals or problem.transcription.intervals)
        changes["transcription"] = spec.model_dump()
    if max_iter is not None:
        changes["solver.ipopt"] = {**problem.solver.ipopt, "max_iter": max_iter}
    if compile is not None:
        changes["solver.compile"] = compile
    return problem.with_values(changes)


def load_case(
    path: Path = PICKUP_56,
    method: str | None = None,
    intervals: int | None = None,
    max_iter: int | None = None,
    compile: str | None = None,
    from_data: bool = False,
) -> Case:
    return Case(load(path, method, intervals, max_iter, compile, from_data))


@dataclass
class Target:
    """One fitted channel of one test at the node times (SI)."""

    test: int
    channel: str
    columns: np.ndarray  # node indices fitted
    data: np.ndarray
    sigma: float
    weight: float


def node_times(case: Case, test: TestCase) -> np.ndarray:
    """The NLP's node grid of a test: uniform over its fit window, intervals + 1 nodes."""
    return np.linspace(*case.fit_window(test), case.problem.transcription.intervals + 1)


def fit_targets(case: Case) -> list[Target]:
    """The channels the identification fits, resampled onto the node times as the NLP does."""
    out = []
    for i, test in enumerate(case.tests):
        if test.data is None or test.spec.data is None:
            continue
        times = node_times(case, test)
        for name, spec in test.spec.data.channels.items():
            channel = test.data.channels.get(name)
            if channel is None or spec.weight == 0:
                continue
            cols = np.flatnonzero((times >= channel.time[0] - 1e-12) & (times <= channel.time[-1] + 1e-12))
            sigma = spec.sigma if spec.sigma is not None else DEFAULT_SIGMA[name]
            out.append(Target(i, name, cols, resample(channel, times[cols]), sigma, spec.weight))
    return out


def residual_vector(targets: list[Target], outputs: list[dict[str, np.ndarray]]) -> np.ndarray:
    """sqrt(weight / n_c) * (model - data) / sigma for every target, stacked."""
    parts = [(outputs[t.test][t.channel][t.columns] - t.data) * (np.sqrt(t.weight / len(t.columns)) / t.sigma) for t in targets]
    return np.concatenate(parts)


def fine_outputs(case: Case, p: np.ndarray) -> list[dict[str, np.ndarray]]:
    """Model outputs at the node times of every test by crashnlp's CVODES forward simulation."""
    out = []
    for test in case.tests:
        times = node_times(case, test)
        response = simulate(case.model, case.test_parameters(test, p), test.speed, times, case.problem.simulation)
        out.append(response.outputs)
    return out


def judge_fit(case: Case, p: np.ndarray, targets: list[Target]) -> dict:
    """Common evaluator: objective and RMSE per channel (its report unit, as result.json gives it) of a full parameter vector."""
    outputs = fine_outputs(case, p)
    rmse = {}
    for t in targets:
        shown = OUTPUT[t.channel]
        err = (outputs[t.test][t.channel][t.columns] - t.data) * shown.factor
        rmse[f"{case.tests[t.test].name}.{t.channel}"] = {"rmse": float(np.sqrt(np.mean(err**2))), "unit": shown.report_unit}
    return {"objective": float(np.sum(residual_vector(targets, outputs) ** 2)), "rmse": rmse}


def timed(fn: Callable, repeats: int = 1) -> tuple[float, object]:
    """Best wall time of `repeats` calls and the last result."""
    best, result = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def machine() -> dict:
    """What the timings ran on (the load average says whether others were busy)."""
    import casadi
    import scipy

    return {
        "cpus": os.cpu_count(),
        "load_average": list(os.getloadavg()),
        "casadi": casadi.__version__,
        "scipy": scipy.__version__,
        "numpy": np.__version__,
    }


def wait_for_compiles(cache: Path, timeout: float = 300.0) -> float:
    """Seconds until no NLP library is being compiled in `cache` (a dead compile holds no lock:
    crashnlp.optimize.oracle.compiles_running)."""
    t0 = time.perf_counter()
    while compiles_running(cache) and time.perf_counter() - t0 < timeout:
        time.sleep(0.2)
    return time.perf_counter() - t0
