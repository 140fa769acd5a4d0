"""Robustness corpus: identify random vehicles from bench/corpus.py with minimal problem files.

Each vehicle's test is written as a CSV, and a problem file that gives only the vehicle and
its test (no breakpoints, no spring values, no estimate: crashnlp.case.completion fills them in).
The identified model is simulated (CVODES, 10 kHz) and judged against the generator's
noise-free response: max displacement, time of zero velocity, and the ISO/TS 18571 rating of
the barrier force over the pulse (impact to the generator's separation from the wall).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from bench.corpus import Vehicle, corpus, measured, simulate, write_csv
from crashnlp.analysis.metrics import crash_metrics
from crashnlp.analysis.rating import iso18571
from crashnlp.case.case import Case
from crashnlp.optimize.identify import identify
from crashnlp.problem import load_problem

COUNT, SEED = 30, 2024
TARGETS = {"displacement_rel": 0.02, "stop_s": 0.002, "force_rating_median": 0.9}
WINDOW = (0.0, 0.2)  # s
ACCEL_FILTER = "CFC60"  # the minimal problems' accelerometers, read as the shipped problems' are (SAE J211 CFC 60)


def minimal_problem(v: Vehicle, csv_name: str, transcription: dict | None = None) -> dict:
    """The issue's minimal problem: the vehicle, its test with data, nothing about the front end."""
    problem = {
        "name": v.name,
        "vehicle": {
            "mass": v.mass,
            "speed": v.speed,
            "pitch_inertia": v.pitch_inertia,
            "cg_to_impact": v.cg_to_impact,
            "cg_above_impact": v.cg_above_impact,
            "cg_to_front_axle": v.cg_to_front_axle,
            "cg_to_rear_axle": v.cg_to_rear_axle,
            "suspension": {"k_front": v.k_front, "k_rear": v.k_rear, "c_front": v.c_front, "c_rear": v.c_rear},
        },
        "model": {"spring": {"law": "force"}, "unloading": {"law": "plastic"}},
        "tests": [
            {
                "name": "t1",
                "speed": v.speed,
                "data": {
                    "file": csv_name,
                    "format": "csv",
                    "time": {"column": "time_s", "unit": "s"},
                    "window": list(WINDOW),
                    "channels": {
                        "accel": {"column": "accel_x_g", "unit": "g", "filter": ACCEL_FILTER},
                        "velocity": {"column": "vel_x_mps", "unit": "m/s"},
                        "displacement": {"column": "disp_x_m", "unit": "m"},
                        "pitch": {"column": "pitch_deg", "unit": "deg"},
                    },
                },
            }
        ],
    }
    if transcription:
        problem["transcription"] = transcription
    return problem


def write_test(v: Vehicle, folder: Path, transcription: dict | None = None) -> tuple[Path, dict[str, np.ndarray]]:
    """The vehicle's CSV and minimal problem file in `folder`; returns the problem path and the truth."""
    truth = simulate(v)
    write_csv(folder / f"{v.name}.csv", measured(v, truth))
    path = folder / f"{v.name}.yaml"
    path.write_text(yaml.safe_dump(minimal_problem(v, f"{v.name}.csv", transcription), sort_keys=False))
    return path, truth


def pulse_end(truth: dict[str, np.ndarray]) -> float:
    """When the generator's barrier force ends for good (last sample above 0.5 % of its peak)."""
    force = truth["barrier_force"]
    return float(truth["time"][np.flatnonzero(force > 0.005 * force.max())[-1]])


def judge(v: Vehicle, problem_path: Path, truth: dict[str, np.ndarray]) -> dict:
    """Identify one vehicle and compare the identified model with the generator's truth."""
    t0 = time.perf_counter()
    case = Case(load_problem(problem_path))
    solution = identify(case, progress=None)
    wall = time.perf_counter() - t0
    out = {
        "name": v.name,
        "mass_kg": v.mass,
        "speed_kmh": v.speed * 3.6,
        "status": solution.status,
        "iterations": solution.result.iterations if solution.result else 0,
        "wall_s": wall,
    }
    if not solution.ok:
        return out
    response = case.simulate(solution.full_parameters(), dt=1e-4)["t1"]
    model = crash_metrics(response.time, response["accel"], response["velocity"], response["displacement"])
    real = crash_metrics(truth["time"], truth["accel"], truth["velocity"], truth["displacement"])
    end = pulse_end(truth)
    span = truth["time"] <= end
    force_model = np.interp(truth["time"][span], response.time, response["barrier_force"])
    out.update(
        displacement_m=model.max_displacement,
        displacement_true_m=real.max_displacement,
        displacement_rel=model.max_displacement / real.max_displacement - 1.0,
        stop_s=model.t_zero_velocity,
        stop_true_s=real.t_zero_velocity,
        stop_err_s=model.t_zero_velocity - real.t_zero_velocity,
        force_rating=iso18571(truth["time"][span], truth["barrier_force"][span], force_model)["overall"],
        pulse_end_s=end,
    )
    return out


def within_targets(r: dict) -> bool:
    """Identified, max displacement within 2 %, stop time within 2 ms."""
    return (
        r["status"] == "ok"
        and abs(r["displacement_rel"]) <= TARGETS["displacement_rel"]
        and abs(r["stop_err_s"]) <= TARGETS["stop_s"]
    )


def summary(rows: list[dict]) -> dict:
    """Success rate, max displacement and stop-time errors, force ratings over the corpus."""
    ok = [r for r in rows if r["status"] == "ok"]
    travel = np.array([abs(r["displacement_rel"]) for r in ok])
    stop = np.array([abs(r["stop_err_s"]) for r in ok])
    rating = np.array([r["force_rating"] for r in ok])
    pick = lambda a, f: float(f(a)) if a.size else float("nan")  # noqa: E731
    return {
        "vehicles": len(rows),
        "succeeded": len(ok),
        "success_rate": len(ok) / len(rows),
        "within_targets": sum(within_targets(r) for r in rows),
        "displacement_rel_median": pick(travel, np.median),
        "displacement_rel_max": pick(travel, np.max),
        "stop_err_median_s": pick(stop, np.median),
        "stop_err_max_s": pick(stop, np.max),
        "force_rating_median": pick(rating, np.median),
        "force_rating_min": pick(rating, np.min),
        "wall_median_s": float(np.median([r["wall_s"] for r in rows])),
    }


def run(quick: bool = False) -> dict:
    """The bench section: the whole corpus (6 vehicles with --quick)."""
    vehicles = corpus(6 if quick else COUNT, SEED)
    rows = []
    with tempfile.TemporaryDirectory(prefix="crashnlp-corpus-") as tmp:
        for v in vehicles:
            path, truth = write_test(v, Path(tmp))
            rows.append(judge(v, path, truth))
            r = rows[-1]
            print(
                f"  {v.name} {v.mass:.0f} kg {v.speed * 3.6:.1f} km/h: {r['status']}"
                + (
                    f", displacement {100 * r['displacement_rel']:+.2f} %, stop {1e3 * r['stop_err_s']:+.2f} ms, force {r['force_rating']:.3f}"
                    if r["status"] == "ok"
                    else ""
                ),
                flush=True,
            )
    return {"seed": SEED, "targets": TARGETS, "summary": summary(rows), "vehicles": rows}
