"""Forward simulation with a CasADi integrator, separate from any NLP transcription."""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from crashnlp.models.form import ABSORBED, OUTPUTS, CrashModel
from crashnlp.numerics.compiled import Evaluator, compiled
from crashnlp.numerics.integrators import rk4
from crashnlp.numerics.runtime import mapped
from crashnlp.problem.schema import Simulation
from crashnlp.results.response import APPROACH, Response


def _key(grid: np.ndarray, options: Simulation) -> tuple:
    return (options.integrator, options.substeps, options.rtol, options.atol, np.asarray(grid, dtype=float).tobytes())


def integrator(model: CrashModel, grid: np.ndarray, options: Simulation) -> ca.Function:
    """A CasADi integrator from grid[0] over the output grid, built once per model, grid and options.

    Its right-hand side is the model's, compiled (crashnlp.numerics.compiled)."""

    def build() -> ca.Function:
        rhs = model.cached(("rhs",), lambda: compiled(model.augmented_rhs, jacobian=True))
        x, p = ca.MX.sym("x", model.nx + len(ABSORBED)), ca.MX.sym("p", model.layout.size)
        dae = {"x": x, "p": p, "ode": rhs(x, p)}
        if options.integrator == "cvodes":
            # the crash ODE is not stiff: Adams with fixed-point iteration needs no Jacobian
            opts: dict[str, Any] = {
                "reltol": options.rtol,
                "abstol": options.atol,
                "max_num_steps": 100000,
                "disable_internal_warnings": True,  # a failure reaches the user as one line (cli.describe)
                "linear_multistep_method": "adams",
                "nonlinear_solver_iteration": "functional",
            }
        else:  # CasADi counts the finite elements over the whole grid, not per output step
            opts = {"number_of_finite_elements": options.substeps * (len(grid) - 1)}
        return ca.integrator("sim", options.integrator, dae, float(grid[0]), list(grid[1:]), opts)

    return model.cached(("integrator", _key(grid, options)), build)


def batch_simulator(model: CrashModel, steps: int, dt: float, n: int, jit: bool = False) -> ca.Function:
    """n simulations at once, one parameter set each: (X0 augmented x n, P np x n) -> outputs.

    Fixed-step RK4 of the simulation ODE accumulated over the steps (mapaccum),
    the named outputs at every step, all mapped over the parameter sets, as a
    what-if study needs. The result has len(OUTPUTS) rows, the front end's permanent set
    (CrashModel.permanent_set) below them, and n * (steps + 1) columns, simulation k in columns k * (steps + 1) onwards. `jit`
    compiles one simulation to C (crashnlp.numerics.compiled: about a second, once per machine)."""
    x, p = ca.SX.sym("x", model.nx + len(ABSORBED)), model.p
    step = rk4(model.augmented_rhs, dt)
    outputs = ca.Function("y", [x, p], [model.outputs(x[: model.nx], p)])
    x0, pm = ca.MX.sym("x0", model.nx + len(ABSORBED)), ca.MX.sym("p", model.layout.size)
    states = ca.horzcat(x0, step.mapaccum("steps", steps)(x0, ca.repmat(pm, 1, steps)))
    each = ca.repmat(pm, 1, steps + 1)
    y = ca.vertcat(outputs.map(steps + 1)(states, each), model.permanent_set.map(steps + 1)(states[: model.nx, :], each))
    one = ca.Function(f"trajectory_{steps}", [x0, pm], [y], ["x0", "p"], ["y"])
    return mapped(compiled(one) if jit else one, n)


def simulate_batch(
    model: CrashModel, P: np.ndarray, speed: float, duration: float, dt: float, jit: bool = False
) -> dict[str, np.ndarray]:
    """Simulate every column of P (full parameter vectors) by fixed-step RK4 of step dt.

    Returns "time" and each named output as an array of shape (simulations, times), the crush
    the front end's own and the shortening of its line of action APPROACH (`with_front_end`)."""
    n, steps = P.shape[1], int(round(duration / dt))
    X0 = np.vstack([np.asarray(model.initial_state.map(n)(P, speed)), np.zeros((len(ABSORBED), n))])
    batch = model.cached(("batch", steps, dt, n, jit), lambda: Evaluator(batch_simulator(model, steps, dt, n, jit)))
    (y,) = batch(x0=X0, p=P)
    y = y.reshape(len(OUTPUTS) + 1, n, steps + 1)
    return {"time": dt * np.arange(steps + 1), **with_front_end({name: y[i] for i, name in enumerate(OUTPUTS)}, y[-1])}


