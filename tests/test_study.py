"""Constraint what-if studies: monotone costs, executors agree, resume, failures, bad study files."""

from __future__ import annotations

import csv
import itertools
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import types
from concurrent.futures.process import BrokenProcessPool, ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import yaml
from builders import BASE, ROOT, command, die_always, die_once, merge, parents, worker_pid, worker_state

from crashnlp.base.errors import InputError, RunError
from crashnlp.base.outputs import METRIC
from crashnlp.case.case import Case
from crashnlp.engine import executors
from crashnlp.engine.executors import LOCAL_CLUSTER_CONFIG, NO_WORKERS_WAIT, WORKER_DEATHS, DaskExecutor, LocalExecutor
from crashnlp.engine.schedule import map_all, run_tree
from crashnlp.optimize.identify import identify
from crashnlp.problem import problem_from_dict
from crashnlp.studies import load_study, run_study
from crashnlp.studies.plan import case_indices, case_problem, corners, lattice, plan_cases, warm_start_plan
from crashnlp.studies.spec import set_path
from crashnlp.studies.table import figure_jobs

PITCH = "constraints.bounds.pitch"
BOUNDS = [[None, "2 deg"], [None, "2.5 deg"], [None, "3 deg"], [None, "4 deg"]]  # the free fit pitches ~3.2 deg


