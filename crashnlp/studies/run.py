"""Run a study: solve every case wave by wave, store each as it finishes, write the table and figures.

Layout of the output folder:
  cases/<id>.json   the case's table row and a fingerprint of what it computed
  cases/<id>.npy    its solution vector (warm start for the cases planned after it)
  table.csv         one row per case
  figures/*.png     objective and metrics against each swept entry
A case whose json exists with a matching fingerprint is never solved again, so
running a study again into the same folder resumes it.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from crashnlp.errors import InputError
from crashnlp.files import atomic_open
from crashnlp.jsonfile import clean, write_json
from crashnlp.studies.executors import CONNECT_TIMEOUT, default_workers, make_executor
from crashnlp.studies.plan import PlannedCase, case_id, case_key, case_problem, plan_cases, waves
from crashnlp.studies.spec import Study, SweepEntry, load_study

if TYPE_CHECKING:
    from crashnlp.result import Result

RESULTS = Path("results")
METRICS = ("max_crush_m", "time_zero_velocity_s", "peak_decel_g", "rebound_velocity_mps", "max_pitch_deg", "olc_g")
PLOTTED = ("max_crush_m", "peak_decel_g", "max_pitch_deg", "olc_g")


# --------------------------------------------------------------------------- worker side
def solve_job(job: dict[str, Any]) -> dict[str, Any]:
    """Solve one case from plain data (runs in a worker process; builds the Case there).

    Returns {"record": table columns of the outcome, "z": solution vector or None};
    bad input and any exception become a record with that status.
    """
    from crashnlp.api import solve
    from crashnlp.problem import problem_from_dict
    from crashnlp.runtime import THREADS_ENV

    if job["threads"] is not None:
        os.environ[THREADS_ENV] = str(job["threads"])
    try:
        problem = problem_from_dict(job["raw"], Path(job["base_dir"]), source=job["id"])
        with contextlib.redirect_stderr(io.StringIO()):  # CasADi's warnings: the row's status says it
            result = solve(problem, progress=None, warm=job["warm"])
    except InputError as exc:
        return {"record": {"status": f"input error: {_one_line(exc)}"}, "z": None}
    except Exception as exc:  # noqa: BLE001 - any failure of one case is that case's status
        return {"record": {"status": f"error: {type(exc).__name__}: {_one_line(exc)}"}, "z": None}
    return {"record": result_record(result, job["constraints"]), "z": result.z}


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def result_record(result: Result, constraints: list[str]) -> dict[str, Any]:
    """Status, solver figures, metrics, parameters and the multipliers of the swept constraints."""
    record: dict[str, Any] = {
        "status": result.status,
        "objective": result.solver.objective,
        "iterations": result.solver.iterations,
        "wall_s": result.solver.wall_s,
    }
    for name, test in result.tests.items():
        record.update({f"{name}.{k}": test.metrics[k] for k in METRICS})
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


def constraint_names(study: Study) -> list[str]:
    """NLP constraint names (without the test prefix) that the swept entries set."""
    names = []
    for e in study.entries:
        if e.keys[0] == "constraints" and len(e.keys) > 1:
            parts = ["bound" if k == "bounds" else str(k) for k in e.keys[1:]]
            names.append(".".join(parts))
    return names


# --------------------------------------------------------------------------- storage
class CaseStore:
    """cases/<id>.json (row + fingerprint) and cases/<id>.npy, each written atomically."""

    def __init__(self, folder: Path):
        self.folder = folder

    def row(self, case: str, key: str) -> dict | None:
        """The stored row of a finished case, if it was computed from the same inputs and is whole.

        A json that does not parse, lacks its row or status, or promises a solution vector whose
        .npy is missing, empty or corrupt marks the case unfinished: it is solved again.
        """
        path = self.folder / f"{case}.json"
        try:
            stored = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):  # missing, unreadable, not UTF-8, not JSON
            return None
        if not isinstance(stored, dict) or stored.get("key") != key:
            return None
        row = stored.get("row")
        if not isinstance(row, dict) or not isinstance(row.get("status"), str):
            return None
        size = stored.get("vector", -1)  # -1: written before sizes were stored; check the file if there
        if size is None:
            return row
        z = self.vector(case)
        if size == -1:
            return row if z is not None or not (self.folder / f"{case}.npy").exists() else None
        return row if z is not None and z.size == size else None

    def vector(self, case: str) -> np.ndarray | None:
        """The stored solution vector, or None if there is none or it is not a whole finite vector."""
        path = self.folder / f"{case}.npy"
        try:
            z = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError):
            return None
        if z.ndim != 1 or z.dtype.kind != "f" or not np.all(np.isfinite(z)):
            return None
        return z

    def save(self, case: str, key: str, row: dict, z: np.ndarray | None) -> None:
        """Vector first, then the json that marks the case finished."""
        self.folder.mkdir(parents=True, exist_ok=True)
        npy = self.folder / f"{case}.npy"
        if z is not None:
            with atomic_open(npy, "wb") as fh:
                np.save(fh, np.asarray(z, dtype=float))
        else:
            npy.unlink(missing_ok=True)
        size = None if z is None else int(np.size(z))
        write_json(self.folder / f"{case}.json", {"key": key, "row": row, "vector": size})


# --------------------------------------------------------------------------- the study
def run_study(
    path: str | Path,
    out: str | Path | None = None,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
    progress: bool = True,
    timeout: float = CONNECT_TIMEOUT,
    check: bool = False,
) -> list[dict[str, Any]]:
    """Solve every case not yet finished in `out`, then write table.csv and figures; return the rows.

    Every case's problem is validated first, so a bad swept value is an InputError before any
    solve. `check`: stop there (return no rows). A signal stops the workers at once; the cases
    finished so far stay in `out`/cases, and running again resumes.
    """
    study = load_study(path)
    out = Path(out) if out is not None else RESULTS / study.name
    cases = plan_cases(study)
    raws = {c.number: _case_problem(study, c) for c in cases}
    checked: set[str] = set()
    for c in cases:
        _validate(study, c, raws[c.number], checked)
    if check:
        return []
    keys = {c.number: case_key(raws[c.number], c.parent) for c in cases}
    store = CaseStore(out / "cases")
    rows = {c.number: row for c in cases if (row := store.row(c.id, keys[c.number])) is not None}
    todo = [[c for c in wave if c.number not in rows] for wave in waves(cases)]
    size = min(workers or default_workers(), max(len(w) for w in todo))
    pool = make_executor(executor, size, address, timeout) if any(todo) else None
    bar = tqdm(total=len(cases), initial=len(rows), desc=study.name, unit="case", file=sys.stderr, disable=not progress)
    _postfix(bar, rows, len(cases))
    if pool is not None:
        try:
            for wave in filter(None, todo):
                threads = 1 if size > 1 else None  # parallel cases, serial maps inside each
                jobs = [_job(study, c, raws[c.number], store, threads) for c in wave]
                for i, outcome in pool.map_wave(solve_job, jobs):
                    case = wave[i]
                    row, z = _row(study, case, jobs[i], outcome)
                    if not isinstance(outcome, BaseException):  # a lost worker is retried on the next run
                        store.save(case.id, keys[case.number], row, z)
                    rows[case.number] = clean(row)
                    _postfix(bar, rows, len(cases))
                    bar.update()
        except BaseException:
            bar.close()
            pool.abort()
            raise
        pool.close()
    bar.close()
    table = [rows[c.number] for c in cases]
    write_table(out / "table.csv", table)
    write_figures(out / "figures", study, cases, table)
    return table


def _case_problem(study: Study, case: PlannedCase) -> dict[str, Any]:
    try:
        return case_problem(study, case)
    except InputError as exc:
        raise InputError(f"{study.source}: sweep.{exc}") from None


def _validate(study: Study, case: PlannedCase, raw: dict, checked: set[str]) -> None:
    """Refuse a case whose problem is not valid, or whose data contradict it, naming the study file,
    the case and its values. Data are read once per distinct set of tests (`checked`)."""
    from crashnlp.problem import problem_from_dict
    from crashnlp.problem.load import check_fit_keys

    values = ", ".join(f"{e.path} = {show(v)}" for e, v in zip(study.entries, case.values))
    try:
        problem = problem_from_dict(raw, study.base_dir, source="problem")
        check_fit_keys(problem, "problem")
        tests = json.dumps([raw.get("tests"), raw.get("vehicle", {}).get("speed")], sort_keys=True, default=str)
        if tests not in checked:
            _check_data(problem)
            checked.add(tests)
    except InputError as exc:
        detail = str(exc).removeprefix("problem: ")
        raise InputError(f"{study.source}: sweep: {case.id} ({values}): {detail}") from None


def _check_data(problem) -> None:
    """Read every test's data and refuse a speed they contradict (what Case does, without the model)."""
    from crashnlp.case import check_speed
    from crashnlp.data import load_test_data

    masses = [problem.vehicle.mass] + [t.mass for t in problem.tests]
    for i, test in enumerate(problem.tests):
        data = load_test_data(test.data, problem.speed(test)) if test.data is not None else None
        speed = problem.speed(test) or (data.meta.get("speed") if data is not None else None)
        if speed is None:
            raise InputError(f"tests.{i}.speed: no impact speed (give vehicle.speed, the test's speed or a data header)")
        if data is not None:
            check_speed(i, float(speed), test, data)
            masses.append(data.meta.get("mass"))
    if not any(masses):
        raise InputError("vehicle.mass: not given and no data header gives it")


