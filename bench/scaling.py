"""Scaling: identification time against the number of intervals and of tests, both transcriptions.

Every solve is capped at MAX_ITER IPOPT iterations (800 intervals can be slow);
a capped solve is recorded with its status. Times are end-to-end identify()
calls with the compiled NLP (the first run, which compiles it, recorded beside), with
IPOPT's own solve time beside. The log-log slope of time against
intervals over the converged solves says how the cost grows (1 = linear).
"""

from __future__ import annotations

import numpy as np

from bench.common import PICKUP_40, PICKUP_56, RESULTS, TRANSCRIPTIONS, load, timed
from crashnlp.case.case import Case
from crashnlp.optimize.identify import identify
from crashnlp.problem.schema import Problem

MAX_ITER = 300
INTERVALS, QUICK_INTERVALS = (50, 100, 200, 400, 800), (25, 50)
TESTS, QUICK_TESTS = (1, 2, 4), (1, 2)
TESTS_INTERVALS, QUICK_TESTS_INTERVALS = 200, 50


def with_tests(problem: Problem, count: int) -> Problem:
    """pickup-56kph with `count` tests: 56 and 40 km/h, then copies of both under new names."""
    pair = [problem.tests[0], load(PICKUP_40).tests[0]]
    tests = [
        pair[i % 2].model_copy(update={"name": f"{pair[i % 2].name}{'' if i < 2 else '-' + str(i // 2)}"}) for i in range(count)
    ]
    return problem.model_copy(update={"tests": tests})


def measure(method: str, intervals: int, tests: int) -> dict:
    """One capped identification with the compiled NLP (its library compiled first, untimed
    beyond `first_run_s`)."""
    first, _ = timed(
        lambda: identify(Case(with_tests(load(PICKUP_56, method, intervals, MAX_ITER, "now"), tests)), progress=None)
    )
    case = Case(with_tests(load(PICKUP_56, method, intervals, MAX_ITER), tests))
    wall, solution = timed(lambda: identify(case, progress=None))
    r = solution.result
    return {
        "method": method,
        "intervals": intervals,
        "tests": tests,
        "compiled": r.compiled,
        "first_run_s": first,
        "wall_s": wall,
        "ipopt_s": r.wall_s,
        "iterations": r.iterations,
        "status": solution.status,
        "ipopt_status": r.return_status,
        "capped": r.iterations >= MAX_ITER,
    }


def slope(rows: list[dict], key: str) -> float:
    """Least-squares slope of log(key) against log(intervals)."""
    x = np.log([r["intervals"] for r in rows])
    return float(np.polyfit(x, np.log([r[key] for r in rows]), 1)[0])


def slopes(rows: list[dict]) -> dict:
    """Slopes over the converged solves (a capped solve's time says nothing of the method):
    end-to-end, IPOPT, IPOPT per iteration, and the steepest step between neighbours."""
    ok = [dict(r, per_iteration=r["ipopt_s"] / max(r["iterations"], 1)) for r in rows if r["status"] == "ok"]
    if len(ok) < 2:
        nan = float("nan")
        return {"wall_s": nan, "ipopt_s": nan, "ipopt_per_iteration": nan, "steepest_step": nan, "converged_runs": len(ok)}
    steps = [np.log(b["wall_s"] / a["wall_s"]) / np.log(b["intervals"] / a["intervals"]) for a, b in zip(ok, ok[1:])]
    return {
        "wall_s": slope(ok, "wall_s"),
        "ipopt_s": slope(ok, "ipopt_s"),
        "ipopt_per_iteration": slope(ok, "per_iteration"),
        "steepest_step": float(max(steps)),
        "converged_runs": len(ok),
    }


def figure(out: dict, path) -> None:
    """Time against intervals (log-log) and against tests, both transcriptions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for method in TRANSCRIPTIONS:
        rows = [r for r in out["intervals"] if r["method"] == method and r["status"] == "ok"]
        n = [r["intervals"] for r in rows]
        line = a.loglog(n, [r["wall_s"] for r in rows], "o-", label=f"{method} (slope {out['slopes'][method]['wall_s']:.2f})")[0]
        a.loglog(n, [r["ipopt_s"] for r in rows], "x--", color=line.get_color(), label=f"{method}, IPOPT only")
        failed = [r for r in out["intervals"] if r["method"] == method and r["status"] != "ok"]
        if failed:
            a.loglog(
                [r["intervals"] for r in failed],
                [r["wall_s"] for r in failed],
                "o",
                mfc="none",
                color=line.get_color(),
                label=f"{method}, not converged",
            )
        rows = [r for r in out["tests"] if r["method"] == method]
        b.plot([r["tests"] for r in rows], [r["wall_s"] for r in rows], "o-", label=method)
    n = np.array(out["intervals_grid"], dtype=float)
    ref = out["intervals"][0]["wall_s"] * n / n[0]
    a.loglog(n, ref, ":", color="grey", label="linear")
    a.set(xlabel="intervals", ylabel="identification time (s)", title="pickup-56kph, 1 test")
    a.set_xticks(out["intervals_grid"], [str(k) for k in out["intervals_grid"]])
    a.minorticks_off()
    b.set(xlabel="tests", ylabel="identification time (s)", title=f"{out['tests_intervals']} intervals per test")
    for ax in (a, b):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(quick: bool = False) -> dict:
    """The interval sweep, the test sweep, slopes and the figure."""
    grid = QUICK_INTERVALS if quick else INTERVALS
    per_test = QUICK_TESTS_INTERVALS if quick else TESTS_INTERVALS
    out = {"max_iter": MAX_ITER, "intervals_grid": list(grid), "tests_intervals": per_test, "intervals": [], "tests": []}
    for method in TRANSCRIPTIONS:
        for n in grid:
            out["intervals"].append(row := measure(method, n, 1))
            print(
                f"  {method:18s} {n:4d} intervals: {row['wall_s']:6.2f} s ({row['ipopt_s']:.2f} s IPOPT, {row['iterations']} it) {row['status']}"
            )
        for k in QUICK_TESTS if quick else TESTS:
            out["tests"].append(row := measure(method, per_test, k))
            print(
                f"  {method:18s} {k} tests x {per_test}: {row['wall_s']:6.2f} s ({row['ipopt_s']:.2f} s IPOPT, {row['iterations']} it) {row['status']}"
            )
    out["slopes"] = {m: slopes([r for r in out["intervals"] if r["method"] == m]) for m in TRANSCRIPTIONS}
    for m, s in out["slopes"].items():
        print(
            f"  {m}: log-log slope of time vs intervals {s['wall_s']:.2f} end-to-end, {s['ipopt_s']:.2f} IPOPT only, "
            f"{s['ipopt_per_iteration']:.2f} per IPOPT iteration; steepest step {s['steepest_step']:.2f}"
        )
    path = RESULTS / ("bench-quick-scaling.png" if quick else "bench-scaling.png")
    figure(out, path)
    out["figure"] = str(path.relative_to(RESULTS.parent))
    return out
