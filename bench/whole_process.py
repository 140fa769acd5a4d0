"""Whole-process times: what a user waits for, not only the solve.

A user's own new problem, as a user gets it: `crashnlp init` on the Camry's EV5 file, then
`crashnlp identify --no-figures` three times from an empty cache with no crashnlp variable
set: run 1 (the model's functions compiled, the NLP solved in CasADi's virtual machine while
its library compiles, finished after the command at nice 19), run 2 straight after it (the
compile, if still going, beside it), run 3 once that compile has finished; each as a ratio to
the floor below, measured after it.

`crashnlp identify problems/pickup-56kph.yaml` as a process: the first run on a fresh
cache (the same as a new problem's run 1), then, once that compile has finished, the
median of warm runs with and without figures, the commands taking turns so that the
drift of a shared machine's speed slows them alike, each with its peak resident memory
(figures are drawn by a forked process, counted in the peak: the kernel reports the
largest of a process and its waited-for children); against the scipy baseline fit
(bench/baseline.py, the same model) run as a process of its own. `crashnlp simulate`,
and a Python that only imports numpy and CasADi (the floor of any such command),
beside them.

The floor runs with the command's footing: one OpenBLAS thread (OPENBLAS_NUM_THREADS=1, as
the command sets unless the user set a number, crashnlp/__main__.py; with a thread per core
numpy's import varied 0.17 to 0.37 s from run to run), and it is sampled after every run of
every command, so that the ratios rest on floors measured in the same minutes.

crashnlp's bytecode is written first, as `pip install` writes a package's and Python
its own modules' on a first import: where PYTHONDONTWRITEBYTECODE is set (as on the
benchmark machine) and crashnlp is installed editable, every process would otherwise
compile crashnlp's source again, 0.1 s of each run.
"""

from __future__ import annotations

import compileall
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.common import PICKUP_56, ROOT, wait_for_compiles
from crashnlp.__main__ import BLAS_THREADS_ENV
from crashnlp.numerics.compile_job import KEEP_ENV
from crashnlp.numerics.compiled import SWITCH_ENV

CLI = str(Path(sys.executable).with_name("crashnlp"))
BASELINE = "from bench.identification import run_baseline; run_baseline(None, 100)"
FLOOR = [sys.executable, "-c", "import numpy, casadi"]  # what any such command imports first
FLOOR_ENV = {**os.environ, BLAS_THREADS_ENV: os.environ.get(BLAS_THREADS_ENV, "1")}  # the command's BLAS threads
FLOOR_KEY = "python_numpy_casadi"
FLOOR_SAMPLES = 3  # floors after each run of a new problem
CAMRY_EV5 = ROOT / "problems/data/nhtsa-10146/v10146.EV5"


# Starts the command from a small process: a process forked from this one would carry this
# one's resident memory as its own peak (the kernel keeps the high-water mark across exec).
SPAWN = """
import os, sys, time
t0 = time.perf_counter()
pid = os.fork()
if pid == 0:
    os.execvp(sys.argv[1], sys.argv[1:])
_, status, usage = os.wait4(pid, 0)
print(time.perf_counter() - t0, usage.ru_maxrss, os.waitstatus_to_exitcode(status), usage.ru_utime + usage.ru_stime)
"""


def timed_process(command: list[str], env: dict[str, str] | None = None) -> tuple[float, float, int, float]:
    """Wall time (s), peak resident memory (MB; the largest of the process and the children it
    waited for, such as the figure process), exit status and CPU time (s, user + system, of the
    process and those children; not of a background compile, which runs in a session of its own)
    of one process. On a loaded machine the CPU time is what a ratio can rest on: the wall time
    grows with the other processes' share of the cores."""
    spawn = [sys.executable, "-S", "-c", SPAWN, *command]
    proc = subprocess.run(spawn, cwd=ROOT, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True)
    wall, rss_kb, status, cpu = proc.stdout.split()[-4:]
    return float(wall), float(rss_kb) / 1024, int(status), float(cpu)


def median_of(command: list[str], repeats: int, env: dict[str, str] | None = None) -> dict:
    return taking_turns({"run": (command, env)}, repeats)["run"]


def taking_turns(commands: dict[str, tuple[list[str], dict[str, str] | None]], repeats: int, floors: int = 0) -> dict[str, dict]:
    """Median wall and CPU time, all wall times, peak memory and worst exit status of each command, the
    commands run in turns (one of each, `repeats` times) so that a machine whose speed drifts
    (a shared one) slows them alike; with `floors`, that many runs of the floor after each
    command's, gathered under FLOOR_KEY."""
    runs: dict[str, list] = {name: [] for name in commands}
    if floors:
        runs[FLOOR_KEY] = []
    for _ in range(repeats):
        for name, (command, env) in commands.items():
            runs[name].append(timed_process(command, env))
            runs.get(FLOOR_KEY, []).extend(timed_process(FLOOR, FLOOR_ENV) for _ in range(floors))
    return {
        name: {
            "wall_s": statistics.median(r[0] for r in rs),
            "walls_s": [r[0] for r in rs],
            "cpu_s": statistics.median(r[3] for r in rs),
            "cpus_s": [r[3] for r in rs],
            "peak_rss_mb": max(r[1] for r in rs),
            "exit": max(r[2] for r in rs),
        }
        for name, rs in runs.items()
    }