def truth() -> dict:
    return merge(
        BASE,
        {
            "name": "small",
            "vehicle": {"crush_offset": 0.15},
            "model": {"spring": {"crush_breakpoints": [0, 0.2, 0.4, 0.7], "values": [0.0, 380e3, 520e3, 900e3]}},
            "tests": [{"name": "t56", "duration": 0.12}],
            "simulation": {"dt": 2e-4},
        },
    )


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    """A small identification problem (40 intervals, < 1 s a solve) with synthetic data, as fit.yaml."""
    folder = tmp_path_factory.mktemp("small")
    r = Case(problem_from_dict(truth(), folder)).simulate()["t56"]
    noise = np.random.default_rng(3).standard_normal((3, r.time.size))
    columns = {
        "time_s": r.time,
        "accel_g": r["accel"] / 9.80665 + 0.5 * noise[0],
        "disp_m": r["displacement"] + 0.001 * noise[1],
        "pitch_deg": np.degrees(r["pitch"]) + 0.05 * noise[2],
    }
    with (folder / "data.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        w.writerows(zip(*columns.values()))
    channels = {
        "accel": {"column": "accel_g", "unit": "g", "sigma": "0.5 g"},
        "displacement": {"column": "disp_m", "unit": "m", "sigma": 0.001},
        "pitch": {"column": "pitch_deg", "unit": "deg", "sigma": "0.05 deg"},
    }
    fit = merge(
        truth(),
        {
            "model": {"spring": {"values": ["500 kN"] * 4}},
            "vehicle": {"crush_offset": 0.1},
            "tests": [{"name": "t56", "data": {"file": "data.csv", "window": ["0 s", "0.12 s"], "channels": channels}}],
            "estimate": {"model.spring.values": {"bounds": ["0 kN", "3 MN"]}, "vehicle.crush_offset": {"bounds": [-0.3, 0.5]}},
            "transcription": {"method": "multiple-shooting", "intervals": 40, "substeps": 2},
        },
    )
    (folder / "fit.yaml").write_text(yaml.safe_dump(fit))
    return folder


def write_study(folder: Path, name: str = "small-study", **changes) -> Path:
    spec = {"name": name, "problem": "fit.yaml", "sweep": {PITCH: BOUNDS}, "mode": "grid", **changes}
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def without_wall_time(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


def read_table(path: Path) -> list[dict]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


# --------------------------------------------------------------------------- (1) the shipped study
@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    out = tmp_path_factory.mktemp("pitch-bound")
    rows = run_study(ROOT / "problems/studies/pitch-bound.yaml", out, workers=2, progress=False)
    return out, rows


@pytest.mark.integration
def test_tighter_pitch_bound_never_fits_better(shipped):
    out, rows = shipped
    assert [r["status"] for r in rows] == ["ok"] * 4
    rows = sorted(rows, key=lambda r: r[f"{PITCH}_si"])
    objective = [r["objective"] for r in rows]
    assert all(a >= b * (1 - 1e-6) for a, b in zip(objective, objective[1:])), objective
    assert objective[0] > objective[-1]
    for r in rows:
        active = r["56kph.max_pitch_deg"] >= np.degrees(r[f"{PITCH}_si"]) - 1e-4
        multiplier = r["multiplier.56kph.bound.pitch.upper"]
        assert multiplier < 0 if active else multiplier == 0, r  # d objective / d bound: a looser bound fits better
    # tighter bound, dearer: the multiplier rises to 0 as the bound loosens
    active = [r["multiplier.56kph.bound.pitch.upper"] for r in rows if r["multiplier.56kph.bound.pitch.upper"] < 0]
    assert len(active) >= 2 and active == sorted(active)
    table = read_table(out / "table.csv")
    assert [t[PITCH] for t in table] == ["[null, 4 deg]", "[null, 6 deg]", "[null, 8 deg]", "[null, 10 deg]"]
    assert (out / "figures" / f"{PITCH}.png").is_file()


@pytest.mark.integration
def test_the_study_figure_reads_in_degrees_under_the_consoles_labels(shipped):
    _, rows = shipped
    study = load_study(ROOT / "problems/studies/pitch-bound.yaml")
    (job,) = figure_jobs(study, plan_cases(study), rows)
    assert job["xlabel"] == f"{PITCH} (deg)" and job["x"] == pytest.approx([4, 6, 8, 10])
    assert job["title"] == f"pitch-bound: {PITCH}"
    pitch = job["series"]["56kph: max pitch (deg)"]
    assert pitch == pytest.approx([r["56kph.max_pitch_deg"] for r in rows])
    assert job["series"]["56kph: max displacement (mm)"] == pytest.approx([1e3 * r["56kph.max_displacement_m"] for r in rows])
    per_degree = job["series"]["56kph: d objective / d pitch upper bound (1/deg)"]
    assert per_degree == pytest.approx([np.radians(r["multiplier.56kph.bound.pitch.upper"]) for r in rows])
    # the peak under the label the console's table gives it: the CFC class each case's row records
    assert {r["56kph.accel_filter"] for r in rows} == {"CFC60"}
    peak = job["series"][f"56kph: {METRIC['peak_decel_g'].heading_through('CFC60')}"]
    assert peak == pytest.approx([r["56kph.peak_decel_g"] for r in rows])


@pytest.mark.integration
@pytest.mark.slow
def test_the_shipped_crush_space_designs_all_solve_and_more_space_never_costs_more(tmp_path):
    # the shipped design study as it is: 100 intervals, damper, plastic unloading, pitch, the
    # rebound and the end of contact (the kink of max(spring + damper, 0)) inside the horizon.
    # A change of the contact force or of the NLP that stalls one design shows here.
    crush = "constraints.bounds.crush"
    rows = sorted(
        run_study(ROOT / "problems/studies/crush-space.yaml", tmp_path, workers=2, progress=False), key=lambda r: r[f"{crush}_si"]
    )
    assert [r["status"] for r in rows] == ["ok"] * 7
    space = np.array([r[f"{crush}_si"] for r in rows])
    peak = np.array([r["objective"] for r in rows])
    assert np.all(np.diff(peak) <= 1e-6 * peak[:-1]), peak  # a looser bound only adds designs
    assert peak[0] > 1.5 * peak[-1]
    travel = np.array([r["56kph.max_displacement_m"] for r in rows])  # the CG's travel, on the NLP grid
    assert np.all(np.abs(travel - space) < 0.01), travel  # each design uses its space (pitch adds mm)
    gain = [-r["multiplier.56kph.bound.crush.upper"] for r in rows]  # the bound's price: peak fallen per metre
    assert gain == sorted(gain, reverse=True), gain  # space is worth less the more there is
    for r in rows:
        assert r["iterations"] > 0
        assert r["56kph.max_pitch_deg"] <= 10 + 1e-6, r
        assert r["56kph.rebound_velocity_mps"] > 0.5  # the front end springs back and leaves the barrier
        values = [r[f"model.spring.values[{i}]"] for i in range(12)]
        assert min(values) >= -1e-3 and max(values) <= 1.5e6 + 1e-3
        assert r["multiplier.56kph.bound.crush.upper"] < 0, r  # every design is held by its crush space


# --------------------------------------------------------------------------- the plan
def test_warm_start_plan_is_fixed_by_the_case_list():
    parent, depth = warm_start_plan((4,), [0, 3])
    assert parent == [None, 0, 3, None] and depth == [0, 1, 1, 0]
    parent, depth = warm_start_plan((3, 3), [0, 8])
    assert depth == [0, 1, 2, 1, 1, 1, 2, 1, 0]
    assert parent[4] == 0 and parent[1] == 0 and parent[2] == 1


def nearest_closer_neighbour(shape: tuple[int, ...], seeds: list[int]) -> tuple[list[int | None], list[int]]:
    """The plan's rule, case by case: depth the Chebyshev distance to the nearest seed; parent the
    neighbour one step closer, the nearest such (Euclidean), ties to the lower number."""
    points = np.array(list(itertools.product(*(range(n) for n in shape))))
    depth = [int(np.abs(points[seeds] - p).max(axis=1).min()) for p in points]
    parent: list[int | None] = []
    for n, p in enumerate(points):
        near = [m for m in range(len(points)) if np.abs(points[m] - p).max() == 1 and depth[m] == depth[n] - 1]
        parent.append(min(near, key=lambda m: (np.sum((points[m] - p) ** 2), m)) if depth[n] else None)
    return parent, depth


@pytest.mark.parametrize("shape", [(7,), (4, 5), (3, 1, 4), (2, 3, 2, 3)])
def test_the_plan_follows_its_rule_on_any_grid(shape):
    rng = np.random.default_rng(sum(shape))
    count = int(np.prod(shape))
    for seeds in (corners(shape), sorted(rng.choice(count, size=min(3, count), replace=False).tolist()), lattice(shape, 1)):
        assert warm_start_plan(shape, seeds) == nearest_closer_neighbour(shape, seeds)
    assert max(warm_start_plan(shape, lattice(shape, 1))[1]) <= 1


def test_grid_and_zip_cases(small):
    grid = load_study(write_study(small, sweep={PITCH: BOUNDS[:2], "vehicle.mass": ["2400 kg", "2500 kg", 2600]}))
    assert case_indices(grid) == [(i, j) for i in range(2) for j in range(3)]
    assert [c.parent for c in plan_cases(grid)] == [None, 0, None, None, 3, None]
    lattice_grid = load_study(write_study(small, max_depth=0, sweep={PITCH: BOUNDS[:2], "vehicle.mass": [2400, 2500, 2600]}))
    assert [c.parent for c in plan_cases(lattice_grid)] == [None] * 6
    zipped = load_study(write_study(small, mode="zip", sweep={PITCH: BOUNDS[:3], "vehicle.mass": [2400, 2500, 2600]}))
    assert [c.values for c in plan_cases(zipped)][1] == (BOUNDS[1], 2500)
    assert zipped.entries[0].si(BOUNDS[0]) == pytest.approx(np.radians(2))
    assert grid.entries[1].si("2.5 t") == pytest.approx(2500)


# --------------------------------------------------------------------------- (2) executors agree
class Shuffled:
    """An executor whose lanes finish their tasks in a random order, in this process."""

    def __init__(self, lanes: int, seed: int):
        self.lanes, self.rng, self.running = lanes, np.random.default_rng(seed), {}

    def submit(self, lane, fn, item):
        assert lane not in self.running  # one task per lane
        self.running[lane] = fn(item)

    def wait(self):
        lane = sorted(self.running)[self.rng.integers(len(self.running))]
        return lane, self.running.pop(lane)


def started_in_random_order(parent: dict, lanes: int, seed: int) -> list[int]:
    """The order in which run_tree starts tasks finishing at random; each must start after its parent."""
    finished: set[int] = set()
    started: list[int] = []

    def job(n):
        assert parent[n] is None or parent[n] in finished
        started.append(n)
        return n

    for n, result in run_tree(Shuffled(lanes, seed), lambda n: n, parent, job):
        assert result == n
        finished.add(n)
    assert sorted(started) == sorted(finished) == sorted(parent)
    return started


@pytest.mark.parametrize("lanes", [1, 2, 3, 8])
def test_every_case_starts_after_its_parent_whatever_the_lanes_and_timing(lanes):
    shape = (5, 6)
    for seeds in (corners(shape), lattice(shape, 1)):
        parent = dict(enumerate(warm_start_plan(shape, seeds)[0]))
        for seed in range(3):
            started = started_in_random_order(parent, lanes, seed)
            assert set(started[: min(lanes, len(seeds))]) <= set(seeds)  # cold seeds first: most work below


@pytest.mark.integration
def test_workers_live_across_cases_and_a_chain_stays_on_its_worker():
    chain, other = {0: None, 1: 0, 2: 1, 3: 2}, {4: None, 5: 4, 6: 5}
    executor = LocalExecutor(2)
    try:
        pid = dict(run_tree(executor, worker_pid, {**chain, **other}, lambda n: n))
    finally:
        executor.close()
    assert len({pid[n] for n in chain}) == len({pid[n] for n in other}) == 1
    assert len(set(pid.values())) == 2


@pytest.mark.integration
@pytest.mark.slow
def test_tables_agree_for_one_and_two_workers_and_dask(small, tmp_path, compiled_nlp, monkeypatch):
    """One worker and Dask in CasADi's virtual machine; two workers of the command line, as
    users run it (compilation on), with the study's NLP compiled beforehand: the same table."""
    study = write_study(small, sweep={PITCH: BOUNDS[:3], "vehicle.suspension.k_front": ["70 kN/m", "90 kN/m"]})
    with monkeypatch.context() as mp:
        mp.setenv("CRASHNLP_COMPILE", "model")
        one = run_study(study, tmp_path / "one", workers=1, progress=False)
        dask = run_study(study, tmp_path / "dask", executor="dask", workers=2, progress=False)
    assert [r["status"] for r in one] == ["ok"] * 6
    assert [r["warm_start"] for r in one] == ["", "", "case-000", "case-001", "", ""]
    assert without_wall_time(one) == without_wall_time(dask)
    # the library of the cases' shape (the swept entries are numbers the NLP takes as
    # parameters), compiled into a cache of this test's own, so that nothing else adds to it
    cache = tmp_path / "cache"
    monkeypatch.setenv("CRASHNLP_CACHE", str(cache))
    spec = load_study(study)
    first = problem_from_dict(case_problem(spec, plan_cases(spec)[0]), small).with_values({"solver.compile": "now"})
    assert identify(Case(first), progress=None).result.compiled
    libraries = sorted(p.name for p in cache.glob("nlp-*"))
    env = {k: v for k, v in os.environ.items() if k not in ("CRASHNLP_COMPILE", "CRASHNLP_KEEP_COMPILING")}
    argv = [sys.executable, "-m", "crashnlp.cli", "study", str(study), "--out", str(tmp_path / "two"), "--workers", "2"]
    done = subprocess.run([*argv, "--no-progress"], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    # every case loaded that library: a case of another shape would have built its NLP's
    # functions for a compile of their own, and named them beside the library
    assert sorted(p.name for p in cache.glob("nlp-*")) == libraries
    tables = [without_wall_time(read_table(tmp_path / name / "table.csv")) for name in ("one", "two", "dask")]
    assert tables[0] == tables[1] == tables[2]


@pytest.mark.integration
def test_a_task_whose_worker_is_killed_runs_again_on_a_fresh_worker(tmp_path):
    """Each of three tasks kills its worker the first time: each runs again and finishes; a
    task that kills its worker every time ends as the pool's error after WORKER_DEATHS reruns,
    and the others are not held up by it."""
    executor = LocalExecutor(2)
    items = [str(tmp_path / f"ran-{n}") for n in range(3)]
    try:
        pid = dict(map_all(executor, die_once, items))
        last = dict(map_all(executor, die_always, [str(tmp_path / "tally")]))
    finally:
        executor.close()
    assert all(isinstance(p, int) for p in pid.values()) and len(pid) == 3
    assert all(Path(item).exists() for item in items)
    assert isinstance(last[0], BrokenProcessPool)
    assert (tmp_path / "tally").read_text().count("ran") == WORKER_DEATHS + 1


@pytest.mark.integration
def test_an_aborted_executor_leaves_no_worker_and_no_thread_of_its_pools():
    """Abort mid-task ends the workers and waits for the pools' threads: a queue's feeder thread
    cut short by the process's end leaves the resource tracker's warning on the terminal."""
    executor = LocalExecutor(2)
    for lane in range(2):
        executor.submit(lane, time.sleep, 60)
    processes = [p for pool in executor.pools for p in pool._processes.values()]
    threads = [t for pool in executor.pools for t in (pool._executor_manager_thread, pool._call_queue._thread)]
    executor.abort()
    assert len(processes) == 2 and not [p for p in processes if p.is_alive()]
    assert len(threads) == 4 and not [t for t in threads if t is not None and t.is_alive()]


def test_a_held_signal_is_handled_as_the_hold_ends_and_every_handler_is_put_back():
    seen: list[int] = []
    ours = {s: lambda signum, frame: seen.append(signum) for s in executors.HELD_SIGNALS}
    previous = {s: signal.signal(s, handler) for s, handler in ours.items()}
    try:
        with executors._signals_held():
            signal.raise_signal(signal.SIGTERM)
            assert seen == [] and all(signal.getsignal(s) is not h for s, h in ours.items())
        assert seen == [signal.SIGTERM] and all(signal.getsignal(s) is h for s, h in ours.items())
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@pytest.mark.integration
def test_a_signal_while_a_worker_starts_is_handled_once_its_pool_knows_the_worker(monkeypatch):
    """SIGTERM raised while a worker process is being started: the command's handler runs only
    once the worker is in its pool, where `abort` finds it (a worker no pool knows reads its start
    message after the command has removed that message's semaphores)."""
    spawn = ProcessPoolExecutor._spawn_process

    def interrupted_spawn(pool):
        signal.raise_signal(signal.SIGTERM)
        spawn(pool)

    monkeypatch.setattr(ProcessPoolExecutor, "_spawn_process", interrupted_spawn)
    known: list[int] = []
    executor = LocalExecutor(1)
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: known.append(len(executor.pools[0]._processes)))
    try:
        executor.submit(0, worker_pid, None)
        assert known == [1]
        executor.wait()
    finally:
        signal.signal(signal.SIGTERM, previous)
        executor.close()


@pytest.mark.integration
@pytest.mark.slow
def test_a_dask_task_whose_worker_is_lost_runs_on_another(tmp_path):
    """On a LocalCluster, a task bound to a worker that dies under it runs again on the other."""
    executor = DaskExecutor(2)
    try:
        done = dict(run_tree(executor, die_once, {0: None}, lambda n: str(tmp_path / "ran")))
        others = dict(map_all(executor, worker_pid, [None, None]))
    finally:
        executor.close()
    assert isinstance(done[0], int) and (tmp_path / "ran").exists()
    assert all(isinstance(p, int) for p in others.values())


@pytest.mark.integration
def test_a_local_dask_cluster_runs_its_workers_without_the_profiler_and_leaves_the_callers_config(monkeypatch):
    """The LocalCluster's workers take LOCAL_CLUSTER_CONFIG, and malloc's settings of this process
    (not the MALLOC_TRIM_THRESHOLD_ dask's nanny sets by default); the process that started it keeps its own."""
    pytest.importorskip("distributed")  # which loads its part of dask's configuration
    import dask.config as dask_config

    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    before = {key: dask_config.get(key) for key in LOCAL_CLUSTER_CONFIG}
    executor = DaskExecutor(2)
    try:
        seen = executor.client.run(lambda: {key: dask_config.get(key) for key in LOCAL_CLUSTER_CONFIG})
        trim = executor.client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))
    finally:
        executor.close()
    assert len(seen) == 2 and all(config == LOCAL_CLUSTER_CONFIG for config in seen.values())
    assert list(trim.values()) == [None, None]
    assert {key: dask_config.get(key) for key in LOCAL_CLUSTER_CONFIG} == before != LOCAL_CLUSTER_CONFIG


