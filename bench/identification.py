"""Identification: crashnlp (both transcriptions) against the scipy single-shooting baseline.

Times are end-to-end (building the NLP, the initial-guess simulation, IPOPT and
the covariance for crashnlp; the whole least_squares call for the baseline);
IPOPT's own solve time is recorded beside. Both final parameter sets are judged
by the common evaluator of bench.common.
"""

from __future__ import annotations

import numpy as np

from bench import baseline
from bench.common import PICKUP_56, TRANSCRIPTIONS, Target, fit_targets, judge_fit, load_case, timed
from crashnlp.optimize.identify import identify


def check_targets(targets: list[Target], residuals) -> float:
    """Largest difference between the benchmark's resampled data and the NLP's own (must be ~0)."""
    return max(float(np.max(np.abs(t.data - r.data))) for t, r in zip(targets, residuals, strict=True))


def run_crashnlp(method: str, intervals: int | None, compile: str = "auto", repeats: int = 3, from_data: bool = False) -> dict:
    """One identification of pickup-56kph with `method` (best of `repeats`), judged by the common
    evaluator; `compile` as solver.compile (auto: the compiled NLP once its library is cached);
    `from_data` as bench.common.load."""
    case = load_case(PICKUP_56, method, intervals, compile=compile, from_data=from_data)
    targets = fit_targets(case)
    wall, solution = timed(lambda: identify(case, progress=None), repeats)
    r = solution.result
    return {
        "method": method,
        "intervals": case.problem.transcription.intervals,
        "status": solution.status,
        "compiled": r.compiled,
        "wall_s": wall,
        "ipopt_s": r.wall_s,
        "build_s": r.build_s,
        "iterations": r.iterations,
        "ms_per_iteration": 1e3 * r.wall_s / max(r.iterations, 1),
        "profile": r.profile,
        "nlp_objective": r.objective,
        "target_mismatch": check_targets(targets, solution.residuals),
        "parameters": solution.parameters,
        **judge_fit(case, solution.full_parameters(), targets),
    }


def run_baseline(intervals: int | None, max_nfev: int, from_data: bool = False) -> dict:
    """The scipy baseline on the same case, judged by the common evaluator."""
    case = load_case(PICKUP_56, intervals=intervals, from_data=from_data)
    targets = fit_targets(case)
    res = baseline.fit(case, targets, max_nfev)
    return {
        "method": f"scipy least_squares + solve_ivp({baseline.METHOD}, rtol {baseline.RTOL:g}, max_step {baseline.MAX_STEP:g}), FD step {baseline.DIFF_STEP:g}",
        "intervals": case.problem.transcription.intervals,
        "converged": res.converged,
        "status": res.status,
        "message": res.message,
        "max_nfev": max_nfev,
        "wall_s": res.wall_s,
        "iterations": res.iterations,
        "simulations": res.simulations,
        "own_objective": res.cost,
        "parameters": res.parameters,
        **judge_fit(case, res.p, targets),
    }


def run(quick: bool = False) -> dict:
    """crashnlp with each transcription, the baseline, and the ratios."""
    intervals = 50 if quick else None
    out: dict = {"problem": PICKUP_56.name, "crashnlp": {}, "virtual_machine": {}}
    for method in TRANSCRIPTIONS:
        first = run_crashnlp(method, intervals, "now", repeats=1)  # compiles the library when the cache has none
        out["crashnlp"][method] = res = run_crashnlp(method, intervals)
        out["virtual_machine"][method] = vm = run_crashnlp(method, intervals, "never")
        out["crashnlp"][method]["first_run_s"] = first["wall_s"]
        for label, r in (("compiled", res), ("virtual machine", vm)):
            print(
                f"  crashnlp {method} ({label}): {r['status']}, {r['wall_s']:.2f} s ({r['ipopt_s']:.2f} s IPOPT, "
                f"{r['iterations']} it, {r['ms_per_iteration']:.1f} ms/it), objective {r['objective']:.5g}"
            )
    out["baseline"] = b = run_baseline(intervals, 4 if quick else 100)
    _print_baseline(b)
    out["from_data"] = run_from_data(intervals, quick)
    out["ratios"] = {
        m: {
            "speedup": b["wall_s"] / r["wall_s"],
            "speedup_ipopt_only": b["wall_s"] / r["ipopt_s"],
            "objective_ratio": r["objective"] / b["objective"],
        }
        for m, r in out["crashnlp"].items()
    }
    for m, q in out["ratios"].items():
        print(
            f"  {m}: {q['speedup']:.1f}x faster end-to-end ({q['speedup_ipopt_only']:.1f}x on IPOPT time), "
            f"objective ratio {q['objective_ratio']:.4f}"
        )
    return out


def run_from_data(intervals: int | None, quick: bool) -> dict:
    """Both fits again from the measured force-crush curve (the spring values left to
    crashnlp.case.completion, as a problem without a guess gets them): from the problem's flat guess the
    baseline stops at a fit 8 times worse than crashnlp's; from here it goes on to fit."""
    method = TRANSCRIPTIONS[0]
    r = run_crashnlp(method, intervals, from_data=True)
    b = run_baseline(intervals, 4 if quick else 100, from_data=True)
    print(f"  from the data: crashnlp {method} {r['wall_s']:.2f} s, {r['iterations']} it, objective {r['objective']:.5g}")
    _print_baseline(b)
    return {"method": method, "crashnlp": r, "baseline": b, "speedup": b["wall_s"] / r["wall_s"]}


def _print_baseline(b: dict) -> None:
    print(
        f"  baseline: converged {b['converged']} ({b['message']}), {b['wall_s']:.1f} s, {b['iterations']} it, "
        f"{b['simulations']} simulations, objective {b['objective']:.5g}"
    )