def _job(study: Study, case: PlannedCase, raw: dict, store: CaseStore, threads: int | None) -> dict[str, Any]:
    warm = store.vector(case_id(case.parent)) if case.parent is not None else None
    return {
        "threads": threads,
        "id": case.id,
        "raw": raw,
        "base_dir": str(study.base_dir),
        "warm": warm,
        "warm_from": case.parent if warm is not None else None,
        "constraints": constraint_names(study),
    }


def _row(study: Study, case: PlannedCase, job: dict, outcome: Any) -> tuple[dict, np.ndarray | None]:
    """The table row of a finished case; a task that raised (a worker died) is a failed row."""
    if isinstance(outcome, BaseException):
        outcome = {"record": {"status": f"error: {type(outcome).__name__}: {_one_line(outcome)}"}, "z": None}
    row: dict[str, Any] = {"case": case.id}
    row.update({e.path: show(v) for e, v in zip(study.entries, case.values)})
    row.update({f"{e.path}_si": e.si(v) for e, v in zip(study.entries, case.values)})
    row["warm_start"] = case_id(job["warm_from"]) if job["warm_from"] is not None else ""
    row.update(outcome["record"])
    return row, outcome["z"]


def _postfix(bar: tqdm, rows: dict, total: int) -> None:
    failed = sum(1 for r in rows.values() if r["status"] != "ok")
    bar.set_postfix(ok=len(rows) - failed, failed=failed, left=total - len(rows), refresh=False)