@pytest.mark.integration
@pytest.mark.filterwarnings("ignore:Port .* is already in use")  # the two clusters' schedulers' web servers
def test_a_cluster_started_ahead_serves_the_next_executor_of_its_size_and_ends_without_leftovers():
    """start_cluster's LocalCluster is the next DaskExecutor's of its size (one of another size is
    closed); its workers have the solver stack loaded before any case and ignore SIGINT; closing
    ends their processes and leaves none of their lock files in dask's scratch folder."""
    pytest.importorskip("distributed")
    executors.start_cluster(1)
    executors.start_cluster(2)
    other, started = executors._started_clusters[1], executors._started_clusters[2]
    executor = DaskExecutor(2)
    try:
        assert executor.cluster is started and not executors._started_clusters
        assert other.status.name == "closed"
        pids = [nanny.pid for nanny in started.workers.values()]
        locks = [Path(nanny.worker_dir + ".dirlock") for nanny in started.workers.values()]
        assert all(lock.exists() for lock in locks)
        state = executor.client.run(worker_state)
    finally:
        executor.close()
    assert list(state.values()) == [(True, True)] * 2
    time.sleep(0.2)
    assert not [pid for pid in pids if Path(f"/proc/{pid}").exists() and " Z " not in Path(f"/proc/{pid}/stat").read_text()]
    assert not [lock for lock in locks if lock.exists()]


def test_a_dask_cluster_left_without_workers_ends_the_run_in_one_line(monkeypatch):
    """No worker seen for NO_WORKERS_WAIT seconds is a RunError; a worker seen again starts the wait anew."""
    clock = iter([0.0, 50.0, 60.0, 100.0, 61.0 + NO_WORKERS_WAIT])
    monkeypatch.setattr(executors.time, "monotonic", lambda: next(clock))
    state = types.SimpleNamespace(empty_since=None, running={1: None})
    check = DaskExecutor._check_not_empty
    check(state, False)  # t = 0: the wait starts
    check(state, True)  # t = 50: a worker again
    check(state, False)  # t = 60: the wait starts anew
    check(state, False)  # t = 100: 40 s without one
    with pytest.raises(RunError, match=f"no worker for {NO_WORKERS_WAIT:g} s; 1 cases left"):
        check(state, False)  # just past NO_WORKERS_WAIT without one


@pytest.fixture(scope="module")
def calm(small, tmp_path_factory) -> tuple[Path, list[dict]]:
    """write_study(small)'s cases run undisturbed on two workers: the folder and the rows."""
    out = tmp_path_factory.mktemp("calm") / "out"
    return out, run_study(write_study(small), out, workers=2, progress=False)


def _workers_of(pid: int) -> set[int]:
    """The pool workers below a crashnlp process: the children of its fork server's process."""
    parent = parents()
    below = {p for p, pp in parent.items() if pp == pid}
    return {p for p, pp in parent.items() if pp in below and "forkserver" in command(pp)}


