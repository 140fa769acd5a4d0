"""Run a study: solve every case once its warm-start parent is solved, store each as it finishes, write the table and figures.

Layout of the output folder:
  cases/<id>.json   the case's table row and a fingerprint of what it computed
  cases/<id>.npy    its solution vector (warm start for the cases planned after it)
  table.csv         one row per case
  figures/*.png     objective and metrics against each swept entry
A case whose json exists with a matching fingerprint (its problem, its parent, the contents of
its data files and the code: crashnlp.studies.plan.case_key) is never solved again, so running a
study again into the same folder resumes it, and solves again what changed.
"""

from __future__ import annotations

import json
import numbers
import sys
import threading
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
from tqdm import tqdm

from crashnlp.base.errors import InputError
from crashnlp.case.checks import check_keys, check_tests
from crashnlp.data.load import files_read
from crashnlp.engine import CONNECT_TIMEOUT
from crashnlp.engine.executors import default_workers, discard_started_clusters, make_executor, start_cluster, start_early
from crashnlp.engine.schedule import run_tree
from crashnlp.problem import Problem, problem_from_dict
from crashnlp.problem.forms import DEFAULT_FORM, READ_BY
from crashnlp.results.files import claim, run_name
from crashnlp.results.jsonfile import clean
from crashnlp.studies.plan import PlannedCase, case_id, case_key, case_problem, code_identity, file_digests, plan_cases
from crashnlp.studies.spec import Study, load_study
from crashnlp.studies.store import CaseStore
from crashnlp.studies.table import show, write_figures, write_table
from crashnlp.studies.worker import one_line, solve_job

if TYPE_CHECKING:
    from crashnlp.engine.executors import Executor

RESULTS = Path("results")
OWN = {"vehicle.speed": "speed", "vehicle.mass": "mass"}  # a vehicle's entries a test may set for itself
T = TypeVar("T")


def constraint_names(study: Study) -> list[str]:
    """NLP constraint names (without the test prefix) that the swept entries set."""
    names = []
    for e in study.entries:
        if e.keys[0] == "constraints" and len(e.keys) > 1:
            parts = ["bound" if k == "bounds" else str(k) for k in e.keys[1:]]
            names.append(".".join(parts))
    return names


def checked_workers(workers: Any, option: str = "workers") -> int | None:
    """A study's number of worker processes: None (the cores available, default_workers) or a
    whole number from 1; anything else an InputError naming `option` (the command: --workers)."""
    if workers is None:
        return None
    if isinstance(workers, bool) or not isinstance(workers, numbers.Integral) or workers < 1:
        raise InputError(f"{option} {workers!r}: must be a whole number, at least 1")
    return int(workers)


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
    tell: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """Solve every case not yet finished in `out`, then write table.csv and figures; return the rows.

    Every case's problem is validated first, so a bad swept value is an InputError before any
    solve. `check`: stop there (return no rows). A signal stops the workers at once; the cases
    finished so far stay in `out`/cases, and running again resumes. `tell` (the command: the
    console) is told how many stored cases a run into a folder holding some reuses. `workers`:
    None (the cores available) or at least 1 (`checked_workers`).
    """
    workers = checked_workers(workers)
    if executor == "local" and not check:
        start_early()  # the workers' fork server preloads crashnlp while the cases are checked
    try:
        if executor == "dask" and address is None and not check:
            checking = _in_thread(_checked_cases, path)  # while the LocalCluster starts (it must in the main thread)
            start_cluster(workers or default_workers())
            study, cases, raws, files = checking.result()
        else:
            study, cases, raws, files = _checked_cases(path)
        if check:
            return []
        out = Path(out) if out is not None else RESULTS / study.name
        with claim(out, run_name("study", study.name), option=None):
            return _run(study, _Cases(cases, raws, files), out, executor, workers, address, progress, timeout, tell)
    finally:
        discard_started_clusters()  # one not taken: the study was refused, or had fewer cases left than workers


def _checked_cases(path: str | Path) -> tuple[Study, list[PlannedCase], dict[int, dict], dict[int, tuple[Path, ...]]]:
    """The study, its cases, their raw problems, every one validated, and the data files each reads."""
    study = load_study(path)
    cases = plan_cases(study)
    unread: dict[str, list[str]] = {}
    raws = {c.number: _vehicle_for_its_form(study, _case_problem(study, c), unread) for c in cases}
    checked: set[str] = set()
    listed: dict[tuple[Path, str], list[Path]] = {}
    files = {c.number: _data_files(_validate(study, c, raws[c.number], checked), listed) for c in cases}
    return study, cases, raws, files


def _data_files(problem: Problem, listed: dict[tuple[Path, str], list[Path]]) -> tuple[Path, ...]:
    """The files the problem's tests read their data from (crashnlp.data.load.files_read), each
    test's data file listed once per study (`listed`)."""
    files: list[Path] = []
    for test in problem.tests:
        if test.data is not None:
            where = (test.data.file, test.data.format)
            if where not in listed:
                listed[where] = files_read(test.data)
            files += listed[where]
    return tuple(files)


