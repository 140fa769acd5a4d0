"""Whole-process times: what a user waits for, not only the solve.

`crashnlp identify problems/pickup-56kph.yaml` as a process: the first run on a fresh
cache (the model's functions compiled, the NLP solved in CasADi's virtual machine while
its library compiles in the background), then, once that compile has finished, the
median of warm runs with and without figures, the commands taking turns so that the
drift of a shared machine's speed slows them alike, each with its peak resident memory
(figures are drawn by a forked process, counted in the peak: the kernel reports the
largest of a process and its waited-for children); against the scipy baseline fit
(bench/baseline.py, the same model) run as a process of its own. `crashnlp simulate`,
and a Python that only imports numpy and CasADi (the floor of any such command),
beside them.

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

CLI = str(Path(sys.executable).with_name("crashnlp"))
BASELINE = "from bench.identification import run_baseline; run_baseline(None, 100)"


# Starts the command from a small process: a process forked from this one would carry this
# one's resident memory as its own peak (the kernel keeps the high-water mark across exec).
SPAWN = """
import os, sys, time
t0 = time.perf_counter()
pid = os.fork()
if pid == 0:
    os.execvp(sys.argv[1], sys.argv[1:])
_, status, usage = os.wait4(pid, 0)
print(time.perf_counter() - t0, usage.ru_maxrss, os.waitstatus_to_exitcode(status))
"""


def timed_process(command: list[str], env: dict[str, str] | None = None) -> tuple[float, float, int]:
    """Wall time (s), peak resident memory (MB; the largest of the process and the children it
    waited for, such as the figure process) and exit status of one process."""
    spawn = [sys.executable, "-S", "-c", SPAWN, *command]
    proc = subprocess.run(spawn, cwd=ROOT, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True)
    wall, rss_kb, status = proc.stdout.split()[-3:]
    return float(wall), float(rss_kb) / 1024, int(status)


def median_of(command: list[str], repeats: int, env: dict[str, str] | None = None) -> dict:
    return taking_turns({"run": (command, env)}, repeats)["run"]


def taking_turns(commands: dict[str, tuple[list[str], dict[str, str] | None]], repeats: int) -> dict[str, dict]:
    """Median wall time, all wall times, peak memory and worst exit status of each command, the
    commands run in turns (one of each, `repeats` times) so that a machine whose speed drifts
    (a shared one) slows them alike."""
    runs: dict[str, list] = {name: [] for name in commands}
    for _ in range(repeats):
        for name, (command, env) in commands.items():
            runs[name].append(timed_process(command, env))
    return {
        name: {
            "wall_s": statistics.median(r[0] for r in rs),
            "walls_s": [r[0] for r in rs],
            "peak_rss_mb": max(r[1] for r in rs),
            "exit": max(r[2] for r in rs),
        }
        for name, rs in runs.items()
    }


def run(quick: bool = False) -> dict:
    repeats = 1 if quick else 5
    compileall.compile_dir(ROOT / "crashnlp", quiet=1)
    with tempfile.TemporaryDirectory() as tmp:
        identify = [CLI, "identify", str(PICKUP_56), "--out", str(Path(tmp) / "out")]
        # the first run's background compile is to finish after it, for the second run
        fresh_env = {**os.environ, "CRASHNLP_CACHE": str(Path(tmp) / "cache"), "CRASHNLP_KEEP_COMPILING": "1"}
        fresh_env.pop("NUMBA_CACHE_DIR", None)
        out = {"command": "crashnlp identify problems/pickup-56kph.yaml", "repeats": repeats}
        out["first_run_fresh_cache"] = median_of(identify, 1, fresh_env)
        out["background_compile_s"] = wait_for_compiles(Path(tmp) / "cache")
        out["second_run_fresh_cache"] = median_of(identify, 1, fresh_env)
        simulate = [CLI, "simulate", str(PICKUP_56), "--out", str(Path(tmp) / "sim")]
        baseline_env = {**os.environ, "PYTHONPATH": str(ROOT)}
        turns = {
            "warm": (identify, fresh_env),
            "warm_no_figures": ([*identify, "--no-figures"], fresh_env),
            "simulate_warm": (simulate, fresh_env),
            "simulate_no_figures": ([*simulate, "--no-figures"], fresh_env),
            "python_numpy_casadi": ([sys.executable, "-c", "import numpy, casadi"], None),
            "scipy_baseline": ([sys.executable, "-c", BASELINE], baseline_env),
        }
        out.update(taking_turns(turns, repeats))
    out["speedup"] = out["scipy_baseline"]["wall_s"] / out["warm"]["wall_s"]
    out["speedup_no_figures"] = out["scipy_baseline"]["wall_s"] / out["warm_no_figures"]["wall_s"]
    for key in ("first_run_fresh_cache", "second_run_fresh_cache", *turns):
        r = out[key]
        print(f"  {key}: {r['wall_s']:.2f} s, peak {r['peak_rss_mb']:.0f} MB, exit {r['exit']}")
    return out
