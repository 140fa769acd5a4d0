"""The watch's rules on corpus fits: thresholds set on one seed, checked on another unseen when they were set.

A fit's solve (crashnlp.optimize.solve) stops or hands over where one of its rules fires:
Gauss-Newton's slow tail (Newton finishes), a cycle (the integration is refined, or the cycle
settled), a wander (warm starts only), a steady objective (IPOPT's acceptable level,
crashnlp.optimize.options.STEADY_OPTIONS), a settle's cycle that does not settle (the exact
Hessian finishes). The rules' thresholds and reasons are in
crashnlp/optimize/watch.py and options.py. Here each rule is judged on the corpus vehicles of two
seeds (SEEDS): the set seed, on whose vehicles the thresholds were argued (the robustness corpus:
v10's tail, v13's and v17's cold starts, v17's steady stop), and the check seed, never fitted
before this section. Per vehicle (COUNT a seed) three fits from minimal problems: its own test
alone (the robustness corpus's fit), and 40 + 56 and 40 + 64 km/h jointly (the cross-speed
benchmark's, where cycles were seen). Each fit is solved twice:

- watched: as crashnlp fits it, every IPOPT run recorded with what stopped it;
- left alone: Gauss-Newton only, no watch, IPOPT's own termination (LEFT_ALONE), at most
  LEFT_ALONE["max_iter"] iterations, at the same integration.

Per rule: how often it fires; false alarms, where it fired on a fit that did not need it: a tail
whose Newton did not finish the same fit (crashnlp.optimize.solve.finishes), a cycle or a wander
on a fit that converged left alone, a steady stop more than STEADY_REACH standard errors from
where the fit left alone converged, an unsettled cycle whose exact Hessian did not converge;
misses: a run that reached its iteration limit with no rule firing.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from bench.corpus import Vehicle, measured, random_vehicle, simulate, write_csv
from bench.cross_speed import fit_problem
from bench.robustness import minimal_problem
from crashnlp.case.case import Case
from crashnlp.optimize import solve as strategy
from crashnlp.optimize.identify import Solution, identify
from crashnlp.optimize.options import SETTLE_OPTIONS
from crashnlp.optimize.solved import SolveResult
from crashnlp.problem import load_problem
from crashnlp.problem.schema import Solver

SEEDS = {"set": 2024, "check": 2027}  # the check seed's vehicles were never fitted before this section
COUNT = 10  # vehicles a seed
JOINTS = ((40.0, 56.0), (40.0, 64.0))  # the cross-speed benchmark's two splits
RULES = ("tail", "cycle", "wander", "steady", "settle", "unsettled")
# IPOPT's own acceptable termination (its defaults), in place of the steady stop; Gauss-Newton's budget in `auto`
LEFT_ALONE = {
    "max_iter": strategy.AUTO_GAUSS_NEWTON_ITER,
    "acceptable_tol": 1e-6,
    "acceptable_iter": 15,
    "acceptable_obj_change_tol": 1e20,
    "acceptable_constr_viol_tol": 1e-2,
}
STEADY_REACH = 1e-3  # standard errors: a steady stop this close to the fit left alone stopped where going on gains nothing
CONVERGED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


@dataclass
class Run:
    """One IPOPT run of a watched fit: what it was, what stopped it."""

    kind: str  # gauss-newton, newton (the exact Hessian), settle
    status: str
    iterations: int
    fired: str | None  # the rule that stopped it (RULES), None where IPOPT's own test did
    result: SolveResult


@contextmanager
def recorded() -> Iterator[list[Run]]:
    """Every IPOPT run the fit strategy makes inside the block, in order (crashnlp.optimize.solve's
    runs, each recorded as it returns)."""
    runs: list[Run] = []
    inner = strategy._solve

    def recording(nlp, spec: Solver, *args, **kwargs) -> SolveResult:
        result = inner(nlp, spec, *args, **kwargs)
        runs.append(_run(spec, result))
        return result

    strategy._solve = recording
    try:
        yield runs
    finally:
        strategy._solve = inner


def _run(spec: Solver, result: SolveResult) -> Run:
    settle = all(spec.ipopt.get(k) == v for k, v in SETTLE_OPTIONS.items())
    kind = "settle" if settle else "newton" if spec.hessian == "exact" else "gauss-newton"
    fired = "tail" if result.tail is not None else result.stopped
    if fired is None and not settle and result.return_status == "Solved_To_Acceptable_Level":
        fired = "steady"
    if settle:
        fired = "unsettled" if result.stopped == "unsettled" else "settle"
    return Run(kind, result.return_status, result.iterations, fired, result)


def problems(v: Vehicle, folder: Path) -> dict[str, tuple[Path, Path]]:
    """The vehicle's fits, its own test alone and each of JOINTS jointly, each as (watched, left alone)."""
    write_csv(folder / f"{v.name}.csv", measured(v, simulate(v)))
    fits: dict[str, list[Path]] = {}
    for label, solver in (("watched", None), ("left-alone", {"hessian": "gauss-newton", "ipopt": LEFT_ALONE})):
        raw = minimal_problem(v, f"{v.name}.csv")
        path = folder / f"{v.name}-{label}.yaml"
        path.write_text(yaml.safe_dump({**raw, "solver": solver} if solver else raw, sort_keys=False))
        fits.setdefault("single", []).append(path)
        for speeds in JOINTS:
            (joint := folder / f"{label}-{speeds[1]:.0f}").mkdir()
            fits.setdefault(" + ".join(f"{k:g}" for k in speeds), []).append(fit_problem(v, speeds, joint, solver=solver))
    return {fit: (watched, alone) for fit, (watched, alone) in fits.items()}


def _identify(path: Path) -> tuple[Solution, float]:
    t0 = time.perf_counter()
    solution = identify(Case(load_problem(path)), progress=None)
    return solution, time.perf_counter() - t0


def judge(watched_path: Path, alone_path: Path) -> dict:
    """One fit watched and left alone: each watched run's rule, and each firing judged (the module's rules)."""
    with recorded() as runs:
        watched, wall = _identify(watched_path)
    alone, alone_wall = _identify(alone_path)
    converged_alone = alone.result is not None and alone.result.return_status in CONVERGED
    fires = [_judged(runs, i, converged_alone, watched, alone) for i, r in enumerate(runs) if r.fired]
    return {
        "status": watched.status,
        "iterations": sum(r.iterations for r in runs),
        "wall_s": wall,
        "runs": [{"kind": r.kind, "status": r.status, "iterations": r.iterations, "fired": r.fired} for r in runs],
        "fires": fires,
        "misses": sum(r.status == "Maximum_Iterations_Exceeded" and r.fired is None for r in runs),
        "alone_status": alone.result.return_status if alone.result else alone.status,
        "alone_iterations": alone.result.iterations if alone.result else 0,
        "alone_wall_s": alone_wall,
        "alone_converged": converged_alone,
        "apart_std": _apart(watched, alone),
    }


def _judged(runs: list[Run], i: int, converged_alone: bool, watched: Solution, alone: Solution) -> dict:
    """Run i's firing and whether it was a false alarm (the module's rules)."""
    run = runs[i]
    if run.fired == "tail":
        following = runs[i + 1] if i + 1 < len(runs) else None
        false = following is None or following.kind != "newton" or not strategy.finishes(run.result, following.result)
    elif run.fired in ("cycle", "wander"):
        false = converged_alone
    elif run.fired == "unsettled":
        following = runs[i + 1] if i + 1 < len(runs) else None
        false = following is None or following.kind != "newton" or following.status not in CONVERGED
    elif run.fired == "steady":
        apart = _apart(watched, alone)
        false = converged_alone and apart is not None and apart > STEADY_REACH
    else:  # a settle ends a cycle already judged
        false = False
    return {"rule": run.fired, "at": sum(r.iterations for r in runs[: i + 1]), "false_alarm": bool(false)}


def _apart(watched: Solution, alone: Solution) -> float | None:
    """How far the fit left alone ended from the watched fit: the largest parameter difference in the
    watched fit's standard errors (None where either did not converge)."""
    if not (watched.ok and alone.ok) or watched.std_errors is None or watched.theta.shape != alone.theta.shape:
        return None
    return float(np.max(np.abs(watched.theta - alone.theta) / watched.std_errors))


def summary(fits: list[dict]) -> dict:
    """Per rule: fires, false alarms, fits it fired on; misses; the fits that did not converge left alone."""
    fires = [f for fit in fits for f in fit["fires"]]
    return {
        "fits": len(fits),
        "ok": sum(f["status"] == "ok" for f in fits),
        "rules": {
            rule: {
                "fires": sum(f["rule"] == rule for f in fires),
                "fits": sum(any(f["rule"] == rule for f in fit["fires"]) for fit in fits),
                "false_alarms": sum(f["rule"] == rule and f["false_alarm"] for f in fires),
            }
            for rule in RULES
        },
        "misses": sum(f["misses"] for f in fits),
        "alone_not_converged": sum(not f["alone_converged"] for f in fits),
        "iterations_median": float(np.median([f["iterations"] for f in fits])),
        "alone_iterations_median": float(np.median([f["alone_iterations"] for f in fits])),
        "apart_std_max": max((f["apart_std"] for f in fits if f["apart_std"] is not None), default=float("nan")),
    }


def run(quick: bool = False) -> dict:
    """The bench section: COUNT vehicles of each seed (2 with --quick), both fits, watched and left alone."""
    out: dict = {"seeds": SEEDS, "count": 2 if quick else COUNT, "joints_kmh": JOINTS, "left_alone": LEFT_ALONE}
    with tempfile.TemporaryDirectory(prefix="crashnlp-detectors-") as tmp:
        for role, seed in SEEDS.items():
            rows = []
            for i in range(out["count"]):
                v = random_vehicle(i, seed)
                folder = Path(tmp) / f"{seed}-{v.name}"
                folder.mkdir()
                for fit, (watched, alone) in problems(v, folder).items():
                    rows.append(r := {"vehicle": v.name, "fit": fit, **judge(watched, alone)})
                    print(_line(seed, r), flush=True)
            out[role] = {"seed": seed, "summary": summary(rows), "fits": rows}
    return out


def _line(seed: int, r: dict) -> str:
    fired = ", ".join(f"{f['rule']} at {f['at']}{' (false alarm)' if f['false_alarm'] else ''}" for f in r["fires"]) or "none"
    apart = "" if r["apart_std"] is None else f", {r['apart_std']:.1e} std apart"
    return (
        f"  seed {seed} {r['vehicle']} {r['fit']}: {r['status']}, {r['iterations']} it, rules {fired}; "
        f"left alone {r['alone_status']}, {r['alone_iterations']} it{apart}"
    )
