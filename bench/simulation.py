"""Forward simulation: one crashnlp simulation against solve_ivp, and a batch of what-if runs.

Single run: crashnlp's CVODES integrator (the problem's rtol 1e-8, atol 1e-10,
output every 0.1 ms) against solve_ivp on the same augmented RHS, same
tolerances and output grid; the fastest of a few solve_ivp methods is the baseline.

Batch: crashnlp's batch simulator (fixed-step RK4 of the simulation ODE,
mapaccum over the steps, mapped over parameter sets with spring values scaled by
random factors in [0.8, 1.2]), in CasADi's virtual machine and compiled to C.
The first call (build, and compile or load the cached library) is recorded apart.
"""

from __future__ import annotations

import numpy as np

from bench.baseline import shoot
from bench.common import PICKUP_56, load_case, timed
from crashnlp.base.units import G0
from crashnlp.case.case import Case
from crashnlp.models.simulation import integrator, simulate, simulate_batch

SCIPY_METHODS = ("LSODA", "RK45", "DOP853")
BATCH_DT = 5e-4


def single(case: Case, repeats: int) -> dict:
    """Best-of-`repeats` wall time of one simulation by crashnlp and by each solve_ivp method."""
    test, opts = case.tests[0], case.problem.simulation
    p = case.test_parameters(test)
    grid = np.arange(0.0, test.duration + 0.5 * opts.dt, opts.dt)
    t_full, ref = timed(lambda: simulate(case.model, p, test.speed, grid, opts), repeats)
    sim = integrator(case.model, grid, opts)
    x0 = np.concatenate([np.asarray(case.model.initial_state(p, test.speed)).ravel(), np.zeros(3)])
    t_call, _ = timed(lambda: sim(x0=x0, p=p), repeats)
    out = {
        "grid_points": len(grid),
        "rtol": opts.rtol,
        "atol": opts.atol,
        "crashnlp_s": t_full,
        "crashnlp_call_only_s": t_call,
        "scipy": {},
    }
    for method in SCIPY_METHODS:
        t, y = timed(lambda method=method: shoot(case, case.base, 0, grid, method, opts.rtol, opts.atol, np.inf), repeats)
        out["scipy"][method] = {
            "wall_s": t,
            "max_crush_diff_mm": 1e3 * float(np.max(np.abs(y["crush"] - ref["crush"]))),
            "max_accel_diff_g": float(np.max(np.abs(y["accel"] - ref["accel"]))) / G0,
        }
    best = min(out["scipy"], key=lambda m: out["scipy"][m]["wall_s"])
    out["scipy_best"] = best
    out["speedup"] = out["scipy"][best]["wall_s"] / t_full
    out["speedup_call_only"] = out["scipy"][best]["wall_s"] / t_call
    return out


def parameter_sets(case: Case, n: int, seed: int = 0) -> np.ndarray:
    """n full parameter vectors (columns): spring values scaled by uniform factors in [0.8, 1.2]."""
    where = case.layout.index("model.spring.values")
    rng = np.random.default_rng(seed)
    P = np.tile(case.test_parameters(case.tests[0])[:, None], (1, n))
    P[where] *= rng.uniform(0.8, 1.2, size=(where.stop - where.start, n))
    return P


def batch(case: Case, n: int, members: tuple[int, ...]) -> dict:
    """n simulations through crashnlp's batch simulator (RK4 mapaccum, mapped over parameter sets).

    The first call builds (and, compiled, compiles once per machine or loads the
    cached library); the run time is the best of three calls after it."""
    test = case.tests[0]
    steps = int(round(test.duration / BATCH_DT))
    P = parameter_sets(case, n)
    out = {"n": n, "dt": BATCH_DT, "steps": steps, "integrator": "RK4 fixed step (crashnlp.models.simulation.simulate_batch)"}
    for mode, jit in (("vm", False), ("compiled", True)):
        run = lambda jit=jit: simulate_batch(case.model, P, test.speed, test.duration, BATCH_DT, jit)
        first_s, _ = timed(run)
        wall, y = timed(run, 3)
        out[mode] = {"first_call_s": first_s, "wall_s": wall, "per_simulation_ms": 1e3 * wall / n}
    out["checks"] = [check_member(case, y["crush"], P, k) for k in members if k < n]
    return out


def check_member(case: Case, crush: np.ndarray, P: np.ndarray, k: int) -> dict:
    """Member k of the batch against the same run alone and against crashnlp's CVODES simulation."""
    test = case.tests[0]
    alone = simulate_batch(case.model, P[:, k : k + 1], test.speed, test.duration, BATCH_DT)["crush"][0]
    grid = BATCH_DT * np.arange(crush.shape[1])
    ref = simulate(case.model, P[:, k], test.speed, grid, case.problem.simulation)
    return {
        "member": k,
        "max_diff_vs_alone": float(np.max(np.abs(crush[k] - alone))),
        "max_crush_diff_vs_cvodes_mm": 1e3 * float(np.max(np.abs(crush[k] - ref["crush"]))),
    }


def run(quick: bool = False) -> dict:
    """Single-run comparison and the batch."""
    case = load_case(PICKUP_56)
    out = {"single": single(case, 2 if quick else 5), "batch": batch(case, 20 if quick else 1000, (0, 1, 999))}
    s, b = out["single"], out["batch"]
    print(
        f"  single: crashnlp {s['crashnlp_s'] * 1e3:.1f} ms ({s['crashnlp_call_only_s'] * 1e3:.1f} ms call only), "
        f"solve_ivp {s['scipy_best']} {s['scipy'][s['scipy_best']]['wall_s'] * 1e3:.1f} ms: {s['speedup']:.1f}x"
    )
    for mode in ("vm", "compiled"):
        m = b[mode]
        print(
            f"  batch of {b['n']} ({mode}): first call {m['first_call_s']:.2f} s, then {m['wall_s']:.2f} s ({m['per_simulation_ms']:.2f} ms per simulation)"
        )
    for c in b["checks"]:
        print(
            f"    member {c['member']}: vs alone {c['max_diff_vs_alone']:.1e}, vs CVODES crush {c['max_crush_diff_vs_cvodes_mm']:.3f} mm"
        )
    return out