def show(value: Any) -> str:
    """A swept value as the user wrote it, in YAML flow style ([null, 4 deg])."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {show(v)}" for k, v in value.items()) + "}"
    return str(value)


# --------------------------------------------------------------------------- table and figures
def write_table(path: Path, rows: list[dict[str, Any]]) -> None:
    """table.csv: the union of the rows' columns, in first-seen order; missing cells empty."""
    columns = list(dict.fromkeys(k for r in rows for k in r))
    with atomic_open(path) as fh:
        writer = csv.DictWriter(fh, columns, restval="")
        writer.writeheader()
        writer.writerows([{k: "" if v is None else v for k, v in r.items()} for r in rows])


def write_figures(folder: Path, study: Study, cases: list[PlannedCase], rows: list[dict]) -> None:
    """Objective, metrics and swept multipliers of the solved cases against each swept entry.

    With several varied entries in a grid, one figure per combination of the others.
    """
    solved = [(c, r) for c, r in zip(cases, rows) if r["status"] == "ok"]
    if not solved:
        return
    names = ["objective"] + [
        k for k in dict.fromkeys(k for _, r in solved for k in r) if k.endswith(PLOTTED) or k.startswith("multiplier.")
    ]
    for i, entry in enumerate(study.entries):
        if len(entry.values) < 2:
            continue
        groups: dict[tuple, list] = {}
        for c, r in solved:
            others = tuple(show(v) for j, v in enumerate(c.values) if j != i)
            groups.setdefault(others, []).append((c, r))
        for k, (others, members) in enumerate(groups.items()):
            suffix = f"-{k}" if len(groups) > 1 else ""
            where = ", ".join(f"{e.path} = {v}" for e, v in zip([e for j, e in enumerate(study.entries) if j != i], others))
            _figure(folder / f"{entry.path}{suffix}.png", entry, i, members, names, f"{study.name} {where}".strip())


def _figure(path: Path, entry: SweepEntry, i: int, members: list, names: list[str], title: str) -> None:
    x = np.array([entry.si(c.values[i]) for c, _ in members])
    xlabel = f"{entry.path} ({entry.unit})" if entry.unit else entry.path
    if np.all(np.isnan(x)):
        x = np.array([float(c.index[0] if len(c.index) == 1 else c.index[i]) for c, _ in members])
        xlabel = f"{entry.path} (value number)"
    order = np.argsort(x, kind="stable")
    series = {n: np.array([_number(r.get(n)) for _, r in members])[order] for n in names}
    from crashnlp import plots  # matplotlib: only once the figures are drawn

    plots.xy_figure(path, x[order], series, xlabel, title)


def _number(value: Any) -> float:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan
