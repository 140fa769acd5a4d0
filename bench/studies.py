"""Studies: `crashnlp study` wall times by worker count, what one case costs, and a 10,000-case projection.

- pitch-bound.yaml (4 cases), 1 and 2 workers, threaded and serial maps;
- pitch-suspension.yaml (a 4 x 4 grid) on 1 worker (threaded and serial maps), 2 workers and a
  dask LocalCluster of 2, the runs interleaved and repeated (medians), every table compared;
- the same entries on an 8 x 8 grid (64 cases), 1 and 2 workers and a dask LocalCluster of 2, interleaved;
- one case in this process: its whole cost against IPOPT's (their ratio, the per-case overhead), and the
  bytes a worker gets and returns;
- the scheduler's own cost per case (no-op tasks of real size through the process pool and dask),
  and the main process's per case (storing a case) and per case set up (checking a 10,000-case study);
- a projection: the real scheduler on a virtual clock over a 100 x 100 grid with the measured case
  costs, for 2 to 1024 workers.

Each CLI run goes into a fresh temporary folder (a study resumes from its folder).
"""

from __future__ import annotations

import csv
import heapq
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bench.common import PROBLEMS, ROOT, wait_for_compiles
from crashnlp.base.cache import cache_dir
from crashnlp.numerics.compile_job import KEEP_ENV
from crashnlp.numerics.runtime import THREADS_ENV

CLI = [sys.executable, "-m", "crashnlp.cli", "study"]
# the crashnlp of this checkout; the warm-up runs' background compiles finish after them (the default), for the timed runs
ENV = {k: v for k, v in {**os.environ, "PYTHONPATH": str(ROOT)}.items() if k != KEEP_ENV}
PITCH_BOUND = PROBLEMS / "studies" / "pitch-bound.yaml"
GRID = PROBLEMS / "studies" / "pitch-suspension.yaml"
PITCH = "constraints.bounds.pitch"
K_FRONT = "vehicle.suspension.k_front"
QUICK_STUDY = {"name": "pitch-bound-quick", "sweep": {PITCH: [[None, "6 deg"], [None, "10 deg"]]}, "mode": "grid"}
GRID_64 = {
    "name": "pitch-suspension-64",
    "sweep": {PITCH: [[None, f"{d} deg"] for d in range(3, 11)], K_FRONT: [f"{k} kN/m" for k in range(40, 120, 10)]},
    "mode": "grid",
}
LANES = (2, 8, 32, 128, 512, 1024)


def write_study(folder: Path, spec: dict) -> Path:
    """A study file on the pickup problem."""
    path = folder / f"{spec['name']}.yaml"
    path.write_text(yaml.safe_dump({**spec, "problem": str(PROBLEMS / "pickup-56kph.yaml")}))
    return path


def run_once(study: Path, workers: int, executor: str = "local", serial_maps: bool = False) -> dict:
    """Wall time, exit status and table of one `crashnlp study` process into a fresh folder.

    `serial_maps` sets CRASHNLP_THREADS=1, so that one worker uses one core (by default a
    lone worker's solve uses the threaded maps on every core)."""
    env = {**ENV, THREADS_ENV: "1"} if serial_maps else ENV
    with tempfile.TemporaryDirectory(prefix="bench-study-") as out:
        cmd = [*CLI, str(study), "--workers", str(workers), "--executor", executor, "--out", out, "--no-progress"]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env)
        wall = time.perf_counter() - t0
        table = Path(out) / "table.csv"
        rows = list(csv.DictReader(table.open())) if table.exists() else []
    summary = (proc.stdout.strip().splitlines() or [proc.stderr.strip()[-300:]])[0]
    return {"wall_s": wall, "exit": proc.returncode, "cases": len(rows), "summary": summary, "rows": rows}