def as_a_user(cache: Path) -> dict[str, str]:
    """The environment of a user who has set no crashnlp variable, with a cache of `cache`."""
    env = {k: v for k, v in os.environ.items() if k not in (KEEP_ENV, SWITCH_ENV, "NUMBA_CACHE_DIR")}
    return {**env, "CRASHNLP_CACHE": str(cache)}


def new_problem(folder: Path) -> dict:
    """A problem written by `crashnlp init`, identified three times from an empty cache (see the
    module), each run followed by FLOOR_SAMPLES floors; ratios to the median of those floors."""
    problem = folder / "camry.yaml"
    subprocess.run([CLI, "init", str(CAMRY_EV5), "--out", str(problem)], check=True, capture_output=True)
    env = as_a_user(folder / "cache")
    identify = [CLI, "identify", str(problem), "--no-figures", "--out", str(folder / "camry")]
    floors: dict[str, list[float]] = {"wall_s": [], "cpu_s": []}

    def identified() -> dict:
        turn = taking_turns({"run": (identify, env)}, 1, floors=FLOOR_SAMPLES)
        floors["wall_s"] += turn[FLOOR_KEY]["walls_s"]
        floors["cpu_s"] += turn[FLOOR_KEY]["cpus_s"]
        return turn["run"]

    runs = [identified(), identified()]
    compile_s = wait_for_compiles(folder / "cache")
    runs.append(identified())
    floor = {k: statistics.median(v) for k, v in floors.items()}
    out = {
        f"run_{n + 1}": {**r, "vs_floor": r["wall_s"] / floor["wall_s"], "cpu_vs_floor": r["cpu_s"] / floor["cpu_s"]}
        for n, r in enumerate(runs)
    }
    out |= {"floor_s": floor["wall_s"], "floor_cpu_s": floor["cpu_s"], "floors_s": floors["wall_s"]}
    out["compile_after_run_2_s"] = compile_s
    for n in range(1, 4):
        r = out[f"run_{n}"]
        print(
            f"  new problem (init), run {n}: {r['wall_s']:.2f} s, {r['vs_floor']:.1f}x the floor "
            f"(CPU {r['cpu_s']:.2f} s, {r['cpu_vs_floor']:.1f}x), exit {r['exit']}"
        )
    return out


def run(quick: bool = False) -> dict:
    repeats = 1 if quick else 5
    compileall.compile_dir(ROOT / "crashnlp", quiet=1)
    with tempfile.TemporaryDirectory() as tmp:
        out = {"command": "crashnlp identify problems/pickup-56kph.yaml", "repeats": repeats}
        out["new_problem"] = new_problem(Path(tmp))
        identify = [CLI, "identify", str(PICKUP_56), "--out", str(Path(tmp) / "out")]
        # the first run's background compile finishes after it (the default), for the second run
        fresh_env = as_a_user(Path(tmp) / "pickup-cache")
        out["first_run_fresh_cache"] = median_of(identify, 1, fresh_env)
        out["background_compile_s"] = wait_for_compiles(Path(tmp) / "pickup-cache")
        out["second_run_fresh_cache"] = median_of(identify, 1, fresh_env)
        simulate = [CLI, "simulate", str(PICKUP_56), "--out", str(Path(tmp) / "sim")]
        baseline_env = {**os.environ, "PYTHONPATH": str(ROOT)}
        turns = {
            "warm": (identify, fresh_env),
            "warm_no_figures": ([*identify, "--no-figures"], fresh_env),
            "simulate_warm": (simulate, fresh_env),
            "simulate_no_figures": ([*simulate, "--no-figures"], fresh_env),
            "scipy_baseline": ([sys.executable, "-c", BASELINE], baseline_env),
        }
        out.update(taking_turns(turns, repeats, floors=1))
        # what the last runs left compiling at nice 19 ends here, not beside the next section's timings
        for cache in (Path(tmp) / "cache", Path(tmp) / "pickup-cache"):
            wait_for_compiles(cache)
    out["speedup"] = out["scipy_baseline"]["wall_s"] / out["warm"]["wall_s"]
    out["speedup_no_figures"] = out["scipy_baseline"]["wall_s"] / out["warm_no_figures"]["wall_s"]
    floor = out[FLOOR_KEY]
    out["vs_floor"] = {key: out[key]["wall_s"] / floor["wall_s"] for key in ("warm", "warm_no_figures")}
    out["cpu_vs_floor"] = {key: out[key]["cpu_s"] / floor["cpu_s"] for key in ("warm", "warm_no_figures")}
    for key in ("first_run_fresh_cache", "second_run_fresh_cache", *turns, FLOOR_KEY):
        r = out[key]
        ratio = f", {out['vs_floor'][key]:.1f}x the floor (CPU {out['cpu_vs_floor'][key]:.1f}x)" if key in out["vs_floor"] else ""
        print(f"  {key}: {r['wall_s']:.2f} s (CPU {r['cpu_s']:.2f} s){ratio}, peak {r['peak_rss_mb']:.0f} MB, exit {r['exit']}")
    return out