def simulate(model: CrashModel, p: np.ndarray, speed: float, grid: np.ndarray, options: Simulation) -> Response:
    """Simulate one impact at `speed` with parameter vector `p` on `grid` (starts at 0)."""
    x0 = np.concatenate([np.asarray(model.initial_state(p, speed)).ravel(), np.zeros(len(ABSORBED))])
    (xf,) = model.cached(("integration", _key(grid, options)), lambda: Evaluator(integrator(model, grid, options), ("xf",)))(
        x0=x0, p=p
    )
    states = np.column_stack([x0, xf])
    return response_from_states(model, p, grid, states)


def _outputs_on_grid(model: CrashModel, n: int) -> tuple[Evaluator, Evaluator]:
    """The compiled outputs, and the front end's permanent set (CrashModel.permanent_set), each
    mapped over the n points of one simulation, to be evaluated on its arrays (the parameters
    broadcast to every point)."""

    def build() -> tuple[Evaluator, Evaluator]:
        outputs = model.cached(("outputs",), lambda: compiled(model.outputs))
        permanent = model.cached(("permanent_set",), lambda: compiled(model.permanent_set))
        return Evaluator(outputs.map(n)), Evaluator(permanent.map(n))

    return model.cached(("outputs", n), build)


def front_end_crush(crush: np.ndarray, permanent: np.ndarray) -> np.ndarray:
    """The front end's crush, its deformation, where its `crush` output (the shortening of its line
    of action) and its permanent set (CrashModel.permanent_set) take these values over time (the
    last axis): that crush, or where it is smaller the permanent set, neither negative nor past the
    largest crush so far. After separation the line of action's shortening keeps falling as the
    vehicle moves away; that gap is not crush, and the front end stays at its permanent set. Its
    largest value is the line of action's."""
    return np.maximum(crush, np.clip(permanent, 0.0, np.maximum.accumulate(crush, axis=-1)))


def with_front_end(outputs: dict[str, np.ndarray], permanent: np.ndarray) -> dict[str, np.ndarray]:
    """A simulation's outputs (the model's, on a grid; or n simulations', n x times) with its crush
    the front end's own (`front_end_crush`), the shortening of its line of action kept as APPROACH."""
    return {**outputs, APPROACH: outputs["crush"], "crush": front_end_crush(outputs["crush"], permanent)}


def response_from_states(model: CrashModel, p: np.ndarray, grid: np.ndarray, states: np.ndarray) -> Response:
    """Outputs on a grid from states (rows: the model's states()[, the ABSORBED works])."""
    x = states[: model.nx]
    outputs, permanent = _outputs_on_grid(model, x.shape[1])
    each = np.broadcast_to(np.asarray(p, dtype=float).reshape(-1, 1), (np.size(p), x.shape[1]))
    (y,), (held,) = outputs(x=x, p=each), permanent(x=x, p=each)
    return response_of_outputs(model, grid, y, held[0], states)


def response_of_outputs(
    model: CrashModel, grid: np.ndarray, y: np.ndarray, permanent: np.ndarray, states: np.ndarray
) -> Response:
    """The response of the model's outputs `y` (rows: OUTPUTS) and its permanent set at `states`
    (rows: the model's states()[, the ABSORBED works]): its crush the front end's own
    (`with_front_end`), and where the states carry them the works and what they leave."""
    outputs = with_front_end({name: y[i] for i, name in enumerate(OUTPUTS)}, permanent)
    if states.shape[0] > model.nx:  # the works, and what was absorbed less what the front end still stores
        work = dict(zip(ABSORBED, states[model.nx :]))
        outputs["front_work"], outputs["front_damper_work"] = work["barrier_power"], work["front_damper_power"]
        outputs["suspension_work"] = work["damper_power"]
        outputs["absorbed"] = outputs["front_work"] + outputs["suspension_work"]
        outputs["dissipated"] = outputs["absorbed"] - outputs["front_energy"]
    return Response(np.asarray(grid, dtype=float), outputs, states)