@pytest.mark.integration
@pytest.mark.slow
@pytest.mark.parametrize("pidfd", [True, False])
def test_a_worker_ends_once_the_process_that_started_it_is_killed(pidfd):
    """A study's main process killed by SIGKILL (or the out-of-memory killer) stops nothing: its
    workers, children of the fork server, waited on their queues for ever. A worker ends once its
    main process is gone, watched through a pidfd, or polled where there is none."""
    main = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    no_pidfd = "" if pidfd else "import os; del os.pidfd_open; "
    watch = f"{no_pidfd}from crashnlp.engine import executors; executors._worker_init({main.pid}); print('watching', flush=True)"
    worker = subprocess.Popen([sys.executable, "-c", f"{watch}; import time; time.sleep(120)"], stdout=subprocess.PIPE, text=True)
    try:
        assert worker.stdout.readline() == "watching\n"
        time.sleep(0.2)
        assert worker.poll() is None  # its main process is there: it stays
        main.kill()
        main.wait()
        assert worker.wait(timeout=3 * executors.ORPHAN_POLL + 10) == 1
    finally:
        for process in (main, worker):
            process.kill()
            process.wait()


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc")
def test_a_study_whose_worker_is_killed_mid_case_completes_with_the_same_table(small, calm, tmp_path):
    """SIGKILL to one of the two workers while it solves a case: the command ends 0 and its
    table is the undisturbed run's."""
    study, (calm_out, calm) = write_study(small), calm
    out = tmp_path / "killed"
    argv = [sys.executable, "-m", "crashnlp.cli", "study", str(study), "--out", str(out), "--workers", "2", "--no-progress"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline, killed = time.monotonic() + 60, None
    while killed is None and time.monotonic() < deadline and proc.poll() is None:
        workers = _workers_of(proc.pid)
        if workers and not list(out.glob("cases/*.json")):
            time.sleep(0.3)  # into its case
            killed = min(workers)
            os.kill(killed, signal.SIGKILL)
        time.sleep(0.05)
    _, err = proc.communicate(timeout=120)
    assert killed is not None, "no worker was seen to kill"
    assert proc.returncode == 0, err
    assert without_wall_time(read_table(out / "table.csv")) == without_wall_time(read_table(calm_out / "table.csv"))
    assert [r["status"] for r in calm] == ["ok"] * 4


# --------------------------------------------------------------------------- (3) resume
@pytest.mark.integration
@pytest.mark.slow
def test_an_interrupted_study_resumes_without_redoing_finished_cases(small, calm, tmp_path):
    study, out, (calm_out, first) = write_study(small), tmp_path / "out", calm
    shutil.copytree(calm_out, out)
    cases = out / "cases"
    stamp = {p.name: p.stat().st_mtime_ns for p in cases.glob("*.json")}
    for name in ("case-001", "case-002"):  # as if stopped after the seed wave
        (cases / f"{name}.json").unlink()
        (cases / f"{name}.npy").unlink()
    again = run_study(study, out, workers=2, progress=False)
    restamp = {p.name: p.stat().st_mtime_ns for p in cases.glob("*.json")}
    redone = {n for n in restamp if restamp[n] != stamp.get(n)}
    assert redone == {"case-001.json", "case-002.json"}
    assert without_wall_time(again) == without_wall_time(first)
    # nothing left to do: no solve at all, the same table
    run_study(study, out, executor="dask", address="tcp://127.0.0.1:1", progress=False)  # never connects
    assert {p.name: p.stat().st_mtime_ns for p in cases.glob("*.json")} == restamp


def test_a_sweep_of_one_tests_entry_is_that_tests_alone_where_the_tests_share_it_by_an_alias(tmp_path):
    """The shipped two-test pickup gives its tests one channel list by a YAML alias: sweeping the
    first test's accelerometer filter leaves the second's as the file gives it."""
    study = tmp_path / "filter.yaml"
    study.write_text(
        f"name: filter\nproblem: {ROOT / 'problems/pickup-joint.yaml'}\n"
        "sweep:\n  tests.0.data.channels.accel.filter: [CFC180]\nmode: grid\n"
    )
    spec = load_study(study)
    raw = case_problem(spec, plan_cases(spec)[0])
    assert [t["data"]["channels"]["accel"]["filter"] for t in raw["tests"]] == ["CFC180", "CFC60"]


def test_a_swept_entry_that_values_share_is_changed_at_its_place_alone():
    """However the problem's values came (a file's aliases that its reading kept shared, or a
    problem built in Python), a sweep writes its own copy of what it walks through."""
    channels = {"accel": {"filter": "CFC60"}}
    raw = {"tests": [{"data": {"channels": channels}}, {"data": {"channels": channels}}]}
    set_path(raw, ("tests", 0, "data", "channels", "accel", "filter"), "CFC180")
    assert [t["data"]["channels"]["accel"]["filter"] for t in raw["tests"]] == ["CFC180", "CFC60"]
    assert channels == {"accel": {"filter": "CFC60"}}


@pytest.mark.parametrize("workers", [0, -3, 2.5, "2", True])
def test_a_number_of_workers_below_one_or_not_whole_is_refused_by_the_api_as_by_the_command(workers, tmp_path, capsys):
    """crashnlp.study(workers=0) had run on the cores available, -3 failed in min() and 2.5 or "2"
    deep in the executor: each is now the command's one line, naming workers, before any work."""
    import crashnlp
    from crashnlp.cli import main

    study, out = ROOT / "problems/studies/pitch-bound.yaml", tmp_path / "out"
    with pytest.raises(InputError, match=rf"^workers {re.escape(repr(workers))}: must be a whole number, at least 1$"):
        crashnlp.study(study, workers=workers, out=out)
    assert not out.exists()
    if isinstance(workers, int) and not isinstance(workers, bool):  # what --workers (an int) can be given
        assert main(["study", str(study), "--out", str(out), "--workers", str(workers), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.endswith(f" --workers {workers}: must be a whole number, at least 1\n")
        assert not out.exists()


@pytest.mark.integration
def test_a_changed_case_is_solved_again(small, tmp_path):
    out = tmp_path / "out"
    run_study(write_study(small, sweep={PITCH: BOUNDS[:2]}), out, workers=1, progress=False)
    stamp = {p.name: p.stat().st_mtime_ns for p in (out / "cases").glob("*.json")}
    rows = run_study(write_study(small, sweep={PITCH: [BOUNDS[0], BOUNDS[2]]}), out, workers=1, progress=False)
    restamp = {p.name: p.stat().st_mtime_ns for p in (out / "cases").glob("*.json")}
    assert restamp["case-000.json"] == stamp["case-000.json"] and restamp["case-001.json"] != stamp["case-001.json"]
    assert rows[1][PITCH] == "[null, 3 deg]"


@pytest.mark.integration
def test_a_case_whose_data_or_code_changed_is_solved_again_and_the_console_says_what_it_reused(
    small, tmp_path, capsys, monkeypatch
):
    """A run into a study's folder reuses a case only while its problem, its data files' contents
    and crashnlp are the same (it had reused the cases of the data before an edit, silently)."""
    from crashnlp.cli import main
    from crashnlp.studies import run

    folder, out = tmp_path / "study", tmp_path / "out"
    shutil.copytree(small, folder)  # data of its own to edit
    args = ["study", str(write_study(folder, sweep={PITCH: BOUNDS[:2]})), "--out", str(out), "--workers", "1", "--no-progress"]

    def again() -> tuple[str, list[str]]:
        assert main(args) == 0
        return capsys.readouterr().out, [r["objective"] for r in read_table(out / "table.csv")]

    said, first = again()
    assert "reused" not in said
    assert again() == (
        f"2 of 2 cases reused from {out / 'cases'}/: their problem, data and crashnlp unchanged\n"
        f"2 of 2 cases ok; wrote {out}/table.csv and {out}/figures/\n",
        first,
    )
    table = read_table(folder / "data.csv")
    for row in table:
        row["accel_g"] = str(1.2 * float(row["accel_g"]))
    with (folder / "data.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, list(table[0]))
        writer.writeheader()
        writer.writerows(table)
    said, edited = again()
    assert said.startswith("0 of 2 cases reused") and all(a != b for a, b in zip(edited, first))
    monkeypatch.setattr(run, "code_identity", lambda: "crashnlp edited")
    said, _ = again()
    assert said.startswith("0 of 2 cases reused")


def test_a_case_warm_started_from_a_changed_parent_is_solved_again():
    """A case's key holds its parent's key: a study edit that changes only the parent's value (its
    child warm-starts from another solution) reused the child; its key changes now, a seed's not."""
    from crashnlp.studies.plan import PlannedCase
    from crashnlp.studies.run import _Cases

    planned = [PlannedCase(1, (1,), (), 0, 1), PlannedCase(0, (0,), (), None, 0), PlannedCase(2, (2,), (), None, 0)]

    def keys(seed: float) -> dict[int, str]:
        return _Cases(planned, {0: {"bound": seed}, 1: {"bound": 2.0}, 2: {"bound": 3.0}}, {0: (), 1: (), 2: ()}).keys()

    before, after = keys(1.0), keys(5.0)
    assert before[0] != after[0] and before[1] != after[1] and before[2] == after[2]


def test_the_code_a_case_is_keyed_by_changes_with_any_file_of_the_package(tmp_path):
    """crashnlp's version stays the same while its code changes: the package's files key it too."""
    from crashnlp.studies.plan import package_digest

    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "form.py").write_text("a = 1\n")
    (tmp_path / "__pycache__").mkdir()
    before = package_digest(tmp_path)
    (tmp_path / "__pycache__" / "form.cpython-311.pyc").write_bytes(b"compiled")
    assert package_digest(tmp_path) == before
    (tmp_path / "models" / "form.py").write_text("a = 2\n")
    assert package_digest(tmp_path) != before


# --------------------------------------------------------------------------- (4) failures
@pytest.mark.integration
def test_a_failing_case_is_recorded_and_the_others_finish(small, tmp_path):
    sweep = {PITCH: BOUNDS, "solver.ipopt.max_iter": [1000, 1000, 0, 1000]}
    rows = run_study(write_study(small, mode="zip", sweep=sweep), tmp_path / "out", workers=2, progress=False)
    status = [r["status"] for r in rows]
    assert status[0] == "ok" and status[1] == "ok" and status[3] == "ok"
    assert status[2].startswith("solver failed")
    table = read_table(tmp_path / "out/table.csv")
    assert len(table) == 4 and table[2]["status"].startswith("solver failed")


@pytest.mark.integration
def test_a_case_ipopt_solved_that_fails_its_check_keeps_ipopts_status_in_the_table_and_the_console(tmp_path, capsys):
    """The shipped design on 20 intervals: IPOPT solves it, its forward simulation departs from the
    NLP, and the case fails on that; the table had lost IPOPT's return status. The study exits 1
    with its one line on stderr (it had said nothing there)."""
    from crashnlp.cli import main

    study = write_study(tmp_path, problem=str(ROOT / "problems/design-crush-space.yaml"), sweep={"transcription.intervals": [20]})
    assert main(["study", str(study), "--out", str(tmp_path / "out"), "--workers", "1", "--no-progress"]) == 1
    (row,) = read_table(tmp_path / "out/table.csv")
    assert "the forward simulation departs from the NLP" in row["status"] and row["return_status"] == "Solve_Succeeded"
    said = capsys.readouterr()
    assert f"case-000: {row['status']} (IPOPT Solve_Succeeded)" in said.out
    assert said.err.count("\n") == 1 and said.err.startswith("crashnlp: ") and "1 of 1 cases failed (case-000;" in said.err


def test_a_failed_case_is_marked_on_the_sweep_figure_at_its_swept_value(small, monkeypatch):
    """A one-entry sweep's figure marks a failed case at its swept value, as a grid's map marks its
    cell: the failed values go with the job (on the solved cases' scale), and the drawn figure's
    x axis reaches them, with a legend counting them."""
    from crashnlp.results import plots
    from crashnlp.studies.table import draw_figure

    study = load_study(write_study(small, sweep={"solver.ipopt.max_iter": [3, 250, 500]}))
    rows = [
        {"status": "solver failed: Maximum_Iterations_Exceeded"},
        {"status": "ok", "objective": 1.1},
        {"status": "ok", "objective": 1.0},
    ]
    (job,) = figure_jobs(study, plan_cases(study), rows)
    assert job["x"] == pytest.approx([250, 500]) and job["failed"] == pytest.approx([3])
    assert job["series"]["objective"] == pytest.approx([1.1, 1.0])
    drawn = {}
    monkeypatch.setattr(plots, "_png", lambda fig: drawn.setdefault("axes", fig.axes))
    draw_figure(job)
    (ax,) = drawn["axes"]
    assert ax.get_xlim()[0] < 3 and [t.get_text() for t in ax.get_legend().get_texts()] == ["failed: 1"]


def test_a_bad_swept_value_is_refused_before_any_solve(small, tmp_path):
    sweep = {PITCH: [BOUNDS[0], [None, "2 kg"], BOUNDS[2], BOUNDS[3]]}
    with pytest.raises(InputError, match=r"small-study.yaml: sweep: case-001 \(constraints.bounds.pitch = \[null, 2 kg\]\)"):
        run_study(write_study(small, mode="zip", sweep=sweep), tmp_path / "out", workers=2, progress=False)
    assert not (tmp_path / "out").exists()


def test_a_swept_mass_the_data_header_contradicts_is_refused_before_any_solve(tmp_path):
    """Each case's data are checked against its speed and its mass (crashnlp.case.testcase.check_data)."""
    study = write_study(tmp_path, problem=str(ROOT / "problems/nhtsa-10146.yaml"), sweep={"vehicle.mass": ["1719 kg", "2500 kg"]})
    expected = (
        r"sweep: case-001 \(vehicle.mass = 2500 kg\): vehicle.mass: 2500 kg, but the data header of test 10146 says 1719 kg"
    )
    with pytest.raises(InputError, match=expected):
        run_study(study, tmp_path / "out", workers=1, progress=False)
    assert not (tmp_path / "out").exists()


def test_a_swept_entry_of_a_section_the_problem_leaves_out_keeps_its_unit(tmp_path):
    """The pickup as the engine form, its engine left to the data: a sweep of the engine's gap in
    mm and m reads its unit from the engine section's declared type (it had none, the values'
    column was empty and the figure's axis counted the values)."""
    raw = yaml.safe_load((ROOT / "problems/pickup-56kph.yaml").read_text())
    raw["model"]["form"] = "engine-on-mounts"
    raw["tests"][0]["data"]["file"] = str(ROOT / "problems" / raw["tests"][0]["data"]["file"])
    (tmp_path / "engine.yaml").write_text(yaml.safe_dump(raw))
    study = load_study(
        write_study(tmp_path, problem=str(tmp_path / "engine.yaml"), sweep={"vehicle.engine.gap": ["450 mm", "0.55 m"]})
    )
    (entry,) = study.entries
    assert entry.unit == "m" and [entry.si(v) for v in entry.values] == pytest.approx([0.45, 0.55])


@pytest.mark.parametrize("path", ["vehicle.speed", "tests.0.speed"])
def test_a_swept_speed_has_its_si_column_and_its_figure_axis(small, path):
    """vehicle.speed shapes the model (no estimate names it) and a test's speed sits in the list of
    tests: a sweep of either read no unit, its SI column was empty and its figure counted the values."""
    study = load_study(write_study(small, sweep={path: ["55 km/h", "57 km/h"]}))
    (entry,) = study.entries
    assert [entry.si(v) for v in entry.values] == pytest.approx([55 / 3.6, 57 / 3.6])
    (job,) = figure_jobs(study, plan_cases(study), [{"status": "ok", "objective": 1.0}] * 2)
    assert job["x"] == pytest.approx([55 / 3.6, 57 / 3.6]) and job["xlabel"] == f"{path} (m/s)"


def test_a_sweep_of_forms_gives_the_base_problems_engine_to_the_form_that_reads_it(tmp_path):
    """The pickup with an engine of its own, swept over the rigid body and the engine form: each
    case is valid (the rigid body's case had been refused for the engine it does not read), the
    rigid body's without the engine, the engine form's with it, as compare's problems are."""
    from crashnlp.studies.run import _checked_cases

    raw = yaml.safe_load((ROOT / "problems/pickup-56kph.yaml").read_text())
    raw["vehicle"]["engine"] = {"mass": "380 kg"}
    raw["estimate"].pop("vehicle.crush_offset")
    raw["tests"][0]["data"]["file"] = str(ROOT / "problems" / raw["tests"][0]["data"]["file"])
    (tmp_path / "engine.yaml").write_text(yaml.safe_dump(raw))
    forms = ["rigid-body", "engine-on-mounts"]
    _, cases, raws, _ = _checked_cases(write_study(tmp_path, problem=str(tmp_path / "engine.yaml"), sweep={"model.form": forms}))
    engines = {raws[c.number]["model"]["form"]: raws[c.number]["vehicle"].get("engine") for c in cases}
    assert engines == {"rigid-body": None, "engine-on-mounts": {"mass": "380 kg"}}


def test_a_swept_entry_the_form_does_not_read_is_refused_before_any_solve(tmp_path):
    """The pickup as a rigid body (its crush offset left out of its estimate) sweeping the crush
    offset, which a rigid body does not read: every case would give the same row, plotted as if the
    entry did nothing (it ran, 2 of 2 ok)."""
    raw = yaml.safe_load((ROOT / "problems/pickup-56kph.yaml").read_text())
    raw["model"]["form"] = "rigid-body"
    raw["estimate"].pop("vehicle.crush_offset")
    raw["tests"][0]["data"]["file"] = str(ROOT / "problems" / raw["tests"][0]["data"]["file"])
    (tmp_path / "rigid.yaml").write_text(yaml.safe_dump(raw))
    study = write_study(tmp_path, problem=str(tmp_path / "rigid.yaml"), sweep={"vehicle.crush_offset": ["0.1 m", "0.3 m"]})
    expected = r"sweep: case-000 \(vehicle.crush_offset = 0.1 m\): vehicle.crush_offset: model.form rigid-body does not read it"
    with pytest.raises(InputError, match=expected):
        run_study(study, tmp_path / "out", workers=1, progress=False)
    assert not (tmp_path / "out").exists()


def test_a_swept_speed_every_test_sets_for_itself_is_refused_in_one_line_with_exit_2(tmp_path, capsys):
    """The shipped design's test sets its own speed: a sweep of vehicle.speed ran N identical cases,
    each ok (exit 0)."""
    from crashnlp.cli import main

    study = write_study(
        tmp_path, problem=str(ROOT / "problems/design-crush-space.yaml"), sweep={"vehicle.speed": ["40 km/h", "56 km/h"]}
    )
    assert main(["study", str(study), "--out", str(tmp_path / "out"), "--check"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(study) in err
    assert "vehicle.speed: every test sets its own speed (tests.0.speed)" in err and "leave it out of the sweep" in err


def test_a_swept_mass_every_test_sets_for_itself_is_refused_unless_more_of_the_case_reads_it(tmp_path):
    """The pickup whose test sets its own mass: vehicle.mass reaches nothing else of the pendulum's
    case, and its sweep is refused; the engine form takes its engine's mass as a share of
    vehicle.mass, so there the sweep changes the case and stays."""
    raw = yaml.safe_load((ROOT / "problems/pickup-56kph.yaml").read_text())
    raw["tests"][0]["mass"] = "2700 kg"
    raw["tests"][0]["data"]["file"] = str(ROOT / "problems" / raw["tests"][0]["data"]["file"])
    (tmp_path / "pendulum.yaml").write_text(yaml.safe_dump(raw))
    raw["model"]["form"] = "engine-on-mounts"
    raw["estimate"].pop("vehicle.crush_offset")
    raw["vehicle"].pop("crush_offset")
    (tmp_path / "engine.yaml").write_text(yaml.safe_dump(raw))
    sweep = {"vehicle.mass": ["2600 kg", "2700 kg"]}
    expected = r"sweep: case-000 \(vehicle.mass = 2600 kg\): vehicle.mass: every test sets its own mass \(tests.0.mass\)"
    with pytest.raises(InputError, match=expected):
        run_study(write_study(tmp_path, problem=str(tmp_path / "pendulum.yaml"), sweep=sweep), check=True)
    assert run_study(write_study(tmp_path, problem=str(tmp_path / "engine.yaml"), sweep=sweep), check=True) == []


def test_a_swept_form_that_does_not_read_an_estimated_entry_is_refused_before_any_solve(tmp_path):
    """The shipped pickup estimates the pendulum's crush offset, which a rigid body does not read:
    its solve refuses that case, so the study's check does too (it said ok, then failed the case)."""
    study = write_study(
        tmp_path, problem=str(ROOT / "problems/pickup-56kph.yaml"), sweep={"model.form": ["pendulum", "rigid-body"]}
    )
    expected = (
        r"sweep: case-001 \(model.form = rigid-body\): estimate.vehicle.crush_offset: model.form rigid-body does not read it"
    )
    with pytest.raises(InputError, match=expected):
        run_study(study, tmp_path / "out", workers=1, progress=False)
    assert not (tmp_path / "out").exists()


def test_cli_refuses_a_bad_swept_value_with_exit_2_and_writes_nothing(small, tmp_path, capsys):
    from crashnlp.cli import main

    study = write_study(small, sweep={PITCH: [BOUNDS[0], [None, "x deg"]]})
    code = main(["study", str(study), "--out", str(tmp_path / "out"), "--workers", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "case-001" in err and "x deg" in err
    assert not (tmp_path / "out").exists()


def test_a_study_refuses_a_folder_holding_another_run_s_results(small, tmp_path, capsys):
    """The output rule of every command (crashnlp.results.files.claim): a fit's folder is not a study's."""
    from crashnlp.cli import main
    from crashnlp.results.files import RECORD

    out = tmp_path / "out"
    out.mkdir()
    (out / RECORD).write_text('{"run": "identify fit", "entries": ["result.json"]}')
    code = main(["study", str(write_study(small)), "--out", str(out), "--check"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "holds the results of another run (identify fit), not of study small-study" in err
    with pytest.raises(InputError, match="holds the results of another run"):
        run_study(write_study(small), out, progress=False)


# --------------------------------------------------------------------------- bad study files
@pytest.mark.parametrize(
    "changes, message",
    [
        ({"sweeps": {}}, "sweeps: unknown key"),
        ({"sweep": {"constraints.bounds.pich": BOUNDS}}, "sweep.constraints.bounds.pich: not an entry"),
        ({"sweep": {"vehicle.mass.kg": [1]}}, "sweep.vehicle.mass.kg: not an entry"),
        ({"mode": "zip", "sweep": {PITCH: BOUNDS, "vehicle.mass": [1, 2]}}, "sweep: zip mode needs lists of the same length"),
        ({"problem": "missing.yaml"}, "problem: file not found"),
        ({"sweep": {PITCH: []}}, f"sweep.{PITCH}:"),
        ({"seeds": [9]}, "seeds:"),
        ({"seeds": [0], "max_depth": 1}, "give seeds or max_depth, not both"),
        ({"max_depth": -1}, "max_depth:"),
        ({"sweep": {"solver.ipopt.max_itr": [5]}}, "solver.ipopt.max_itr: no such IPOPT option (did you mean max_iter?)"),
    ],
)
def test_bad_study_file_is_one_line_naming_the_key(small, changes, message):
    study = write_study(small, name="bad", **changes)
    with pytest.raises(InputError) as err:
        run_study(study, small / "never", progress=False)
    text = str(err.value)
    assert text.startswith(str(study)) and message in text and "\n" not in text
    assert not (small / "never").exists()
