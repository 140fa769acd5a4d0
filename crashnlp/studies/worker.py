"""The worker side of a study: solve one case from plain data and make its table row."""

from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crashnlp.base.errors import InputError
from crashnlp.base.outputs import PREDICTED_KEYS
from crashnlp.numerics.runtime import THREADS_ENV
from crashnlp.problem import problem_from_dict
from crashnlp.studies.table import ACCEL_FILTER

if TYPE_CHECKING:
    from crashnlp.results.result import Result


def solve_job(job: dict[str, Any]) -> dict[str, Any]:
    """Solve one case from plain data (runs in a worker process; builds the Case there).

    Returns {"record": table columns of the outcome, "z": solution vector or None};
    bad input and any exception become a record with that status.
    """
    from crashnlp.optimize.pipeline import solve_problem  # the solver stack: loaded by the workers, not by the study's planner

    if job["threads"] is not None:
        os.environ[THREADS_ENV] = str(job["threads"])
    try:
        problem = problem_from_dict(job["raw"], Path(job["base_dir"]), source=job["id"])
        with contextlib.redirect_stderr(io.StringIO()):  # CasADi's warnings: the row's status says it
            result = solve_problem(problem, job["id"], progress=None, warm=job["warm"], ratings=False)
    except InputError as exc:
        return {"record": {"status": f"input error: {one_line(exc)}"}, "z": None}
    except Exception as exc:  # noqa: BLE001 - any failure of one case is that case's status
        return {"record": {"status": f"error: {type(exc).__name__}: {one_line(exc)}"}, "z": None}
    return {"record": result_record(result, job["constraints"]), "z": result.z}


def one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def result_record(result: Result, constraints: list[str]) -> dict[str, Any]:
    """Status, IPOPT's return status and figures, metrics (and the CFC class each test's
    accelerations were read through), parameters and the multipliers of the swept constraints."""
    record: dict[str, Any] = {
        "status": result.status,
        "return_status": result.solver.return_status,  # IPOPT's: a case it solved may still fail a check
        "objective": result.solver.objective,
        "iterations": result.solver.iterations,
        "wall_s": result.solver.wall_s,
    }
    for name, test in result.tests.items():
        record.update({f"{name}.{k}": test.metrics[k] for k in PREDICTED_KEYS})
        record[f"{name}.{ACCEL_FILTER}"] = test.response.accel_filter  # its peak's CFC class, as tables name it
    for path, value in result.parameters.items():
        values = np.ravel(value)
        if np.ndim(value):
            record.update({f"{path}[{i}]": float(v) for i, v in enumerate(values)})
        else:
            record[path] = float(values[0])
    if result.z is not None:
        record.update(swept_multipliers(result, constraints))
    return record


def swept_multipliers(result: Result, swept: list[str]) -> dict[str, float]:
    """multiplier.<constraint> for every inequality block a swept entry sets (0 when inactive)."""
    worth = {c.name: c.multiplier for c in result.active_constraints}
    out = {}
    for name in result.inequalities:
        local = next((name[len(t) + 1 :] for t in result.tests if name.startswith(t + ".")), name)
        if any(local == s or local.startswith(s + ".") for s in swept):
            out[f"multiplier.{name}"] = worth.get(name, 0.0)
    return out