def without_times(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


def interleaved(study: Path, variants: dict[str, dict], repeats: int) -> tuple[dict[str, dict], list[dict]]:
    """Every variant (run_once keywords) `repeats` times, taking turns so that a change of the
    machine's load falls on all alike: the median wall time of each, whether every table equals
    the first (but for the solve times), the machine's load average before and after them (a
    speed-up measured beside other work is not the machine's), and the first table."""
    runs: dict[str, list[dict]] = {name: [] for name in variants}
    load_before = os.getloadavg()[0]
    for _ in range(repeats):
        for name, kwargs in variants.items():
            runs[name].append(run_once(study, **kwargs))
    load = {"load_average": [load_before, os.getloadavg()[0]]}  # 1-minute, before and after: what else ran beside them
    reference = without_times(runs[next(iter(runs))][0]["rows"])
    out = {}
    for name, rs in runs.items():
        out[name] = {
            **variants[name],
            "wall_s": statistics.median(r["wall_s"] for r in rs),
            "walls_s": [r["wall_s"] for r in rs],
            "exit": max(r["exit"] for r in rs),
            "cases": rs[0]["cases"],
            "summary": rs[0]["summary"],
            "same_table": all(without_times(r["rows"]) == reference for r in rs),
            **chain_bound(rs[0]["rows"]),
            **load,
        }
        print(
            f"  {study.stem} {name}: {out[name]['wall_s']:.1f} s (runs {', '.join(f'{w:.1f}' for w in out[name]['walls_s'])}), "
            f"{out[name]['summary']}; load average {load_before:.1f} to {load['load_average'][1]:.1f} on {os.cpu_count()} cores"
        )
    return out, runs[next(iter(runs))][0]["rows"]


def chain_bound(rows: list[dict]) -> dict:
    """The solves' total IPOPT time and the longest warm-start chain through them.

    A case starts only after the case it warm-starts from, so no executor finishes the solves
    in less than the longest chain: total / max(chain, total / 2) bounds what two workers gain."""
    if not rows:
        return {}
    wall = {r["case"]: float(r["wall_s"] or 0.0) for r in rows}
    parent = {r["case"]: r["warm_start"] or None for r in rows}
    chain = lambda c: wall[c] + (chain(parent[c]) if parent[c] else 0.0)
    total, longest = sum(wall.values()), max(chain(c) for c in wall)
    return {"solves_s": total, "longest_chain_s": longest, "two_worker_bound": total / max(longest, total / 2)}


def speedups(runs: dict[str, dict], base: str = "1 worker") -> dict[str, float]:
    return {name: runs[base]["wall_s"] / r["wall_s"] for name, r in runs.items()}


# --------------------------------------------------------------------------- one case, in this process
def case_cost(repeats: int) -> dict:
    """A cold seed and a warm case of the 16-case grid solved here (median of `repeats`): the whole
    job against IPOPT's share, and the pickled job (problem + warm start) and result."""
    from crashnlp.studies.plan import case_problem, plan_cases
    from crashnlp.studies.run import constraint_names
    from crashnlp.studies.spec import load_study
    from crashnlp.studies.worker import solve_job

    os.environ[THREADS_ENV] = "1"
    study = load_study(GRID)
    cases = plan_cases(study)
    seed, child = cases[3], next(c for c in cases if c.parent == 3)
    job = {
        "threads": 1,
        "raw": case_problem(study, seed),
        "base_dir": str(study.base_dir),
        "constraints": constraint_names(study),
    }
    job["warm_from"] = None
    solve_job({**job, "id": "warm-up", "warm": None})  # this process's first case pays for loading code
    cold = [timed_job(solve_job, {**job, "id": seed.id, "warm": None}) for _ in range(repeats)]
    warm_job = {**job, "id": child.id, "raw": case_problem(study, child), "warm": cold[-1][1]["z"], "warm_from": seed.number}
    warm = [timed_job(solve_job, warm_job) for _ in range(repeats)]
    os.environ.pop(THREADS_ENV)
    result = warm[-1][1]
    out = {
        "cold_s": statistics.median(w for w, _ in cold),
        "cold_ipopt_s": statistics.median(r["record"]["wall_s"] for _, r in cold),
        "warm_s": statistics.median(w for w, _ in warm),
        "warm_ipopt_s": statistics.median(r["record"]["wall_s"] for _, r in warm),
        "job_bytes": len(pickle.dumps(warm_job)),
        "warm_start_bytes": len(pickle.dumps(warm_job["warm"])),
        "result_bytes": len(pickle.dumps(result)),
        "columns": len(result["record"]),
    }
    out["overhead_s"] = out["warm_s"] - out["warm_ipopt_s"]
    out["warm_vs_ipopt"] = out["warm_s"] / out["warm_ipopt_s"]
    print(
        f"  one case here: cold {out['cold_s']:.2f} s ({out['cold_ipopt_s']:.2f} s IPOPT), warm {out['warm_s']:.2f} s "
        f"({out['warm_ipopt_s']:.2f} s IPOPT); job {out['job_bytes']} B (warm start {out['warm_start_bytes']} B), result {out['result_bytes']} B"
    )
    return out


def timed_job(fn: Callable[[dict], Any], job: dict) -> tuple[float, Any]:
    t0 = time.perf_counter()
    result = fn(job)
    return time.perf_counter() - t0, result


# --------------------------------------------------------------------------- the scheduler's own cost
def echo(item: tuple[bytes, bytes]) -> bytes:
    """A no-op case: takes a job's bytes, returns a result's."""
    return item[1]


def scheduler_cost(kind: str, tasks: int, job_bytes: int, result_bytes: int) -> dict:
    """Per task: no-op tasks with payloads of a real job's and result's size through run_tree on
    two lanes, once the workers are up (their start timed apart)."""
    from crashnlp.engine.executors import make_executor
    from crashnlp.engine.schedule import map_all

    items = [(os.urandom(job_bytes), os.urandom(result_bytes))] * tasks
    t0 = time.perf_counter()
    executor = make_executor(kind, 2)
    list(map_all(executor, echo, items[:2]))  # both workers started
    started = time.perf_counter()
    list(map_all(executor, echo, items))
    done = time.perf_counter()
    executor.close()
    out = {"tasks": tasks, "start_s": started - t0, "per_task_ms": 1e3 * (done - started) / tasks}
    print(
        f"  scheduler, {kind}: workers up in {out['start_s']:.2f} s, then {out['per_task_ms']:.2f} ms per no-op case on 2 lanes"
    )
    return out


def store_cost(rows: list[dict], z_size: int, repeats: int = 50) -> float:
    """Seconds the main process spends storing one finished case (json row + npy vector)."""
    from crashnlp.studies.store import CaseStore

    row = dict(rows[0])
    with tempfile.TemporaryDirectory() as tmp:
        store = CaseStore(Path(tmp))
        z = np.random.default_rng(0).standard_normal(z_size)
        t0 = time.perf_counter()
        for i in range(repeats):
            store.save(f"case-{i:03d}", "key", row, z)
        return (time.perf_counter() - t0) / repeats


def setup_cost(folder: Path, side: int) -> dict:
    """The main process before any solve: read, plan and check a side x side study (run_study check)."""
    from crashnlp.studies.run import run_study

    pitch = [[None, f"{3 + 7 * i / (side - 1):.3f} deg"] for i in range(side)]
    k_front = [f"{40 + 70 * i / (side - 1):.2f} kN/m" for i in range(side)]
    study = write_study(folder, {"name": f"grid-{side}", "sweep": {PITCH: pitch, K_FRONT: k_front}, "mode": "grid"})
    t0 = time.perf_counter()
    run_study(study, folder / "never", check=True)
    wall = time.perf_counter() - t0
    print(f"  checking a {side} x {side} study before any solve: {wall:.1f} s ({1e3 * wall / side**2:.1f} ms a case)")
    return {"cases": side**2, "wall_s": wall, "per_case_ms": 1e3 * wall / side**2}


# --------------------------------------------------------------------------- 10,000 cases on a virtual clock
class VirtualLanes:
    """An executor on a virtual clock: a task takes cost[n]; the main process then spends
    `overhead` on it (storing it, starting the next) before anything else happens."""

    def __init__(self, lanes: int, cost: np.ndarray, overhead: float):
        self.lanes, self.cost, self.overhead = lanes, cost, overhead
        self.clock = 0.0
        self.events: list[tuple[float, int]] = []

    def submit(self, lane: int, fn: Callable[[Any], Any], item: int) -> None:
        heapq.heappush(self.events, (self.clock + self.cost[item], lane))

    def wait(self) -> tuple[int, Any]:
        t, lane = heapq.heappop(self.events)
        self.clock = max(self.clock, t) + self.overhead
        return lane, None


def projection(cold: list[float], warm: list[float], per_case: float, overhead: float, side: int = 100) -> list[dict]:
    """Makespan of a side x side grid on each of LANES workers: the real plan and scheduler, case
    costs drawn from the measured cold and warm ones (+ `per_case` outside IPOPT), the main
    process's `overhead` per case serial."""
    from crashnlp.engine.schedule import run_tree
    from crashnlp.studies.plan import corners, lattice, warm_start_plan

    shape = (side, side)
    rng = np.random.default_rng(0)
    out = []
    for label, seeds in (("corners", corners(shape)), ("max_depth 5", lattice(shape, 5)), ("max_depth 2", lattice(shape, 2))):
        parent, depth = warm_start_plan(shape, seeds)
        cost = np.array([rng.choice(cold if p is None else warm) + per_case for p in parent])
        tasks = dict(enumerate(parent))
        chain = max(_chain(n, tasks, cost) for n in tasks if depth[n] == max(depth))
        for lanes in LANES:
            executor = VirtualLanes(lanes, cost, overhead)
            for _ in run_tree(executor, echo, tasks, lambda n: n):
                pass
            ideal = max(cost.sum() / lanes, chain)
            out.append(
                {
                    "plan": label,
                    "seeds": len(seeds),
                    "depth": int(max(depth)),
                    "lanes": lanes,
                    "work_h": cost.sum() / 3600,
                    "chain_s": chain,
                    "makespan_h": executor.clock / 3600,
                    "efficiency": cost.sum() / (lanes * executor.clock),
                    "vs_bound": ideal / executor.clock,
                }
            )
    for r in out:
        print(
            f"  10,000 cases ({r['plan']}, {r['seeds']} cold) on {r['lanes']} workers: {r['makespan_h']:.2f} h, "
            f"efficiency {r['efficiency']:.2f}"
        )
    return out


def _chain(n: int, parent: dict[int, int | None], cost: np.ndarray) -> float:
    total = 0.0
    while n is not None:
        total, n = total + cost[n], parent[n]
    return total


# --------------------------------------------------------------------------- the section
def run(quick: bool = False) -> dict:
    repeats = 1 if quick else 3
    with tempfile.TemporaryDirectory(prefix="bench-study-spec-") as tmp:
        folder = Path(tmp)
        small = write_study(folder, QUICK_STUDY) if quick else PITCH_BOUND
        for study in (small, GRID):  # every shape's NLP library compiled before anything is timed
            run_once(study, 2)
        wait_for_compiles(cache_dir())
        variants = {"1 worker": {"workers": 1}, "2 workers": {"workers": 2}}
        serial = {f"{k}, serial maps": {**v, "serial_maps": True} for k, v in variants.items()}
        pitch, _ = interleaved(small, {**variants, **serial}, 1)
        dask = {"dask LocalCluster, 2 workers": {"workers": 2, "executor": "dask"}}
        grid, grid_rows = interleaved(
            GRID, {**variants, "1 worker, serial maps": serial["1 worker, serial maps"], **dask}, repeats
        )
        big, rows = interleaved(write_study(folder, GRID_64), {**variants, **dask}, 1 if quick else 2)
        one = case_cost(repeats)
        tasks = 50 if quick else 400
        sched = {kind: scheduler_cost(kind, tasks, one["job_bytes"], one["result_bytes"]) for kind in ("local", "dask")}
        store_s = store_cost(grid_rows, one["warm_start_bytes"] // 8)
        setup = setup_cost(folder, 30 if quick else 100)
    cold = [float(r["wall_s"]) for r in rows + grid_rows if not r["warm_start"]]
    warm = [float(r["wall_s"]) for r in rows + grid_rows if r["warm_start"]]
    overhead = store_s + 1e-3 * sched["local"]["per_task_ms"]
    print(f"  main process per case: storing {1e3 * store_s:.1f} ms, scheduling {sched['local']['per_task_ms']:.2f} ms")
    return {
        "pitch_bound": pitch,
        "grid_16": grid,
        "grid_64": big,
        "grid_64_rows": rows,  # the 1-worker table (bench/convergence.py reads its statuses and iterations)
        "speedup_16": speedups(grid),
        "speedup_64": speedups(big),
        "speedup_pitch_bound": speedups(pitch),
        "same_table_16": all(r["same_table"] for r in grid.values()),
        "same_table_64": all(r["same_table"] for r in big.values()),
        "case": one,
        "scheduler": sched,
        "store_ms": 1e3 * store_s,
        "setup": setup,
        "cold_ipopt_s": {"median": statistics.median(cold), "max": max(cold), "n": len(cold)},
        "warm_ipopt_s": {"median": statistics.median(warm), "max": max(warm), "n": len(warm)},
        "projection": projection(cold, warm, one["overhead_s"], overhead),
    }
