"""Self-consistency of the shipped pickup identification (issue acceptance, at full size).

The truth is the shipped pickup fit; crashnlp's simulator makes data from it at
0.1 ms, in the columns of the shipped CSV, and the shipped problem, pointed at
those data, fits them back: clean with all channels and with velocity removed,
then 12 replicates with white noise (1 g, 0.02 m/s, 1 mm, 0.1 deg; the accel
filtered at CFC 60 as shipped) for the coverage of the 95 % intervals.
"""

from __future__ import annotations

import csv
import sys
import tempfile
from pathlib import Path

import numpy as np

from bench.common import PICKUP_56
from crashnlp.base.outputs import Z95
from crashnlp.base.units import G0
from crashnlp.case.case import Case
from crashnlp.optimize.identify import identify
from crashnlp.problem import load_problem

NOISE = {"accel_x_g": 1.0, "vel_x_mps": 0.02, "disp_x_m": 1e-3, "pitch_deg": 0.1}


def _write(path: Path, case: Case, p: np.ndarray, seed: int | None) -> None:
    test = case.tests[0]
    r = case.simulate(p, dt=1e-4)[test.name]
    rng = np.random.default_rng(seed)
    columns = {
        "accel_x_g": r["accel"] / G0,
        "vel_x_mps": r["velocity"],
        "disp_x_m": r["displacement"],
        "pitch_deg": np.degrees(r["pitch"]),
    }
    if seed is not None:
        columns = {k: v + NOISE[k] * rng.standard_normal(v.size) for k, v in columns.items()}
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", *columns])
        w.writerows(zip(r.time, *columns.values()))


def _refit(path: Path, drop: str | None = None):
    problem = load_problem(PICKUP_56)
    test = problem.tests[0]
    channels = {k: v for k, v in test.data.channels.items() if k != drop}
    data = test.data.model_copy(update={"file": path, "channels": channels})
    problem = problem.model_copy(update={"tests": [test.model_copy(update={"data": data})]})
    return identify(Case(problem), progress=None)


def _errors(sol, truth: dict) -> dict[str, float]:
    """Largest error per parameter: spring values relative to the largest true force."""
    out = {}
    for path, t in truth.items():
        est, t = np.asarray(sol.parameters[path], float), np.asarray(t, float)
        out[path] = float(np.max(np.abs(est - t)) / np.max(np.abs(t)))
    return out


def run(quick: bool = False) -> dict:
    truth_fit = identify(Case.load(PICKUP_56), progress=None)
    truth = truth_fit.parameters
    case = Case.load(PICKUP_56)
    p = truth_fit.full_parameters()
    out: dict = {"truth": truth}
    with tempfile.TemporaryDirectory() as tmp:
        clean = Path(tmp) / "clean.csv"
        _write(clean, case, p, None)
        for label, drop in (("all channels", None), ("without velocity", "velocity")):
            sol = _refit(clean, drop)
            out[label] = {
                "status": sol.status,
                "iterations": sol.result.iterations,
                "relative_errors": _errors(sol, truth),
                "forward_check_worst": sol.verification.worst(case.tests[0].name),
            }
        z = []
        for seed in range(4 if quick else 12):
            noisy = Path(tmp) / f"noisy{seed}.csv"
            _write(noisy, case, p, seed)
            sol = _refit(noisy)
            est = np.concatenate([np.atleast_1d(sol.parameters[k]) for k in truth])
            t = np.concatenate([np.atleast_1d(truth[k]) for k in truth])
            z.extend(((est - t) / sol.std_errors)[~truth_fit.at_bound()])
        z = np.asarray(z)
    out["coverage"] = {
        "replicates": 4 if quick else 12,
        "pairs": int(z.size),
        "coverage_95": float(np.mean(np.abs(z) <= Z95)),
        "rms_z": float(np.sqrt(np.mean(z**2))),
        "z": z.round(3).tolist(),
    }
    return out


if __name__ == "__main__":
    import json

    json.dump(run(quick="--quick" in sys.argv), sys.stdout, indent=1)