def _in_thread(fn: Callable[..., T], *args: Any) -> Future[T]:
    """fn(*args) in a daemon thread of its own (the process does not wait for it if stopped)."""
    future: Future[T] = Future()

    def run() -> None:
        try:
            future.set_result(fn(*args))
        except BaseException as exc:  # noqa: BLE001 - the caller of result() gets it
            future.set_exception(exc)

    threading.Thread(target=run, name="crashnlp-check", daemon=True).start()
    return future


@dataclass(frozen=True)
class _Cases:
    """A study's checked cases: their raw problems and the data files each reads, by case number."""

    planned: list[PlannedCase]
    raws: dict[int, dict]
    files: dict[int, tuple[Path, ...]]

    def keys(self) -> dict[int, str]:
        """Every case's fingerprint (crashnlp.studies.plan.case_key), each data file hashed once, a
        parent's before its children's (by depth), which hold it: a case warm-started from another
        solution is another case. A file counts by its name and contents, not its folder: a study
        moved with its data resumes."""
        digests = file_digests(f for c in self.planned for f in self.files[c.number])
        code = code_identity()
        keys: dict[int, str] = {}
        for c in sorted(self.planned, key=lambda c: c.depth):
            data = [(f.name, digests[f]) for f in self.files[c.number]]
            keys[c.number] = case_key(self.raws[c.number], None if c.parent is None else keys[c.parent], data, code)
        return keys


def _run(
    study: Study,
    checked: _Cases,
    out: Path,
    executor: str,
    workers: int | None,
    address: str | None,
    progress: bool,
    timeout: float,
    tell: Callable[[str], None] | None,
) -> list[dict[str, Any]]:
    """Solve the cases not yet stored in `out`/cases, then write the table and the figures."""
    cases, raws, keys = checked.planned, checked.raws, checked.keys()
    store = CaseStore(out / "cases")
    rows = {c.number: row for c in cases if (row := store.row(c.id, keys[c.number])) is not None}
    if tell is not None and store.holds_any():
        tell(f"{len(rows)} of {len(cases)} cases reused from {store.folder}/: their problem, data and crashnlp unchanged")
    todo = {c.number: c.parent for c in cases if c.number not in rows}
    pool = make_executor(executor, min(workers or default_workers(), len(todo)), address, timeout) if todo else None
    bar = tqdm(total=len(cases), initial=len(rows), desc=study.name, unit="case", file=sys.stderr, disable=not progress)
    _postfix(bar, rows, len(cases))
    try:
        if pool is not None:
            _Solving(study, cases, raws, keys, store).run(todo, pool, rows, bar)
        bar.close()
        table = [rows[c.number] for c in cases]
        write_table(out / "table.csv", table)
        write_figures(out / "figures", study, cases, table, pool)
    except BaseException:
        bar.close()
        if pool is not None:
            pool.abort()
        raise
    if pool is not None:
        pool.close()
    return table


@dataclass
class _Solving:
    """The cases of a study with their raw problems and fingerprints, and where they are stored."""

    study: Study
    cases: list[PlannedCase]
    raws: dict[int, dict]
    keys: dict[int, str]
    store: CaseStore

    def run(self, todo: dict[int, int | None], pool: Executor, rows: dict[int, dict], bar: tqdm) -> None:
        """Solve the cases of `todo` (case -> parent), each once its parent is stored; store each
        as it finishes and put its row in `rows`."""
        threads = 1 if pool.lanes > 1 else None  # parallel cases, serial maps inside each
        jobs: dict[int, dict] = {}

        def job(n: int) -> dict:
            jobs[n] = _job(self.study, self.cases[n], self.raws[n], self.store, threads)
            return jobs[n]

        for n, outcome in run_tree(pool, solve_job, todo, job):
            case = self.cases[n]
            row, z = _row(self.study, case, jobs.pop(n), outcome)
            if not isinstance(outcome, BaseException):  # a lost worker is retried on the next run
                self.store.save(case.id, self.keys[n], row, z)
            rows[n] = clean(row)
            _postfix(bar, rows, len(self.cases))
            bar.update()


def _case_problem(study: Study, case: PlannedCase) -> dict[str, Any]:
    try:
        return case_problem(study, case)
    except InputError as exc:
        raise InputError(f"{study.source}: sweep.{exc}") from None


def _vehicle_for_its_form(study: Study, raw: dict, unread: dict[str, list[str]]) -> dict:
    """A case's problem less the vehicle entries of READ_BY its model form does not read (an
    engine, a crush offset), where the study sweeps model.form: the base problem's engine is the
    engine form's, its crush offset the pendulum's, the other forms' cases have none (as compare's
    problems of each form, crashnlp.optimize.comparison.with_form). `unread`: those entries per
    form and their values, the model built once for each. A problem that does not validate is
    left as it is, for `_validate` to refuse."""
    vehicle = raw.get("vehicle") or {}
    if not any(key in vehicle for key in READ_BY) or "model.form" not in {e.path for e in study.entries}:
        return raw
    form = (raw.get("model") or {}).get("form", DEFAULT_FORM)
    key = json.dumps([form, {k: vehicle.get(k) for k in READ_BY}], sort_keys=True, default=str)
    if key not in unread:
        from crashnlp.case.case import case_of  # the model: once per form, not per case

        try:
            unread[key] = case_of(problem_from_dict(raw, study.base_dir, source="problem")).unread_given()
        except InputError:
            return raw
    return {**raw, "vehicle": {k: v for k, v in vehicle.items() if k not in unread[key]}} if unread[key] else raw


