"""Forward simulation: one crashnlp simulation against solve_ivp, and a batch of what-if runs.

Single run: crashnlp's CVODES integrator (the problem's rtol 1e-8, atol 1e-10,
output every 0.1 ms) against solve_ivp on the same augmented RHS, same
tolerances and output grid; the fastest of a few solve_ivp methods is the baseline.

Batch: a fixed-step RK4 of the augmented RHS as one CasADi Function (mapaccum
over the steps, the step compiled to C by CasADi's JIT), mapped over parameter
sets with spring values scaled by random factors in [0.8, 1.2], serially and
on 2 threads. The compile time is recorded apart: it is paid once per model.
"""
from __future__ import annotations

import tempfile

import casadi as ca
import numpy as np

from bench.baseline import shoot
from bench.common import PICKUP_56, load_case, timed
from crashnlp.case import Case
from crashnlp.model.pendulum import NX, OUTPUTS
from crashnlp.simulate import integrator, simulate
from crashnlp.units import G0

SCIPY_METHODS = ("LSODA", "RK45", "DOP853")
BATCH_DT = 1e-4
JIT = {"jit": True, "compiler": "shell", "jit_options": {"flags": ["-O3", "-march=native"], "directory": tempfile.gettempdir() + "/"}}


def single(case: Case, repeats: int) -> dict:
    """Best-of-`repeats` wall time of one simulation by crashnlp and by each solve_ivp method."""
    test, opts = case.tests[0], case.problem.simulation
    p = case.test_parameters(test)
    grid = np.arange(0.0, test.duration + 0.5 * opts.dt, opts.dt)
    t_full, ref = timed(lambda: simulate(case.model, p, test.speed, grid, opts), repeats)
    sim = integrator(case.model, grid, opts)
    x0 = np.concatenate([np.asarray(case.model.initial_state(p, test.speed)).ravel(), np.zeros(3)])
    t_call, _ = timed(lambda: sim(x0=x0, p=p), repeats)
    out = {"grid_points": len(grid), "rtol": opts.rtol, "atol": opts.atol,
           "crashnlp_s": t_full, "crashnlp_call_only_s": t_call, "scipy": {}}
    for method in SCIPY_METHODS:
        t, y = timed(lambda: shoot(case, case.base, 0, grid, method, opts.rtol, opts.atol, np.inf), repeats)
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


def rk4_trajectory(case: Case, steps: int, dt: float) -> ca.Function:
    """(x0[7], p) -> states at steps 1..steps (7 x steps): fixed-step RK4 of the augmented RHS.

    The steps are one mapaccum call node in an MX graph, so `.map` over parameter
    sets sees one p per simulation (not one per step)."""
    x, p = ca.SX.sym("x", NX + 3), ca.SX.sym("p", case.layout.size)
    f = case.model.augmented_rhs
    k1 = f(x, p)
    k2 = f(x + dt / 2 * k1, p)
    k3 = f(x + dt / 2 * k2, p)
    k4 = f(x + dt * k3, p)
    step = ca.Function("rk4", [x, p], [x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)], JIT)
    x0, pm = ca.MX.sym("x0", NX + 3), ca.MX.sym("p", case.layout.size)
    states = step.mapaccum("steps", steps)(x0, ca.repmat(pm, 1, steps))
    return ca.Function("trajectory", [x0, pm], [states], ["x0", "p"], ["states"])


def parameter_sets(case: Case, n: int, seed: int = 0) -> np.ndarray:
    """n full parameter vectors (columns): spring values scaled by uniform factors in [0.8, 1.2]."""
    where = case.layout.index("model.spring.values")
    rng = np.random.default_rng(seed)
    P = np.tile(case.test_parameters(case.tests[0])[:, None], (1, n))
    P[where] *= rng.uniform(0.8, 1.2, size=(where.stop - where.start, n))
    return P


def batch(case: Case, n: int, members: tuple[int, ...]) -> dict:
    """n simulations through CasADi map, serial and 2 threads; members checked against single runs."""
    test, opts = case.tests[0], case.problem.simulation
    steps = int(round(test.duration / BATCH_DT))
    compile_s, traj = timed(lambda: rk4_trajectory(case, steps, BATCH_DT))
    P = parameter_sets(case, n)
    x0_of = case.model.initial_state.map(n)
    out = {"n": n, "dt": BATCH_DT, "steps": steps, "integrator": "RK4 fixed step, JIT-compiled", "compile_s": compile_s}
    for mode, mapped in (("serial", traj.map(n)), ("thread2", traj.map(n, "thread", 2))):
        def run():
            X0 = ca.vertcat(x0_of(P, test.speed), ca.DM.zeros(3, n))
            return np.asarray(mapped(X0, P))

        wall, X = timed(run)
        out[mode] = {"wall_s": wall, "per_simulation_ms": 1e3 * wall / n}
    grid = BATCH_DT * np.arange(steps + 1)
    out["checks"] = [check_member(case, traj, X, P, k, steps, grid) for k in members if k < n]
    return out


def check_member(case: Case, traj: ca.Function, X: np.ndarray, P: np.ndarray, k: int, steps: int, grid: np.ndarray) -> dict:
    """Member k of the batch against the same RK4 run alone and against crashnlp's CVODES simulation."""
    test = case.tests[0]
    p = P[:, k]
    x0 = np.concatenate([np.asarray(case.model.initial_state(p, test.speed)).ravel(), np.zeros(3)])
    member = X[:, k * steps : (k + 1) * steps]
    alone = np.asarray(traj(x0, p))
    ref = simulate(case.model, p, test.speed, grid, case.problem.simulation)
    states = np.column_stack([x0, member])
    y = np.asarray(case.model.outputs.map(steps + 1)(states[:NX], np.tile(p[:, None], (1, steps + 1)), states[NX]))
    crush, accel = y[OUTPUTS.index("crush")], y[OUTPUTS.index("accel")]
    return {
        "member": k,
        "max_diff_vs_alone": float(np.max(np.abs(member - alone))),
        "max_crush_diff_vs_cvodes_mm": 1e3 * float(np.max(np.abs(crush - ref["crush"]))),
        "max_accel_diff_vs_cvodes_g": float(np.max(np.abs(accel - ref["accel"]))) / G0,
    }


def run(quick: bool = False) -> dict:
    """Single-run comparison and the batch."""
    case = load_case(PICKUP_56)
    out = {"single": single(case, 2 if quick else 5), "batch": batch(case, 20 if quick else 1000, (0, 1, 999))}
    s, b = out["single"], out["batch"]
    print(f"  single: crashnlp {s['crashnlp_s'] * 1e3:.1f} ms ({s['crashnlp_call_only_s'] * 1e3:.1f} ms call only), "
          f"solve_ivp {s['scipy_best']} {s['scipy'][s['scipy_best']]['wall_s'] * 1e3:.1f} ms: {s['speedup']:.1f}x")
    print(f"  batch of {b['n']} (compile {b['compile_s']:.2f} s once): serial {b['serial']['wall_s']:.2f} s, 2 threads {b['thread2']['wall_s']:.2f} s "
          f"({b['thread2']['per_simulation_ms']:.2f} ms per simulation)")
    for c in b["checks"]:
        print(f"    member {c['member']}: vs alone {c['max_diff_vs_alone']:.1e}, vs CVODES crush "
              f"{c['max_crush_diff_vs_cvodes_mm']:.3f} mm, accel {c['max_accel_diff_vs_cvodes_g']:.3f} g")
    return out
