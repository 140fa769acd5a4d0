"""Forward simulation with a CasADi integrator, separate from any NLP transcription."""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from crashnlp.model.pendulum import NX, OUTPUTS, PendulumModel
from crashnlp.problem.schema import Simulation
from crashnlp.units import G0

RESPONSE_COLUMNS = {  # csv column: (output, factor from SI)
    "time_s": ("time", 1.0),
    "displacement_m": ("displacement", 1.0),
    "velocity_mps": ("velocity", 1.0),
    "accel_g": ("accel", 1 / G0),
    "pitch_deg": ("pitch", 180 / np.pi),
    "crush_m": ("crush", 1.0),
    "barrier_force_N": ("barrier_force", 1.0),
}


@dataclass
class Response:
    """Named outputs (SI) on a time grid, plus the absorbed energies."""

    time: np.ndarray
    outputs: dict[str, np.ndarray]
    states: np.ndarray  # rows r, theta, rdot, thetadot, x_max[, absorbed energies]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.time if name == "time" else self.outputs[name]

    def write_csv(self, path: Path) -> None:
        write_response_csv(path, self.time, self.outputs)


def write_response_csv(path: Path, time: np.ndarray, outputs: dict[str, np.ndarray]) -> None:
    """response.csv: the columns simulate and identify both write, in report units."""
    path.parent.mkdir(parents=True, exist_ok=True)
    series = {"time": np.asarray(time), **outputs}
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(RESPONSE_COLUMNS)
        cols = [series[name] * f for name, f in RESPONSE_COLUMNS.values()]
        for row in zip(*cols):
            w.writerow([f"{v:.9g}" for v in row])


def integrator(model: PendulumModel, grid: np.ndarray, options: Simulation) -> ca.Function:
    """A CasADi integrator from grid[0] over the output grid."""
    x = ca.SX.sym("x", NX + 3)
    dae = {"x": x, "p": model.p, "ode": model.augmented_rhs(x, model.p)}
    if options.integrator == "cvodes":
        opts = {"reltol": options.rtol, "abstol": options.atol, "max_num_steps": 100000}
    else:
        opts = {"number_of_finite_elements": options.substeps}
    return ca.integrator("sim", options.integrator, dae, float(grid[0]), list(grid[1:]), opts)


def simulate(
    model: PendulumModel, p: np.ndarray, speed: float, grid: np.ndarray, options: Simulation
) -> Response:
    """Simulate one impact at `speed` with parameter vector `p` on `grid` (starts at 0)."""
    x0 = np.concatenate([np.asarray(model.initial_state(p, speed)).ravel(), [0.0, 0.0, 0.0]])
    xf = np.asarray(integrator(model, grid, options)(x0=x0, p=p)["xf"])
    states = np.column_stack([x0, xf])
    return response_from_states(model, p, grid, states)


def response_from_states(model: PendulumModel, p: np.ndarray, grid: np.ndarray, states: np.ndarray) -> Response:
    """Outputs on a grid from states (rows r, theta, rdot, thetadot, x_max[, W_barrier, W_damper])."""
    n = states.shape[1]
    y = np.asarray(model.outputs.map(n)(states[:NX], ca.repmat(p, 1, n), states[NX]))
    outputs = {name: y[i] for i, name in enumerate(OUTPUTS)}
    if states.shape[0] > NX + 1:
        outputs["absorbed"] = states[NX + 1] + states[NX + 2]
        outputs["dissipated"] = outputs["absorbed"] - (outputs["potential"] - _suspension_and_gravity(model, p, states))
    return Response(np.asarray(grid, dtype=float), outputs, states)


def _suspension_and_gravity(model: PendulumModel, p: np.ndarray, states: np.ndarray) -> np.ndarray:
    """Potential energy without the front end's recoverable part."""
    f = ca.Function("V", [model.q, model.p], [model.energy_terms["V"]])
    return np.asarray(f.map(states.shape[1])(states[:2], ca.repmat(p, 1, states.shape[1]))).ravel()