def _validate(study: Study, case: PlannedCase, raw: dict, checked: set[str]) -> Problem:
    """The case's problem, validated: refuse one that is not valid, whose data contradict it
    (crashnlp.case.checks), or whose estimate or sweep names an entry its model form does not read
    (`_check_read`): those of a solve, naming the study file, the case and its values. Data are read
    once per distinct set of tests, speed and mass, the model built once per form and estimate (`checked`)."""
    values = ", ".join(f"{e.path} = {show(v)}" for e, v in zip(study.entries, case.values))
    try:
        problem = problem_from_dict(raw, study.base_dir, source="problem")
        check_keys(problem, "problem")
        vehicle = raw.get("vehicle", {})
        tests = json.dumps([raw.get("tests"), vehicle.get("speed"), vehicle.get("mass")], sort_keys=True, default=str)
        if tests not in checked:
            check_tests(problem, "problem")
            checked.add(tests)
        _check_read(problem, [e.path for e in study.entries], checked)
        _check_own(problem, [e.path for e in study.entries], checked)
    except InputError as exc:
        detail = str(exc).removeprefix("problem: ")
        raise InputError(f"{study.source}: sweep: {case.id} ({values}): {detail}") from None
    return problem


def _check_read(problem: Problem, swept: list[str], checked: set[str]) -> None:
    """Refuse an estimate entry or a given engine the case's model form does not read
    (crashnlp.optimize.pipeline.check_read), as its solve would, and a swept entry it does not read:
    every case of the sweep would be the same, plotted as if the entry did nothing. The model is
    built once per form, estimate and sweep (`checked`)."""
    key = json.dumps(["reads", problem.model.form, sorted(problem.estimate), swept])
    if key in checked:
        return
    from crashnlp.case.case import case_of  # the model: once per form and estimate, not per case
    from crashnlp.optimize.pipeline import check_read

    case = case_of(problem, "problem")
    check_read(case)
    slices = case.layout.slices()
    unread = case.model.unread([path for path in swept if path in slices])
    if unread:
        raise InputError(
            f"{unread[0]}: model.form {problem.model.form} does not read it (no equation of the form depends on it): "
            "every case would be the same; leave it out of the sweep"
        )
    checked.add(key)


def _check_own(problem: Problem, swept: list[str], checked: set[str]) -> None:
    """Refuse a swept vehicle.speed or vehicle.mass that every test of the case sets for itself
    (`OWN`) where nothing else reads it: the case built at another value completes to the same
    problem, so every case would be the same. Mass may reach more than the tests (an engine's
    share of it, a nominal damper, default estimate bounds): such a sweep stays. The cases are
    built once per problem apart from the entry (`checked`)."""
    from crashnlp.case.case import case_of  # the model: once per problem apart from the entry, not per case

    for path in swept:
        field = OWN.get(path)
        if field is None or not all(getattr(test, field) is not None for test in problem.tests):
            continue
        key = json.dumps(["own", path, _less(problem, field)], sort_keys=True)
        if key in checked:
            continue
        other = problem.with_values({path: 1.25 * getattr(problem.vehicle, field)})
        if _less(case_of(problem, "problem").problem, field) == _less(case_of(other, "problem").problem, field):
            tests = ", ".join(f"tests.{i}.{field}" for i in range(len(problem.tests)))
            raise InputError(
                f"{path}: every test sets its own {field} ({tests}) and nothing else reads it: "
                "every case would be the same; leave it out of the sweep"
            )
        checked.add(key)


def _less(problem: Problem, field: str) -> dict[str, Any]:
    """The problem as plain data, less vehicle.`field`."""
    dumped = problem.model_dump(mode="json")
    dumped["vehicle"].pop(field)
    return dumped


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
        outcome = {"record": {"status": f"error: {type(outcome).__name__}: {one_line(outcome)}"}, "z": None}
    row: dict[str, Any] = {"case": case.id}
    row.update({e.path: show(v) for e, v in zip(study.entries, case.values)})
    row.update({f"{e.path}_si": e.si(v) for e, v in zip(study.entries, case.values)})
    row["warm_start"] = case_id(job["warm_from"]) if job["warm_from"] is not None else ""
    row.update(outcome["record"])
    return row, outcome["z"]


def _postfix(bar: tqdm, rows: dict, total: int) -> None:
    failed = sum(1 for r in rows.values() if r["status"] != "ok")
    bar.set_postfix(ok=len(rows) - failed, failed=failed, left=total - len(rows), refresh=False)
